"""The survey's counted exploration: the paper's goal-biased, constrained T-RRT, counting each pose once.

What is counted (docs/contract.md section 4): each pose the exploration samples and steers to,
once, as stable (margin >= threshold) or unstable. The points interpolated along an edge to
check it are checks, not states: they decide whether the edge joins the tree and are never
counted. A pose that collides is not counted (``stats['rejected']`` says how many); joint
limits cannot be broken, since a steered pose is clipped to them.

How a leg is explored: a tree grows from the leg's start (the pick's lift pose, or the handover
pose) and, taking turns with it, one from the leg's goal (``bidirectional``, as the planner's
own T-RRT does: a goal reached only through a narrow approach, such as a handover in front of
the chest, is found from its side); a share ``goal_bias`` of each tree's samples aims at the
other tree, at one of its nodes drawn at random (``goal_aim``); the others are drawn near the leg's
start or goal (``sampler: ends``, the paper's bias towards the path's starting and ending points)
or, for comparison, uniformly over the joint box (``sampler: box``). Each round steers ``batch_size``
samples from the trees as they stand; the new poses are evaluated in one batch, then judged one
by one in a fixed order:

* a pose the leg already sampled (the same nearest node steered towards the same aim gives the
  same pose) is not sampled again: it is neither counted nor judged a second time;
* an unstable pose is counted and not grown from (the constrained planner discards it);
* a stable pose must pass the T-RRT transition test (cost = -margin) and have a valid edge
  (every interpolated check collision-free and stable) to join the tree;
* after every extension, the goal test: a new node within one step of the other tree (of the
  goal, with one tree) whose straight edge to it is valid ends the leg. There is no
  straight-line shortcut from the start: the goal is reached only by growing the trees.

The leg ends at its goal or when it has counted ``leg_cap_states`` poses (not solved). Poses
judged after the one that reached the goal (or the cap) in the same round are not counted, so
the counts are those of a one-by-one exploration that stops there.

With ``budget`` (the fixed-budget mode, ``until: states``) the legs take turns round by round
and never stop at their goals; the seed ends when ``budget`` poses were counted.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Literal, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from planner.motion.edge_checks import CollisionFree, all_valid_coarse_to_fine
from planner.motion.interpolation import edge_states
from planner.motion.trrt import TreeSearch, TrrtSettings
from planner.stability.evaluator import HoldSpec, StateEvaluator
from planner.survey.shared_checks import leg_checks
from planner.transforms import matrices_to_pose7

ShouldStop = Callable[[], bool]


@dataclass(frozen=True)
class ExploreLeg:
    """One leg of a task: from ``start`` to ``goal`` holding the object as ``hold``, moving ``active`` columns.

    ``collision_free`` checks this leg's states (the held object differs per leg).
    """

    start: np.ndarray
    goal: np.ndarray
    hold: HoldSpec | None
    active: np.ndarray
    collision_free: CollisionFree | None = None


class CountingSettings(BaseModel):
    """How the counted exploration steers; the T-RRT's own parameters come from :class:`TrrtSettings`."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    batch_size: int = Field(16, ge=1, description="samples steered per round (judged one by one, in order)")
    goal_bias: float = Field(0.3, ge=0, lt=1, description="share of samples aimed at the other tree (the goal); below 1, "
                             "so that uniform samples always give the trees new poses to grow to")
    goal_aim: Literal["tree", "root"] = Field(
        "tree", description="tree: a goal-biased sample aims at a node of the other tree drawn at random; root: at the "
        "other tree's root. Aiming at the root, a tree whose nearest node cannot reach the root re-steers the same pose "
        "with every goal-biased sample; upright, about 1 seed in 8 of the dual-arm rows then reached the 20,000-state leg "
        "cap, and those seeds' R outweighed the rest. Aiming at the tree, the largest of 256 upright seeds counted 892")
    bidirectional: bool = Field(True, description="a second tree grows from the goal; the leg ends when the trees meet")
    step_rad: float = Field(0.3, gt=0, description="largest extension (Euclidean, active joints)")
    sampler: Literal["ends", "box"] = Field(
        "ends", description="where the samples that do not aim at the other tree go. ends: the paper's reading (its "
        "exploration has 'a bias towards the starting and ending points of a given path'): a share ends_share of them "
        "near the leg's start or its goal, one of the two drawn at random, each active joint within +-ends_spread_rad "
        "of it (clipped to the limits), the rest uniform over the joint box as T-RRT samples; box: all uniform over "
        "the whole box of the waist and the holding arm's joint limits")
    ends_share: float = Field(0.5, gt=0, le=1, description="share of the non-aimed samples drawn near an end (ends)")
    ends_spread_rad: float = Field(0.3, gt=0, description="half-width of the box around the start or goal the ends "
                                   "sampler draws from (one step)")


@dataclass
class LegCount:
    """One leg's counts: C, U, whether its tree reached the goal, and its tree size."""

    stable: int = 0
    unstable: int = 0
    solved: bool = False
    rounds: int = 0
    nodes: int = 1
    collisions: int = 0
    invalid_edges: int = 0
    transition_rejects: int = 0
    goal_tests: int = 0
    #: steered poses the leg had already sampled (neither counted nor judged again)
    repeats: int = 0

    @property
    def counted(self) -> int:
        return self.stable + self.unstable


@dataclass
class CountedExploration:
    """Every counted pose of one seed, in counting order, and per-leg counts.

    ``q`` (N, n), ``leg`` (N,), ``holding`` (N,) str, ``object_pose`` (N, 7) (NaN when nothing
    is held), ``stable`` (N,) bool, ``margin`` (N,), ``com`` (N, 3). ``status`` is ``done``,
    ``leg_cap`` (some leg hit its cap) or ``canceled``: the caps end a seed, never the clock.
    """

    q: np.ndarray
    leg: np.ndarray
    holding: np.ndarray
    object_pose: np.ndarray
    stable: np.ndarray
    margin: np.ndarray
    com: np.ndarray
    legs: list[LegCount]
    status: str
    stats: dict = field(default_factory=dict)

    @property
    def n_stable(self) -> int:
        return int(self.stable.sum())

    @property
    def n_unstable(self) -> int:
        return int((~self.stable).sum())

    @property
    def solved(self) -> bool:
        return all(leg.solved for leg in self.legs)


class _Counted:
    """The counted poses so far, in chunks (concatenated once at the end, when the object poses
    are also turned into 7-vectors, all at once)."""

    def __init__(self) -> None:
        self.parts: list[tuple] = []
        self.n = 0

    def add(self, leg: int, label: str, Q: np.ndarray, object_pose: np.ndarray | None, stable: np.ndarray,
            margin: np.ndarray, com: np.ndarray) -> None:
        """Counted poses ``Q`` (k, n) of one leg, with their (k, 4, 4) object poses (None: nothing held)."""
        if len(Q):
            held = np.full(len(Q), object_pose is not None)
            T = object_pose if object_pose is not None else np.zeros((len(Q), 4, 4))
            self.parts.append((np.full(len(Q), leg, np.int32), np.full(len(Q), label, dtype="U5"), Q, T, held, stable,
                               margin, com))
            self.n += len(Q)

    def arrays(self, nq: int) -> tuple:
        if not self.parts:
            return (np.zeros((0, nq)), np.zeros(0, np.int32), np.zeros(0, "U5"), np.zeros((0, 7)), np.zeros(0, bool),
                    np.zeros(0), np.zeros((0, 3)))
        leg, lab, Q, T, held, st, m, com = (np.concatenate([p[k] for p in self.parts]) for k in range(8))
        pose = np.full((len(Q), 7), np.nan)
        if held.any():
            pose[held] = matrices_to_pose7(T[held])
        return Q, leg, lab, pose, st.astype(bool), m, com


class _Leg:
    """One leg's tree and its checks."""

    def __init__(self, index: int, leg: ExploreLeg, evaluator: StateEvaluator, trrt: TrrtSettings,
                 settings: CountingSettings):
        robot = evaluator.robot
        self.index = index
        self.leg = leg
        self.evaluator = evaluator
        self.settings = settings
        self.active = np.asarray(sorted(set(int(a) for a in leg.active)), dtype=int)
        start, goal = np.asarray(leg.start, float), np.asarray(leg.goal, float)
        ends = evaluator.evaluate(np.vstack([start, goal]), leg.hold, active=self.active)
        self.search = TreeSearch(start, goal, self.active, robot.lower, robot.upper, float(ends.margin[0]),
                              float(ends.margin[1]), trrt.model_copy(update={"step_rad": settings.step_rad}))
        self.trees = self.search.trees  # from the start; from the goal (grown when bidirectional)
        self.turn = 0
        self.goal = goal[self.active]
        self.start = start[self.active]
        self.count = LegCount()
        self.sampled: set[bytes] = set()  # every pose this leg steered to, by its exact values
        self.label = leg.hold.label if leg.hold is not None else "none"
        # One forward-kinematics pass per batch for the margin, the limits and the collision check, when the
        # leg's collision check can take it (planner.survey.shared_checks); else the checks one after the other.
        self.checks = leg_checks(evaluator, leg.collision_free, leg.hold)

    def free(self, Q: np.ndarray) -> np.ndarray:
        if self.leg.collision_free is None:
            return np.ones(len(Q), dtype=bool)
        return np.asarray(self.leg.collision_free(Q), dtype=bool)

    def valid(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Edge checks: stable, then collision-free (collision only for the stable ones)."""
        if self.checks is not None:
            return self.checks.valid(Q)
        batch = self.evaluator.evaluate(Q, self.leg.hold, active=self.active)
        ok = batch.stable.copy()
        if ok.any():
            ok[ok] = self.free(Q[ok])
        return ok, batch.margin

    def propose(self, rng: np.random.Generator) -> list[tuple[int, int, np.ndarray, float]]:
        """Samples steered from the trees as they stand: (tree, nearest node, new pose, distance to the sample).

        With one tree, the goal-biased samples aim at the goal; with two, the trees take turns and
        each aims its goal-biased samples at the other tree (``goal_aim``). A pose this leg already
        sampled is left out (``repeats``)."""
        s = self.search
        out = []
        for _ in range(self.settings.batch_size):
            ti = self.turn if self.settings.bidirectional else 0
            self.turn ^= 1
            tree = self.trees[ti]
            if rng.random() < self.settings.goal_bias:
                target = self._aim(ti, rng)
            else:
                target = self._sample(rng)
            near, dist = tree.nearest(target)
            if dist < 1e-12:
                continue
            x = tree.nodes[near]
            new = np.clip(target if dist <= self.settings.step_rad else x + (target - x) * (self.settings.step_rad / dist),
                          s.lo, s.hi)
            key = new.tobytes()
            if key in self.sampled:
                self.count.repeats += 1
                continue
            self.sampled.add(key)
            out.append((ti, near, new, dist))
        return out

    def _sample(self, rng: np.random.Generator) -> np.ndarray:
        """A sample that does not aim at the other tree (``CountingSettings.sampler``)."""
        s = self.search
        if self.settings.sampler == "box" or rng.random() >= self.settings.ends_share:
            return rng.uniform(s.lo, s.hi)
        end = self.start if rng.random() < 0.5 else self.goal
        spread = self.settings.ends_spread_rad
        return np.clip(end + rng.uniform(-spread, spread, end.shape), s.lo, s.hi)

    def _aim(self, ti: int, rng: np.random.Generator) -> np.ndarray:
        """Where tree ``ti``'s goal-biased sample aims: the goal, or the other tree (its root or a random node)."""
        if not self.settings.bidirectional:
            return self.goal
        other = self.trees[ti ^ 1]
        if self.settings.goal_aim == "root" or other.size == 1:
            return other.nodes[0]
        return other.nodes[int(rng.integers(other.size))]

    def round(self, rng: np.random.Generator, rec: _Counted, cap: int | None, stop_at_goal: bool) -> bool:
        """One round; returns True when the leg is over (goal reached or cap)."""
        self.count.rounds += 1
        cands = self.propose(rng)
        if not cands:
            return False
        X = np.array([c[2] for c in cands])
        Q = self.search.full(X)
        if self.checks is not None:
            batch, free = self.checks.judge(Q)
        else:
            batch = self.evaluator.evaluate(Q, self.leg.hold, active=self.active)
            free = self.free(Q)
        # Judged in order: which are counted, which try to join the tree.
        counted: list[int] = []
        tries: list[int] = []
        end_at = len(cands)  # candidates from here on are not counted (the cap was reached)
        for k in range(len(cands)):
            if not free[k]:
                self.count.collisions += 1
                continue
            counted.append(k)
            if cap is not None and self.count.counted + len(counted) >= cap:
                end_at = k + 1
            if batch.stable[k]:
                ti, near, new, dist = cands[k]
                if self.search.transition(self.trees[ti], near, new, float(batch.margin[k]), dist, rng):
                    tries.append(k)
                else:
                    self.count.transition_rejects += 1
            if end_at <= k + 1:
                break
        tries = [k for k in tries if k < end_at]
        res = self.search.s.edge_resolution_rad
        edges = [edge_states(self.trees[cands[k][0]].nodes[cands[k][1]], cands[k][2], res)[:-1] for k in tries]
        with_checks = [i for i, e in enumerate(edges) if len(e)]
        edge_ok = [True] * len(tries)
        if with_checks:
            for i, ok in zip(with_checks, all_valid_coarse_to_fine([self.search.full(edges[i]) for i in with_checks], self.valid)):
                edge_ok[i] = ok
        added: list[tuple[int, int]] = []  # (candidate, node index)
        for k, ok in zip(tries, edge_ok):
            if not ok:
                self.count.invalid_edges += 1
                continue
            ti, near, new, _ = cands[k]
            added.append((k, self.trees[ti].add(new, near, float(batch.margin[k]))))
        reached = None
        if stop_at_goal and added:
            # The goal test: the new node within one step of the goal (or of the goal's tree) by a valid edge.
            near_goal = []
            for k, i in added:
                ti = cands[k][0]
                q = self.trees[ti].nodes[i]
                if self.settings.bidirectional:
                    j, d = self.trees[ti ^ 1].nearest(q)
                    target = self.trees[ti ^ 1].nodes[j]
                else:
                    target = self.goal
                    d = float(np.linalg.norm(q - target))
                if d <= self.settings.step_rad:
                    near_goal.append((k, q, target))
            self.count.goal_tests += len(added)
            if near_goal:
                checks = [self.search.full(edge_states(q, target, res)) for _, q, target in near_goal]
                for (k, _, _), ok in zip(near_goal, all_valid_coarse_to_fine(checks, self.valid)):
                    if ok:
                        reached = k
                        break
        if reached is not None:
            end_at = min(end_at, reached + 1)
        keep = np.array([k for k in counted if k < end_at], dtype=int)
        if keep.size:
            st = batch.stable[keep]
            rec.add(self.index, self.label, Q[keep], None if batch.object_pose is None else batch.object_pose[keep], st,
                    batch.margin[keep], batch.com[keep])
            self.count.stable += int(st.sum())
            self.count.unstable += int((~st).sum())
        self.count.nodes = sum(t.size for t in self.trees)
        if reached is not None:
            self.count.solved = True
            return True
        return cap is not None and self.count.counted >= cap


def explore_counted(
    legs: Sequence[ExploreLeg],
    evaluator: StateEvaluator,
    rng: np.random.Generator,
    *,
    leg_cap_states: int = 20_000,
    budget: int | None = None,
    settings: CountingSettings | None = None,
    trrt: TrrtSettings | None = None,
    should_stop: ShouldStop | None = None,
) -> CountedExploration:
    """Explore a task's legs and count every sampled pose once (module docstring).

    Without ``budget`` each leg runs, in order, until its tree reaches its goal or it counted
    ``leg_cap_states`` poses; with ``budget`` the legs take turns until ``budget`` poses were
    counted in all, trees growing past their goals.
    """
    s = settings or CountingSettings()
    t0 = time.perf_counter()
    if not legs:
        raise ValueError("explore_counted needs at least one leg")
    if budget is not None and budget < 1:
        raise ValueError(f"budget must be >= 1 state, got {budget}")
    if leg_cap_states < 1:
        raise ValueError(f"leg_cap_states must be >= 1, got {leg_cap_states}")
    trrt = trrt or TrrtSettings()
    runs = [_Leg(i, leg, evaluator, trrt, s) for i, leg in enumerate(legs)]
    rec = _Counted()
    status = "done"

    def interrupted() -> str | None:
        if should_stop is not None and should_stop():
            return "canceled"
        return None

    if budget is None:
        for run in runs:
            while not run.round(rng, rec, leg_cap_states, stop_at_goal=True):
                why = interrupted()
                if why:
                    status = why
                    break
            if status != "done":
                break
            if not run.count.solved:
                status = "leg_cap"
    else:
        turn = 0
        while rec.n < budget:
            why = interrupted()
            if why:
                status = why
                break
            run = runs[turn % len(runs)]
            turn += 1
            run.round(rng, rec, budget - rec.n + run.count.counted, stop_at_goal=not run.count.solved)
    Q, leg, lab, pose, st, m, com = rec.arrays(evaluator.robot.nq)
    elapsed = time.perf_counter() - t0
    stats = {"counted": int(len(st)), "stable": int(st.sum()), "unstable": int((~st).sum()), "time_s": elapsed,
             "states_per_s": len(st) / max(elapsed, 1e-9),
             "rejected": {"collision": sum(r.count.collisions for r in runs), "joint_limits": 0},
             "legs": [vars(r.count) | {"counted": r.count.counted} for r in runs]}
    return CountedExploration(q=Q, leg=leg, holding=lab, object_pose=pose, stable=st, margin=m, com=com,
                              legs=[r.count for r in runs], status=status, stats=stats)
