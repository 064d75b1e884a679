"""Paths through one or two task-space via points: the quick way around a table edge that random
sampling seldom finds.

A T-RRT path between two postures wanders (its samples are uniform in joint space), and shortcuts
cannot move it out of the way it went around an obstacle. Where the straight joint-space line
between a motion's ends sweeps the hand through the table's edge, the quickest way around is
usually simple in the hand's own space: rise to the higher end's height behind the edge, then go
on. :func:`via_paths` builds such paths through via postures whose moving hand is placed by IK
- on a grid: at the higher end's height (and a little above), between the two ends' distances in
  front of the robot;
- at random positions in a box around the two ends' hand positions (more room behind, to the sides
  and above than in front), for the ways the grid does not cover (round the object, over it);
each via started from the straight line's posture at its place along the line and keeping the hand's
orientation there, so the arm keeps the line's course elsewhere. The paths through one via or two
are ranked by their time at the velocity limits and checked, quickest first, by the caller's
validity at the caller's resolution; the few quickest valid ones are returned for the timing's
shortening and ranking like any other candidate path.

Deterministic for a generator: the samples and the IK's restarts draw from it, in a fixed order.
"""

from __future__ import annotations

import itertools
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.motion.edge_checks import Validity, all_valid_coarse_to_fine
from planner.motion.ik import IkSolver
from planner.motion.interpolation import edge_states

Side = Literal["left", "right"]


class ViaSettings(BaseModel):
    """Where the via points are tried and how many paths are checked."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    fractions: tuple[Annotated[float, Field(gt=0, lt=1)], ...] = Field(
        (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8),
        description="places along the straight line (share of the way) whose posture seeds a via's IK")
    reach: tuple[Annotated[float, Field(allow_inf_nan=False)], ...] = Field(
        (-0.3, 0.0, 0.3, 0.6), description="the via's distance in front of the robot (world x): share of the way from "
        "the lower end's to the higher end's")
    rise_m: tuple[Annotated[float, Field(ge=0, allow_inf_nan=False)], ...] = Field(
        (0.0, 0.05, 0.1), description="the via's height above the higher end (m)")
    samples: int = Field(40, ge=0, description="more vias at random hand positions in the box around the two ends' "
                         "TCP positions (below: sample_below_m, above: sample_above_m), each seeded from the line's "
                         "posture at a random place between the first and last fractions")
    sample_below_m: tuple[Annotated[float, Field(ge=0, allow_inf_nan=False)], ...] = Field(
        (0.25, 0.2, 0.0), min_length=3, max_length=3, description="how far the sampled box reaches below the lower of "
        "the two ends' TCP coordinates (world x, y, z; m): back towards the robot, to the sides")
    sample_above_m: tuple[Annotated[float, Field(ge=0, allow_inf_nan=False)], ...] = Field(
        (0.05, 0.2, 0.35), min_length=3, max_length=3, description="how far it reaches above the higher of the two "
        "ends' TCP coordinates (world x, y, z; m): over the table")
    pairs: bool = Field(True, description="also paths through two of the vias (in their order along the line)")
    checked: int = Field(1200, ge=0, description="candidate paths considered at most, quickest first (one whose "
                         "segment was already refused costs nothing)")
    keep: int = Field(3, ge=0, description="valid paths returned at most")


def via_paths(start: np.ndarray, goal: np.ndarray, side: Side, ik: IkSolver, validity: Validity,
              rng: np.random.Generator, weights: np.ndarray, resolution_rad: float,
              settings: ViaSettings | None = None) -> list[np.ndarray]:
    """Up to ``settings.keep`` valid paths (K, n) from ``start`` to ``goal`` through one or two via postures of the
    ``side`` hand, quickest first by their time at the velocity limits (``weights`` = 1 / velocity limit). Every
    state of a returned path passed ``validity`` at most ``resolution_rad`` apart per joint. Empty when none
    passed within ``settings.checked`` candidates.

    Candidates share their segments (start to a via, a via to another, a via to the goal), so each segment is
    checked once: a candidate with a segment already refused is passed over unchecked, and only the segments
    nobody has checked yet are checked, eight candidates at a time (coarse states first, then the rest)."""
    s = settings or ViaSettings()
    if s.keep == 0 or s.checked == 0:
        return []
    start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
    vias = _vias(start, goal, side, ik, rng, s)
    if not vias:
        return []
    nodes = np.vstack([start, *(q for _, q in vias), goal])
    last = len(nodes) - 1
    # time at the velocity limits of the straight segment between any two nodes
    segment = (np.abs(nodes[:, None, :] - nodes[None, :, :]) * np.asarray(weights)[None, None, :]).max(axis=2)
    inner = np.arange(1, last)
    routes: list[tuple[int, ...]] = [(0, int(k), last) for k in inner]
    cost = [segment[0, inner] + segment[inner, last]]
    if s.pairs:
        fraction = np.array([f for f, _ in vias])
        a, b = np.triu_indices(len(vias), k=1)
        in_order = fraction[a] < fraction[b]
        a, b = a[in_order] + 1, b[in_order] + 1
        routes += [(0, int(i), int(j), last) for i, j in zip(a, b)]
        cost.append(segment[0, a] + segment[a, b] + segment[b, last])
    order = [routes[i] for i in np.argsort(np.concatenate(cost), kind="stable")[: s.checked]]
    known: dict[tuple[int, int], bool] = {}
    found: list[np.ndarray] = []
    batch = 8
    for first in range(0, len(order), batch):
        group = [r for r in order[first:first + batch] if all(known.get(e, True) for e in zip(r[:-1], r[1:]))]
        todo = list(dict.fromkeys(e for r in group for e in zip(r[:-1], r[1:]) if e not in known))
        if todo:
            edges = [edge_states(nodes[a], nodes[b], resolution_rad) for a, b in todo]
            known.update(zip(todo, all_valid_coarse_to_fine(edges, validity)))
        found += [np.vstack([nodes[i] for i in r]) for r in group if all(known[e] for e in zip(r[:-1], r[1:]))]
        if len(found) >= s.keep:
            break
    return found[: s.keep]


def _vias(start: np.ndarray, goal: np.ndarray, side: Side, ik: IkSolver, rng: np.random.Generator,
          s: ViaSettings) -> list[tuple[float, np.ndarray]]:
    """(fraction, posture) of every via whose IK converged: the grid in the settings' order, then the samples in the
    order drawn. A via keeps the orientation the hand has on the straight line at its fraction."""
    p_start, p_goal = ik.tcp_pose(start, side)[:3, 3], ik.tcp_pose(goal, side)[:3, 3]
    low, high = (p_start, p_goal) if p_start[2] <= p_goal[2] else (p_goal, p_start)
    places: list[tuple[float, np.ndarray]] = []
    for f in s.fractions:
        for reach, rise in itertools.product(s.reach, s.rise_m):
            places.append((f, np.array([low[0] + reach * (high[0] - low[0]), np.nan, high[2] + rise])))
    if s.samples and s.fractions:
        box_low = np.minimum(p_start, p_goal) - np.asarray(s.sample_below_m)
        box_high = np.maximum(p_start, p_goal) + np.asarray(s.sample_above_m)
        first, last = min(s.fractions), max(s.fractions)
        for _ in range(s.samples):
            places.append((float(rng.uniform(first, last)), rng.uniform(box_low, box_high)))
    out: list[tuple[float, np.ndarray]] = []
    for f, position in places:
        on_line = start + f * (goal - start)
        target = ik.tcp_pose(on_line, side)
        target[:3, 3] = np.where(np.isnan(position), target[:3, 3], position)  # nan: the line's own coordinate
        res = ik.solve({side: target}, on_line, rng, rest_q=on_line)
        if res.q is not None:
            out.append((f, res.q))
    return out
