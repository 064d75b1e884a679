"""foxglove.JointStates and foxglove.FrameTransforms bodies from joint positions and the URDF tree."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from .encoding import stamp
from .markers import quat, v3
from .settings import AuditError
from .urdf_frames import WORLD_FRAME, UrdfTree, joint_transforms


def joint_states_body(joint_names: Sequence[str], q: Sequence[float], velocity: Sequence[float] | None,
                      ns: int) -> dict[str, Any]:
    """One instant of named joint positions (and velocities)."""
    if len(joint_names) != len(q):
        raise AuditError(f"{len(joint_names)} joint names but {len(q)} positions")
    if velocity is not None and len(velocity) != len(q):
        raise AuditError(f"{len(q)} positions but {len(velocity)} velocities")
    joints = []
    for i, name in enumerate(joint_names):
        joint: dict[str, Any] = {"name": str(name), "position": float(q[i])}
        if velocity is not None:
            joint["velocity"] = float(velocity[i])
        joints.append(joint)
    return {"timestamp": stamp(ns), "joints": joints}


def tf_body(tree: UrdfTree | None, positions: Mapping[str, float], base_pose: Sequence[float] | None, prefix: str,
            ns: int) -> dict[str, Any] | None:
    """World -> root link at ``base_pose`` and every joint's transform, frames under ``prefix``; None without a model."""
    if tree is None:
        return None
    if base_pose is not None and len(base_pose) != 7:
        raise AuditError(f"base pose must be [x, y, z, qx, qy, qz, qw], got {len(base_pose)} numbers")
    t = stamp(ns)
    transforms = []
    if base_pose is not None:
        transforms.append({"timestamp": t, "parent_frame_id": WORLD_FRAME, "child_frame_id": prefix + tree.root,
                           "translation": v3(base_pose[:3]), "rotation": quat(base_pose[3:7])})
    for parent, child, xyz, rot in joint_transforms(tree, positions):
        transforms.append({"timestamp": t, "parent_frame_id": prefix + parent, "child_frame_id": prefix + child,
                           "translation": v3(xyz), "rotation": quat(rot)})
    return {"transforms": transforms} if transforms else None
