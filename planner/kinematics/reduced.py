"""Exact batched CoM and frame poses of a robot whose joints a batch moves only in part.

The planner's T-RRT and the stability survey evaluate tens of thousands of configurations of
one robot in one stance. With the stance fixed, the feet and pelvis never move, and every joint
that a batch does not vary (legs, neck, the idle arm, the jaws) only carries its links rigidly
along with the nearest moving joint above it. :class:`ReducedKinematics` folds every fixed part
into a constant world mass or into the composite body of the moving joint it hangs from, so a
batch walks only the moving joints (12 for waist + one arm instead of 39 pinocchio joints). It is
exact, not an approximation: the tests compare it with pinocchio's ``centerOfMass`` to 1e-9.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pinocchio as pin

from planner.compiled.tree_kernels import tree_spec, walk
from planner.kinematics.joint_table import affine, joint_table
from planner.robot.model import RobotModel
from planner.stability.robot_com import BodyMasses, fold_masses, robot_com_batch

_I3 = np.eye(3)


@dataclass(frozen=True)
class _Step:
    jid: int
    anchor: int  # index of the parent step, -1 for the fixed world part
    R_rel: np.ndarray | None  # None: identity
    p_rel: np.ndarray
    kind: str  # "R", "P", "RU", "PU"
    axis_index: int
    axis: np.ndarray
    col: int
    mult: float
    offset: float
    mass: float
    lever: np.ndarray  # composite CoM in the joint frame


class ReducedKinematics:
    """Exact batched CoM and frame poses when only ``active`` wire columns vary.

    Built once for a base pose, a reference configuration (giving the values of
    every fixed joint) and the active columns; evaluating a batch then costs a
    few vector operations per active joint.
    """

    def __init__(
        self,
        robot: RobotModel,
        base_pose: np.ndarray,
        q_ref: np.ndarray,
        active: Sequence[int],
        frames: Sequence[str] = (),
        data: pin.Data | None = None,
    ):
        """``data``: a pinocchio scratch buffer to reuse (creating one costs more than the rest)."""
        table = joint_table(robot)
        rows = table.rows
        if data is None:
            data = robot.pin_model.createData()
        self.robot = robot
        self.active = np.array(sorted(set(int(a) for a in active)), dtype=int)
        self.q_ref = np.array(q_ref, dtype=float)
        active_set = set(self.active.tolist())
        pin.forwardKinematics(robot.pin_model, data, robot.to_pin_q(np.asarray(base_pose, float), self.q_ref))
        oMi = list(data.oMi)  # one copy of the vector (each indexed access would copy it again)

        # anchor[j]: step index of the nearest moving joint at or above j; -1 = fixed in the world.
        anchor = [-1] * table.njoints
        steps_raw: list[dict] = []
        for jid in range(1, table.njoints):
            row = rows[jid]
            parent_anchor = anchor[row.parent] if jid > 1 else -1
            col, mult, off = row.source
            if jid < 2 or col not in active_set:
                anchor[jid] = parent_anchor
                continue
            kind, ax = row.kind, row.axis_index
            if kind is None:
                raise ValueError(f"joint {row.name!r} of type {row.type_name} is not supported")
            axis = row.axis / np.linalg.norm(row.axis)
            parent_frame = oMi[steps_raw[parent_anchor]["jid"]] if parent_anchor >= 0 else pin.SE3.Identity()
            rel = parent_frame.actInv(oMi[row.parent] * row.placement)
            R_rel = np.array(rel.rotation)
            steps_raw.append(dict(
                jid=jid, anchor=parent_anchor, R_rel=None if np.abs(R_rel - _I3).max() < 1e-14 else R_rel,
                p_rel=np.array(rel.translation), kind=kind, axis_index=ax, axis=axis,
                col=col, mult=mult, offset=off, mass=0.0, moment=np.zeros(3),
            ))
            anchor[jid] = len(steps_raw) - 1

        bodies = []
        for jid in range(1, table.njoints):
            m, lever = rows[jid].mass, rows[jid].lever
            if m <= 0.0:
                continue
            c_world = oMi[jid].act(lever)
            a = anchor[jid]
            bodies.append((a, m, c_world if a < 0 else oMi[steps_raw[a]["jid"]].actInv(c_world)))
        slot_mass, slot_lever, fixed_mass, fixed_moment = fold_masses(bodies, len(steps_raw))
        self.total_mass = float(fixed_mass + sum(slot_mass.tolist()))
        self._steps = [
            _Step(
                jid=s["jid"], anchor=s["anchor"], R_rel=s["R_rel"], p_rel=s["p_rel"], kind=s["kind"],
                axis_index=s["axis_index"], axis=s["axis"], col=s["col"], mult=s["mult"], offset=s["offset"],
                mass=float(slot_mass[k]), lever=slot_lever[k],
            )
            for k, s in enumerate(steps_raw)
        ]
        steps = self._steps
        self._tree = tree_spec(parent=[s.anchor for s in steps], R0=[s.R_rel for s in steps], p0=[s.p_rel for s in steps],
                               kind=[s.kind for s in steps], axis_index=[max(s.axis_index, 0) for s in steps],
                               axis=[s.axis for s in steps], col=[s.col for s in steps], mult=[s.mult for s in steps],
                               offset=[s.offset for s in steps])
        slots = np.array([k for k, s in enumerate(steps) if s.mass > 0.0], dtype=np.int64)
        self.masses = BodyMasses(slots=slots, mass=np.array([steps[k].mass for k in slots], dtype=float),
                                 lever=np.array([steps[k].lever for k in slots], dtype=float).reshape(-1, 3),
                                 base_moment=fixed_moment, total_mass=self.total_mass)
        self._frames: dict[str, tuple[int, np.ndarray, np.ndarray]] = {}
        for name in frames:
            if name not in table.frames:
                robot.frame_id(name)  # raises the error that lists the frames
            parent_joint, placement = table.frames[name]
            world = oMi[parent_joint] * placement
            a = anchor[parent_joint]
            rel = oMi[self._steps[a].jid].actInv(world) if a >= 0 else world
            self._frames[name] = (a, np.array(rel.rotation), np.array(rel.translation))

    @property
    def frames(self) -> tuple[str, ...]:
        return tuple(self._frames)

    def _forward(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (S, 3, 3, N) and positions (S, 3, N) of every moving joint frame."""
        n = Q.shape[0]
        R = np.empty((self._tree.size, 3, 3, n))
        p = np.empty((self._tree.size, 3, n))
        walk(self._tree, Q, R, p)
        return R, p

    def _com(self, Rs: np.ndarray, ps: np.ndarray) -> np.ndarray:
        return robot_com_batch(Rs, ps, self.masses)

    def _frame(self, Rs: list[np.ndarray], ps: list[np.ndarray], name: str, n: int) -> tuple[np.ndarray, np.ndarray]:
        a, R0, p0 = self._frames[name]
        if a < 0:
            return np.repeat(R0[None], n, axis=0), np.repeat(p0[None], n, axis=0)
        R = np.einsum("ijn,jk->nik", Rs[a], R0)
        p = affine(ps[a], Rs[a], p0).T
        return R, p

    def com(self, Q: np.ndarray) -> np.ndarray:
        """Robot CoM in the world, (N, 3)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        Rs, ps = self._forward(Q)
        return self._com(Rs, ps)

    def com_and_frames(self, Q: np.ndarray, frames: Sequence[str] | None = None) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
        """Robot CoM (N, 3) and world (R (N, 3, 3), p (N, 3)) of the requested frames (default: all built)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        n = Q.shape[0]
        Rs, ps = self._forward(Q)
        names = self.frames if frames is None else frames
        return self._com(Rs, ps), {f: self._frame(Rs, ps, f, n) for f in names}
