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

from .urdf_kinematics import UrdfModel, quaternion_matrix

_HOLDERS = {0: (), 1: ("left",), 2: ("right",), 3: ("left", "right")}  # the gate's holding index -> hands


class EffortVeto(Exception):
    """A point over an effort limit or a slipping grip: ``check`` ("effort" | "grip"), the point, the message."""

    def __init__(self, check: str, message: str, point: int):
        super().__init__(message)
        self.check = check
        self.message = message
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
    """The spec's hands and limits, from either spec layout (``arms`` with a gripper, or ``hands`` with jaws)."""
    grip = spec.get("grip")
    g = None if not grip else (float(grip["friction"]), float(grip["force_n"]), float(grip["patch_radius_m"]))
    hands: dict[str, HandLimits] = {}
    for side in ("left", "right"):
        if "hands" in spec:
            hand = spec["hands"][side]
            jaw = hand.get("jaw")
            jaws = tuple(jaw.get("joints", ())) if jaw else ()
            hands[side] = HandLimits(tcp=hand["frame"], jaws=jaws, grip=g if jaws else None)
        else:
            arm = spec["arms"][side]
            gripper = arm.get("gripper")
            jaws = (gripper["joint"],) if gripper else ()
            hands[side] = HandLimits(tcp=arm["tcp"], jaws=jaws, grip=g if jaws else None)
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


def static_torques(model: UrdfModel, joint_order: tuple[str, ...], Q: np.ndarray, base_pose: np.ndarray,
                   holders: list[tuple[str, ...]], object_com: np.ndarray, object_mass: float,
                   tcp: dict[str, str], soles: list[str], gravity: float
                   ) -> tuple[dict[str, np.ndarray], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Static torques (N,) of every movable joint of the URDF by name (mimic joints too), and the world
    (R, p) of every link, for plan points Q (N, n) in ``joint_order``.

    ``holders[i]`` names the hands holding at point i; ``object_com`` (N, 3) the held object's CoM."""
    n = len(Q)
    col = {name: i for i, name in enumerate(joint_order)}
    R = {model.root: np.repeat(quaternion_matrix(base_pose[3:])[None], n, axis=0)}
    p = {model.root: np.repeat(np.asarray(base_pose[:3], float)[None], n, axis=0)}
    axis_w: dict[str, np.ndarray] = {}
    for j in model.joints:  # parents before children
        Rp, pp = R[j.parent], p[j.parent]
        Ro = Rp @ j.origin_rot
        po = pp + Rp @ j.origin_xyz
        if j.type == "fixed":
            R[j.child], p[j.child] = Ro, po
            continue
        master, mult, off = j.mimic if j.mimic is not None else (j.name, 1.0, 0.0)
        value = Q[:, col[master]] * mult + off
        a = j.axis
        axis_w[j.name] = Ro @ a
        if j.type == "prismatic":
            R[j.child], p[j.child] = Ro, po + axis_w[j.name] * value[:, None]
        else:
            c, s = np.cos(value), np.sin(value)
            K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
            rot = (np.eye(3)[None] + s[:, None, None] * K[None] + (1.0 - c)[:, None, None] * (K @ K)[None])
            R[j.child], p[j.child] = Ro @ rot, po
    # forces (world) and moments about the world origin acting on each link
    F = {name: np.zeros((n, 3)) for name in model.links}
    M = {name: np.zeros((n, 3)) for name in model.links}
    down = np.array([0.0, 0.0, -gravity])
    for name, link in model.links.items():
        if link.mass > 0.0:
            c = p[name] + R[name] @ link.com_local
            f = link.mass * down
            F[name] += f
            M[name] += np.cross(c, f)
    total = model.total_mass + object_mass * np.array([1.0 if h else 0.0 for h in holders])
    com_moment = sum(link.mass * (p[name] + R[name] @ link.com_local) for name, link in model.links.items()
                     if link.mass > 0.0)
    for i, hands in enumerate(holders):
        for side in hands:
            f = object_mass / len(hands) * down
            F[tcp[side]][i] += f
            M[tcp[side]][i] += np.cross(object_com[i], f)
        if hands:
            com_moment[i] = com_moment[i] + object_mass * object_com[i]
    # contact wrenches: sum of forces = total weight up, sum of moments about the origin = c x weight
    C = len(soles)
    A = np.zeros((n, 6, 6 * C))
    for k, sole in enumerate(soles):
        ps = p[sole]
        A[:, 0:3, 6 * k:6 * k + 3] = np.eye(3)
        A[:, 3, 6 * k + 1], A[:, 3, 6 * k + 2] = -ps[:, 2], ps[:, 1]
        A[:, 4, 6 * k + 0], A[:, 4, 6 * k + 2] = ps[:, 2], -ps[:, 0]
        A[:, 5, 6 * k + 0], A[:, 5, 6 * k + 1] = -ps[:, 1], ps[:, 0]
        A[:, 3:6, 6 * k + 3:6 * k + 6] = np.eye(3)
    up = np.zeros((n, 3))
    up[:, 2] = total * gravity
    b = np.concatenate([up, np.cross(com_moment / total[:, None], up)], axis=1)
    w = (np.linalg.pinv(A) @ b[:, :, None])[:, :, 0]
    for k, sole in enumerate(soles):
        f, m = w[:, 6 * k:6 * k + 3], w[:, 6 * k + 3:6 * k + 6]
        F[sole] += f
        M[sole] += np.cross(p[sole], f) + m
    torques: dict[str, np.ndarray] = {}
    for j in reversed(model.joints):  # children before parents: carry each subtree's sums up
        if j.type != "fixed":
            a = axis_w[j.name]
            if j.type == "prismatic":
                tau = -(a * F[j.child]).sum(axis=1)
            else:
                o = p[j.child]
                tau = -(a * (M[j.child] - np.cross(o, F[j.child]))).sum(axis=1)
            torques[j.name] = tau
        F[j.parent] += F[j.child]
        M[j.parent] += M[j.child]
    return torques, {k: (R[k], p[k]) for k in R}


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
    holders = [_HOLDERS[int(h)] for h in holding]
    obj_R = quaternion_matrix(object_pose[:, 3:])
    object_com = object_pose[:, :3] + obj_R @ com_local
    soles = [f["frame"] for f in feet if f.get("in_contact", True)]
    tcp = {side: hand.tcp for side, hand in es.hands.items()}
    torques, frames = static_torques(model, joint_order, Q, base_pose, holders, object_com, object_mass, tcp, soles,
                                        gravity)
    # a mimic joint's torque adds to its master's (through the multiplier)
    wire = {name: torques[name].copy() for name in checked}
    for j in model.joints:
        if j.mimic is not None and j.mimic[0] in wire:
            wire[j.mimic[0]] += j.mimic[1] * torques[j.name]
    ratio = np.zeros(len(Q))
    worst_joint = np.full(len(Q), "", dtype=object)
    for name in checked:
        r = np.abs(wire[name]) / limits[name]
        worse = r > ratio
        ratio = np.where(worse, r, ratio)
        worst_joint[worse] = name
    over = np.flatnonzero(ratio > 1.0 + tolerance)
    if over.size:
        i = int(over[0])
        name = worst_joint[i]
        raise EffortVeto("effort", f"joint {name} needs {abs(wire[name][i]):.1f} N*m at point {i}, over its effort "
                         f"limit {limits[name]:.1f} (ratio {ratio[i]:.3f})", i)
    grip_ratio = np.zeros(len(Q))
    for side, hand in es.hands.items():
        if hand.grip is None or object_mass <= 0.0:
            continue
        mu, force_n, radius = hand.grip
        share = np.array([object_mass / len(h) if side in h else 0.0 for h in holders]) * gravity
        Rt, pt = frames[hand.tcp]
        lever = object_com - pt
        # the share's weight (0, 0, -share) at the CoM: its moment about the TCP, on the closing (y) axis
        moment = np.cross(lever, np.stack([np.zeros_like(share), np.zeros_like(share), -share], axis=1))
        about = np.abs((moment * Rt[:, :, 1]).sum(axis=1))
        r = np.maximum(share / (2 * mu * force_n), about / (2 * mu * force_n * radius))
        bad = np.flatnonzero(r > 1.0 + tolerance)
        if bad.size:
            i = int(bad[0])
            raise EffortVeto("grip", f"the {side} hand's grip slips at point {i}: load {share[i]:.1f} N against "
                             f"{2 * mu * force_n:.1f} N, moment {about[i]:.2f} N*m about the closing axis against "
                             f"{2 * mu * force_n * radius:.2f} N*m", i)
        grip_ratio = np.maximum(grip_ratio, r)
    return {"max_effort_ratio": float(ratio.max()) if len(ratio) else 0.0,
            "max_grip_ratio": float(grip_ratio.max()) if len(grip_ratio) else 0.0}
