"""A small humanoid made up for the tests: its URDF (boxes, no sole or TCP frames) and a spec file for it.

Pelvis, two 6-joint legs, a waist yaw, a chest with a head, two 6-joint arms, each hand a palm and two
fingers on a prismatic jaw (the second finger a mimic), or with ``rigid`` a flat pad fixed to the wrist
(no jaw: the spec says ``jaw: null``). The spec creates the sole and TCP frames.
"""

from __future__ import annotations

import copy
from pathlib import Path

import yaml

LEG = [("hip_y", "z"), ("hip_r", "x"), ("hip_p", "y"), ("knee", "y"), ("ankle_p", "y"), ("ankle_r", "x")]
ARM = [("sh_p", "y"), ("sh_r", "x"), ("sh_y", "z"), ("elbow", "y"), ("wr_y", "z"), ("wr_p", "y")]
AXES = {"x": "1 0 0", "y": "0 1 0", "z": "0 0 1"}


def _box_link(name: str, mass: float, size: tuple[float, float, float], center: tuple[float, float, float]) -> str:
    a, b, c = size
    ixx, iyy, izz = mass * (b * b + c * c) / 12, mass * (a * a + c * c) / 12, mass * (a * a + b * b) / 12
    xyz = " ".join(repr(v) for v in center)
    return (f'<link name="{name}"><inertial><origin xyz="{xyz}"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial>'
            f'<collision><origin xyz="{xyz}"/><geometry><box size="{a} {b} {c}"/></geometry></collision></link>')


def _joint(name, parent, child, xyz, axis, lower=-2.0, upper=2.0, kind="revolute", effort=300.0, mimic=None) -> str:
    lim = f'<limit lower="{lower}" upper="{upper}" velocity="1.0"' + (f' effort="{effort}"/>' if effort else "/>")
    mim = f'<mimic joint="{mimic[0]}" multiplier="{mimic[1]}"/>' if mimic else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}"/><axis xyz="{AXES[axis] if axis in AXES else axis}"/>{lim}{mim}</joint>')


def small_humanoid_urdf(no_effort: str | None = None, rigid: bool = False) -> str:
    """The URDF text; ``no_effort``: a joint written without an effort limit; ``rigid``: pads for hands."""
    parts = ['<robot name="small_humanoid">', _box_link("pelvis", 8.0, (0.2, 0.3, 0.12), (0, 0, 0))]

    def J(*args, **kw):
        if args[0] == no_effort:
            kw["effort"] = None
        parts.append(_joint(*args, **kw))

    for side, y in (("l", 0.1), ("r", -0.1)):
        parent = "pelvis"
        offsets = [f"0 {y} -0.06", "0 0 0", "0 0 0", "0 0 -0.4", "0 0 -0.4", "0 0 0"]
        for k, ((jn, ax), off) in enumerate(zip(LEG, offsets)):
            link = f"{side}_leg{k + 1}"
            size, center, mass = (0.06, 0.06, 0.06), (0, 0, 0), 0.5
            if jn == "hip_p":
                size, center, mass = (0.1, 0.1, 0.36), (0, 0, -0.2), 4.0
            if jn == "knee":
                size, center, mass = (0.08, 0.08, 0.36), (0, 0, -0.2), 2.5
            if jn == "ankle_r":
                size, center, mass = (0.22, 0.12, 0.06), (0.02, 0, -0.05), 1.0
            parts.append(_box_link(link, mass, size, center))
            lo, hi = (-0.1, 2.4) if jn == "knee" else (-1.5, 1.5)
            J(f"{side}_{jn}", parent, link, off, ax, lower=lo, upper=hi)
            parent = link
    parts.append(_box_link("chest", 14.0, (0.22, 0.32, 0.4), (0, 0, 0.22)))
    J("waist_y", "pelvis", "chest", "0 0 0.08", "z", lower=-1.0, upper=1.0)
    parts.append(_box_link("head", 3.0, (0.16, 0.16, 0.2), (0, 0, 0.12)))
    J("neck_y", "chest", "head", "0 0 0.45", "z", lower=-1.0, upper=1.0)
    for side, y in (("l", 0.21), ("r", -0.21)):
        parent = "chest"
        offsets = [f"0 {y} 0.38", "0 0 0", "0 0 0", "0 0 -0.28", "0 0 0", "0 0 -0.24"]
        for k, ((jn, ax), off) in enumerate(zip(ARM, offsets)):
            link = f"{side}_arm{k + 1}"
            size, center, mass = (0.05, 0.05, 0.05), (0, 0, 0), 0.3
            if jn == "sh_y":
                size, center, mass = (0.07, 0.07, 0.24), (0, 0, -0.14), 1.8
            if jn == "wr_y":
                size, center, mass = (0.06, 0.06, 0.2), (0, 0, -0.12), 1.0
            if jn == "wr_p":
                size, center, mass = (0.05, 0.09, 0.04), (0, 0, -0.03), 0.4
            parts.append(_box_link(link, mass, size, center))
            lo, hi = (-2.4, 0.0) if jn == "elbow" else (-2.0, 2.0)
            J(f"{side}_{jn}", parent, link, off, ax, lower=lo, upper=hi)
            parent = link
        if rigid:
            parts.append(_box_link(f"{side}_pad", 0.1, (0.06, 0.08, 0.02), (0, 0, -0.01)))  # face at z = -0.12
            parts.append(f'<joint name="{side}_pad_fixed" type="fixed"><parent link="{side}_arm6"/>'
                         f'<child link="{side}_pad"/><origin xyz="0 0 -0.10"/></joint>')
            continue
        for finger, sign in (("a", 1.0), ("b", -1.0)):
            link = f"{side}_finger_{finger}"
            parts.append(_box_link(link, 0.05, (0.03, 0.01, 0.1), (0, 0.005 * sign, -0.1)))  # inner face at the jaw
            J(f"{side}_jaw" if finger == "a" else f"{side}_jaw_mimic", f"{side}_arm6", link, "0 0 0",
              f"0 {sign} 0", lower=0.0, upper=0.045, kind="prismatic", effort=50.0,
              mimic=None if finger == "a" else (f"{side}_jaw", 1.0))
    parts.append("</robot>")
    return "\n".join(parts)


SPEC = {
    "schema": "regrasp.robot/1",
    "name": "small_humanoid",
    "description": "a humanoid made up for the tests",
    "urdf": "small_humanoid.urdf",
    "feet": {side: {"frame": f"{side[0]}_sole", "link": f"{side[0]}_leg6", "pose_in_link": [0.02, 0, -0.08, 0, 0, 0, 1],
                    "size": [0.22, 0.12]} for side in ("left", "right")},
    "hands": {side: {"frame": f"{side[0]}_tcp", "link": f"{side[0]}_arm6", "pose_in_link": [0, 0, -0.13, 1, 0, 0, 0],
                     "jaw": {"joints": [f"{side[0]}_jaw"], "open": 0.045, "closed": 0.0, "width_m": [0.0, 0.09]}}
              for side in ("left", "right")},
    "upright": {"pelvis_height_m": 0.84, "foot_y_m": 0.1},
    "acceleration_limits": {"default": 2.0},
    "effort_limits": {"l_knee": 250.0, "r_knee": 250.0},
    "grip": {"friction": 0.6, "force_n": 200.0, "patch_radius_m": 0.015},
    "default_posture_rad": {"l_sh_r": 0.2, "r_sh_r": -0.2, "l_elbow": -0.4, "r_elbow": -0.4, "l_jaw": 0.045,
                            "r_jaw": 0.045},
}


def rigid_hands(spec: dict) -> None:
    """Edit a copy of :data:`SPEC` for the URDF written with ``rigid``: no jaws, the TCP on each pad's face."""
    for side, hand in spec["hands"].items():
        hand.update(jaw=None, pose_in_link=[0, 0, -0.12, 1, 0, 0, 0])
    spec.pop("grip")
    for joint in ("l_jaw", "r_jaw"):
        spec["default_posture_rad"].pop(joint)


def write_small_humanoid(folder: Path, spec_changes=None, no_effort: str | None = None, rigid: bool = False) -> Path:
    """Write the URDF and a spec file (``spec_changes(spec)`` edits a copy first) to ``folder``; the spec's path.
    ``rigid``: the pad hands' URDF and spec (:func:`rigid_hands`)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "small_humanoid.urdf").write_text(small_humanoid_urdf(no_effort, rigid))
    spec = copy.deepcopy(SPEC)
    if rigid:
        rigid_hands(spec)
    if spec_changes is not None:
        spec_changes(spec)
    path = folder / "small_humanoid.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path
