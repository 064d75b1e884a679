"""The one adapter from the pinocchio model to the compiled kinematics: the robot's joint table.

Read once per robot model (pinocchio's vector accessors copy on every index) and kept with the
model (:meth:`planner.robot.model.RobotModel.derived`): per joint id its parent, its kind and
axis in the terms of :mod:`planner.compiled.tree_kernels`, the wire column that drives it (with
the mimic multiplier and offset), its placement in the parent frame, its mass and lever; and
every frame's parent joint and placement. :class:`~planner.kinematics.batch.BatchKinematics`
(the whole tree) and :class:`~planner.kinematics.reduced.ReducedKinematics` (only the joints a
batch moves) both build their trees from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from planner.robot.model import RobotModel

#: pinocchio joint model -> (kernel kind, axis index; -1 for an unaligned axis).
JOINT_KINDS = {
    "JointModelRX": ("R", 0), "JointModelRY": ("R", 1), "JointModelRZ": ("R", 2),
    "JointModelPX": ("P", 0), "JointModelPY": ("P", 1), "JointModelPZ": ("P", 2),
    "JointModelRevoluteUnaligned": ("RU", -1), "JointModelPrismaticUnaligned": ("PU", -1),
}


@dataclass(frozen=True)
class JointRow:
    """One pinocchio joint as the kernels see it."""

    jid: int
    name: str
    parent: int
    #: kernel kind ("R", "P", "RU", "PU"), or None for a joint type the kernels do not support
    kind: str | None
    axis_index: int
    #: the joint axis in its own frame, as pinocchio stores it (a unit axis for aligned joints)
    axis: np.ndarray
    #: pinocchio's type name (for the error that names an unsupported joint)
    type_name: str
    #: (wire column, multiplier, offset) that drive it; (-1, 1.0, 0.0) for the root and undriven joints
    source: tuple[int, float, float]
    placement: pin.SE3
    mass: float
    lever: np.ndarray


@dataclass(frozen=True)
class JointTable:
    """Every joint of a robot model by pinocchio id (0: the universe, 1: the floating base), and its frames."""

    rows: tuple[JointRow, ...]
    #: frame name -> (parent joint id, placement in that joint's frame)
    frames: dict[str, tuple[int, pin.SE3]]

    @property
    def njoints(self) -> int:
        return len(self.rows)


def joint_table(robot: RobotModel) -> JointTable:
    """The robot model's joint table, derived once and kept with the model."""
    return robot.derived("joint_table", lambda: _build(robot))


def _build(robot: RobotModel) -> JointTable:
    model = robot.pin_model
    source_of_pinq = {int(p): (int(s), float(m), float(o))
                      for p, s, m, o in zip(robot.pin_q_index, robot.q_source, robot.q_mult, robot.q_offset)}
    idx_qs, parents, joints, inertias = list(model.idx_qs), list(model.parents), list(model.joints), list(model.inertias)
    placements, names = list(model.jointPlacements), list(model.names)
    rows = []
    for jid, jm in enumerate(joints):
        short = jm.shortname()
        kind, ax = JOINT_KINDS.get(short, (None, -1))
        if kind in ("R", "P"):
            axis = np.eye(3)[ax]
        elif kind in ("RU", "PU"):
            inner = jm.extract()
            axis = np.array(inner.axis if hasattr(inner, "axis") else jm.axis, dtype=float)
        else:
            axis = np.zeros(3)
        source = source_of_pinq.get(int(idx_qs[jid]), (-1, 1.0, 0.0)) if jid >= 2 else (-1, 1.0, 0.0)
        rows.append(JointRow(jid=jid, name=names[jid], parent=int(parents[jid]), kind=kind, axis_index=ax, axis=axis,
                             type_name=short, source=source, placement=placements[jid].copy(),
                             mass=float(inertias[jid].mass), lever=np.array(inertias[jid].lever)))
    frames = {f.name: (int(f.parentJoint), f.placement.copy()) for f in model.frames}
    return JointTable(rows=tuple(rows), frames=frames)


def affine(p: np.ndarray, R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """p + R v for a constant vector v, over a batch: p (3, N), R (3, 3, N)."""
    out = p.copy()
    for j in range(3):
        if v[j] != 0.0:
            out += R[:, j] * v[j]
    return out
