"""The gate's joint-torque and grip checks, recomputed from the URDF with the gate's own code.

Independent of the planner and of pinocchio: the URDF is the gate's parse
(:mod:`robot_bridge.urdf_kinematics`), the effort limits are read here from its ``<limit effort>``
and from the spec's ``effort_limits``, and the static torques are computed per plan point by a
forward pass over the links (world frames), the contact wrenches at the soles in contact by a
least-squares solve per point (the minimum 2-norm solution of the six balance equations), and
each joint's torque by summing the moments of every force that acts beyond it (gravity on its
links, the held object's weight through the holding TCP, half per hand while both hold, the
contact wrenches) about its axis. The definitions are those of the plan contract's section 3;
the jaw joints are not torque-checked, and only a hand with jaws has a grip check.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from .gate_types import Veto
from .urdf_kinematics import UrdfModel, quaternion_matrix, rotate

_HOLDERS = {0: (), 1: ("left",), 2: ("right",), 3: ("left", "right")}  # the gate's holding index -> hands


class EffortVeto(Veto):
    """A gate veto at a plan point over an effort limit or whose grip slips (``check`` "effort" | "grip");
    ``point`` is the plan point, which the gate turns into its sample index."""

    def __init__(self, check: str, message: str, point: int):
        super().__init__(check, message)
        self.point = point


@dataclass(frozen=True)
class HandLimits:
    tcp: str
    jaws: tuple[str, ...]
    #: (friction, force_n, patch_radius_m), or None: a rigid hand (no grip check)
    grip: tuple[float, float, float] | None


@dataclass(frozen=True)
class EffortSpec:
    """What the check reads of the robot's spec: hands (TCP, jaw joints, grip) and effort limit overrides."""

    hands: dict[str, HandLimits]
    effort_limits: dict[str, float]


def effort_spec(spec: dict[str, Any]) -> EffortSpec:
    """The spec's hands (TCP frame, jaw joints, grip) and effort limits, from a ``regrasp.robot/1`` spec file."""
    grip = spec.get("grip")
    g = None if not grip else (float(grip["friction"]), float(grip["force_n"]), float(grip["patch_radius_m"]))
    hands: dict[str, HandLimits] = {}
    for side in ("left", "right"):
        hand = spec["hands"][side]
        jaw = hand.get("jaw")
        jaws = tuple(jaw.get("joints", ())) if jaw else ()
        hands[side] = HandLimits(tcp=hand["frame"], jaws=jaws, grip=g if jaws else None)
    return EffortSpec(hands=hands, effort_limits={k: float(v) for k, v in (spec.get("effort_limits") or {}).items()})


@lru_cache(maxsize=8)
def urdf_efforts(path: str) -> dict[str, float]:
    """``<limit effort>`` per joint of a URDF file (joints without one are absent)."""
    out = {}
    for joint in ET.parse(path).getroot().iter("joint"):
        lim = joint.find("limit")
        if lim is not None and "effort" in lim.attrib:
            out[joint.attrib["name"]] = float(lim.attrib["effort"])
    return out


#: the holders' tuples by the gate's holding index (0 none, 1 left, 2 right, 3 both)
_HOLDING_INDEX = {hands: k for k, hands in _HOLDERS.items()}


def holder_shares(holders: np.ndarray | list[tuple[str, ...]]) -> dict[str, np.ndarray]:
    """The share of the held object's weight (0, 0.5 or 1) per hand and point, from the gate's holding index
    per point (or the holding hands' tuples per point)."""
    index = np.asarray([_HOLDING_INDEX[tuple(h)] for h in holders] if isinstance(holders, list) else holders, dtype=int)
    both = index == 3
    return {"left": np.where(index == 1, 1.0, np.where(both, 0.5, 0.0)),
            "right": np.where(index == 2, 1.0, np.where(both, 0.5, 0.0))}


def static_torques(model: UrdfModel, joint_order: tuple[str, ...], Q: np.ndarray, base_pose: np.ndarray,
                   holders: np.ndarray | list[tuple[str, ...]], object_com: np.ndarray, object_mass: float,
                   tcp: dict[str, str], soles: list[str], gravity: float
                   ) -> tuple[dict[str, np.ndarray], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Static torques (N,) of every movable joint of the URDF by name (mimic joints too), and the world
    (R (N, 3, 3), p (N, 3)) of the TCP and sole links, for plan points Q (N, n) in ``joint_order``.

    ``holders``: per point, the gate's holding index or the tuple of holding hands; ``object_com`` (N, 3)
    the held object's CoM. World frames are kept per component, R as (3, 3, m) and p as (3, m), each row
    contiguous, with m = 1 while every joint above a link stays still (plans move a few joints at a time)
    and m = N below a moving one. Gravity on a subtree is carried as its mass and first moment (the
    weights are all vertical); the held object's weight and the contact wrenches as forces and moments
    about the world origin on the links they act on.
    """
    n = len(Q)
    Qt = np.ascontiguousarray(np.asarray(Q, dtype=float).T)
    col = {name: i for i, name in enumerate(joint_order)}
    moving = np.any(Qt != Qt[:, :1], axis=1)
    # Each link's frame is an anchor's world frame (materialised: R (3, 3, m), p (3, m)) times a constant
    # transform; a link becomes an anchor only below a joint that moves, so most links cost one vector each.
    anchor_R = {model.root: quaternion_matrix(base_pose[3:])[:, :, None]}
    anchor_p = {model.root: np.asarray(base_pose[:3], float)[:, None]}
    rel: dict[str, tuple[str, np.ndarray, np.ndarray]] = {model.root: (model.root, np.eye(3), np.zeros(3))}
    axis_w: dict[str, np.ndarray] = {}
    origin_w: dict[str, np.ndarray] = {}
    for j in model.joints:  # parents before children
        a_link, Rr, pr = rel[j.parent]
        Rr_o, pr_o = Rr @ j.origin_rot, pr + Rr @ j.origin_xyz
        if j.type == "fixed":
            rel[j.child] = (a_link, Rr_o, pr_o)
            continue
        master, mult, off = j.mimic if j.mimic is not None else (j.name, 1.0, 0.0)
        c = col[master]
        RA, pA = anchor_R[a_link], anchor_p[a_link]
        axis_rel = Rr_o @ j.axis
        axis_w[j.name] = rotate(RA, axis_rel)
        origin_w[j.name] = pA + rotate(RA, pr_o)
        if not moving[c]:
            v = float(Qt[c, 0]) * mult + off
            rel[j.child] = ((a_link, Rr_o, pr_o + axis_rel * v) if j.type == "prismatic"
                            else (a_link, Rr_o @ _axis_rotation(j.axis, v), pr_o))
            continue
        value = Qt[c] * mult + off
        Ro = _times_constant(RA, Rr_o)
        if j.type == "prismatic":
            anchor_R[j.child], anchor_p[j.child] = Ro, origin_w[j.name] + axis_w[j.name] * value
        else:
            anchor_R[j.child], anchor_p[j.child] = _rotated_about(Ro, j.axis, value), origin_w[j.name]
        rel[j.child] = (j.child, np.eye(3), np.zeros(3))

    def world_point(link: str, local: np.ndarray) -> np.ndarray:
        a_link, Rr, pr = rel[link]
        return anchor_p[a_link] + rotate(anchor_R[a_link], pr + Rr @ local)

    def world_frame(link: str) -> tuple[np.ndarray, np.ndarray]:
        a_link, Rr, pr = rel[link]
        return _times_constant(anchor_R[a_link], Rr), anchor_p[a_link] + rotate(anchor_R[a_link], pr)

    # gravity: mass and first moment (sum of m c) per subtree; other forces: (F, M about the origin) per link
    mass = {name: link.mass for name, link in model.links.items() if link.mass > 0.0}
    first = {name: mass[name] * world_point(name, model.links[name].com_local) for name in mass}
    F: dict[str, np.ndarray] = {}
    M: dict[str, np.ndarray] = {}

    def add(link: str, f: np.ndarray, m: np.ndarray) -> None:
        F[link] = F[link] + f if link in F else f
        M[link] = M[link] + m if link in M else m

    obj_c = np.ascontiguousarray(np.asarray(object_com, dtype=float).T)
    shares = holder_shares(holders)
    held = shares["left"] + shares["right"]  # 1 while held (by one hand or both), else 0
    for side, share in shares.items():
        if object_mass > 0.0 and share.any():
            add(tcp[side], *_weight(obj_c, object_mass * share * gravity))
    total = model.total_mass + object_mass * held
    com = (sum(first.values()) + object_mass * held * obj_c) / total
    # contact wrenches: sum of forces = the total weight up, sum of moments about the origin = c x weight up
    w_up = total * gravity
    b = np.zeros((n, 6))
    b[:, 2] = w_up
    b[:, 3], b[:, 4] = com[1] * w_up, -com[0] * w_up  # c x (0, 0, W)
    sole_p = {sole: world_point(sole, np.zeros(3)) for sole in soles}
    w = _min_norm_contacts([sole_p[sole] for sole in soles], b)
    for k, sole in enumerate(soles):
        f, m = w[6 * k:6 * k + 3], w[6 * k + 3:6 * k + 6]
        add(sole, f, _cross(sole_p[sole], f) + m)
    torques: dict[str, np.ndarray] = {}
    for j in reversed(model.joints):  # children before parents: carry each subtree's sums up
        child = j.child
        if j.type != "fixed":
            a, o = axis_w[j.name], origin_w[j.name]
            tau = np.zeros(n)
            if child in mass:  # gravity: M - o x F = g (-(S_y - m o_y), S_x - m o_x, 0) for S = sum m c, m = sum m
                m_sub, S = mass[child], first[child]
                tau = tau - gravity * (a[1] * (S[0] - m_sub * o[0]) - a[0] * (S[1] - m_sub * o[1])) \
                    if j.type != "prismatic" else tau + gravity * m_sub * a[2]
            if child in F:
                Fc, Mc = F[child], M[child]
                tau = tau - ((a * Fc).sum(axis=0) if j.type == "prismatic" else (a * (Mc - _cross(o, Fc))).sum(axis=0))
            torques[j.name] = np.broadcast_to(tau, (n,))
        if child in mass:
            mass[j.parent] = mass.get(j.parent, 0.0) + mass[child]
            first[j.parent] = first[j.parent] + first[child] if j.parent in first else first[child]
        if child in F:
            add(j.parent, F[child], M[child])
    frames = {}
    for link in {*tcp.values(), *soles}:
        Rw, pw = world_frame(link)
        frames[link] = (np.broadcast_to(Rw.transpose(2, 0, 1), (n, 3, 3)), np.broadcast_to(pw.T, (n, 3)))
    return torques, frames


def _min_norm_contacts(sole_points: list[np.ndarray], b: np.ndarray) -> np.ndarray:
    """The minimum 2-norm contact wrenches (6 C, N) [force; moment] at the soles (points (3, m)) whose sum
    balances ``b`` (N, 6): forces summing to b[:3], moments about the origin to b[3:].

    w = A^T (A A^T)^-1 b, A of full row rank (each sole's force and moment blocks are identities); once
    for all points when the soles stay still (m = 1), else per point."""
    n, C = len(b), len(sole_points)
    m = max(ps.shape[1] for ps in sole_points)
    A = np.zeros((m, 6, 6 * C))
    for k, ps in enumerate(sole_points):
        ps = np.broadcast_to(ps, (3, m))
        A[:, 0:3, 6 * k:6 * k + 3] = np.eye(3)
        A[:, 3, 6 * k + 1], A[:, 3, 6 * k + 2] = -ps[2], ps[1]
        A[:, 4, 6 * k + 0], A[:, 4, 6 * k + 2] = ps[2], -ps[0]
        A[:, 5, 6 * k + 0], A[:, 5, 6 * k + 1] = -ps[1], ps[0]
        A[:, 3:6, 6 * k + 3:6 * k + 6] = np.eye(3)
    if m == 1:
        P = A[0].T @ np.linalg.inv(A[0] @ A[0].T)  # (6 C, 6)
        return P @ b.T
    y = np.linalg.solve(np.einsum("nij,nkj->nik", A, A), b[:, :, None])
    return np.einsum("nji,nj->in", A, y[:, :, 0])


def _weight(c: np.ndarray, weight: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A weight ``weight`` (N) acting down at points c (3, m): its force and its moment about the origin."""
    wz = -np.asarray(weight, dtype=float)
    f = np.zeros((3, max(c.shape[1], wz.size)))
    f[2] = wz
    m = np.zeros_like(f)
    m[0], m[1] = c[1] * wz, -c[0] * wz  # c x (0, 0, wz)
    return f, m


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of vectors per column, a (3, m) x b (3, k) (m, k = 1 or N)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _times_constant(R: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Rotations R (3, 3, m) times one constant rotation C (3, 3)."""
    if np.array_equal(C, np.eye(3)):
        return R
    return np.einsum("ikm,kj->ijm", R, C)


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """The rotation (3, 3) by ``angle`` about the unit ``axis`` (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _rotated_about(Ro: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Ro (3, 3, m) times the rotation by ``angle`` (k,) about the constant unit ``axis`` (in Ro's frame).

    About a principal axis (most URDF joints) it is two columns mixed by cos and sin; otherwise Rodrigues'
    matrix per angle."""
    c, s = np.cos(angle), np.sin(angle)
    m = max(Ro.shape[2], len(angle))
    k = int(np.argmax(np.abs(axis)))
    if abs(abs(axis[k]) - 1.0) < 1e-12 and np.count_nonzero(np.abs(axis) > 1e-15) == 1:
        s = s * np.sign(axis[k])
        i, j = (k + 1) % 3, (k + 2) % 3  # the rotation mixes columns i and j (right-handed: i -> j)
        out = np.empty((3, 3, m))
        out[:, k] = Ro[:, k]
        np.multiply(Ro[:, i], c, out=out[:, i])
        out[:, i] += Ro[:, j] * s
        np.multiply(Ro[:, j], c, out=out[:, j])
        out[:, j] -= Ro[:, i] * s
        return out
    a = axis
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    rot = np.eye(3)[:, :, None] + s * K[:, :, None] + (1.0 - c) * (K @ K)[:, :, None]  # (3, 3, k)
    return np.einsum("ikm,kjm->ijm", np.broadcast_to(Ro, (3, 3, m)), np.broadcast_to(rot, (3, 3, m)))


def check_effort_and_grip(model: UrdfModel, spec: dict[str, Any], joint_order: tuple[str, ...], Q: np.ndarray,
                          base_pose: np.ndarray, holding: np.ndarray, object_pose: np.ndarray, com_local: np.ndarray,
                          object_mass: float, feet: list[dict], gravity: float, tolerance: float = 1e-6) -> dict[str, Any]:
    """Raise :class:`EffortVeto` at the first plan point over an effort limit or whose grip slips; else the figures.

    ``holding``: the gate's index per point (0 none, 1 left, 2 right, 3 both); ``object_pose`` (N, 7)."""
    es = effort_spec(spec)
    efforts = urdf_efforts(str(model.path))
    jaws = {j for hand in es.hands.values() for j in hand.jaws}
    checked = [name for name in model.joint_names if name not in jaws]
    limits = {}
    for name in checked:
        lim = es.effort_limits.get(name, efforts.get(name))
        if lim is None or not math.isfinite(lim) or lim <= 0:
            raise EffortVeto("effort", f"joint {name} has no effort limit in the URDF or the robot spec", 0)
        limits[name] = lim
    shares = holder_shares(holding)
    obj_R = quaternion_matrix(object_pose[:, 3:])
    object_com = object_pose[:, :3] + obj_R @ com_local
    soles = [f["frame"] for f in feet if f.get("in_contact", True)]
    tcp = {side: hand.tcp for side, hand in es.hands.items()}
    torques, frames = static_torques(model, joint_order, Q, base_pose, holding, object_com, object_mass, tcp, soles,
                                     gravity)
    # a mimic joint's torque adds to its master's (through the multiplier)
    wire = {name: torques[name].copy() for name in checked}
    for j in model.joints:
        if j.mimic is not None and j.mimic[0] in wire:
            wire[j.mimic[0]] += j.mimic[1] * torques[j.name]
    ratios = np.stack([np.abs(wire[name]) / limits[name] for name in checked]) if checked else np.zeros((1, len(Q)))
    ratio = ratios.max(axis=0)  # NaN propagates: a point with a non-finite torque is over
    over = np.flatnonzero(~(ratio <= 1.0 + tolerance))
    if over.size:
        i = int(over[0])
        name = checked[int(np.argmax(ratios[:, i]))] if checked else ""
        if not math.isfinite(ratio[i]):
            raise EffortVeto("effort", f"the static torques at point {i} are not finite numbers", i)
        raise EffortVeto("effort", f"joint {name} needs {abs(wire[name][i]):.1f} N*m at point {i}, over its effort "
                         f"limit {limits[name]:.1f} (ratio {ratio[i]:.3f})", i)
    grip_ratio = np.zeros(len(Q))
    for side, hand in es.hands.items():
        if hand.grip is None or object_mass <= 0.0:
            continue
        mu, force_n, radius = hand.grip
        share = object_mass * shares[side] * gravity
        Rt, pt = frames[hand.tcp]
        lever = object_com - pt
        # the share's weight (0, 0, -share) at the CoM: its moment about the TCP, on the closing (y) axis
        moment = np.cross(lever, np.stack([np.zeros_like(share), np.zeros_like(share), -share], axis=1))
        about = np.abs((moment * Rt[:, :, 1]).sum(axis=1))
        r = np.maximum(share / (2 * mu * force_n), about / (2 * mu * force_n * radius))
        bad = np.flatnonzero(~(r <= 1.0 + tolerance))
        if bad.size:
            i = int(bad[0])
            raise EffortVeto("grip", f"the {side} hand's grip slips at point {i}: load {share[i]:.1f} N against "
                             f"{2 * mu * force_n:.1f} N, moment {about[i]:.2f} N*m about the closing axis against "
                             f"{2 * mu * force_n * radius:.2f} N*m", i)
        grip_ratio = np.maximum(grip_ratio, r)
    return {"max_effort_ratio": float(ratio.max()) if len(ratio) else 0.0,
            "max_grip_ratio": float(grip_ratio.max()) if len(grip_ratio) else 0.0}
