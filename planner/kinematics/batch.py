"""Batched forward kinematics and CoM, many configurations per call.

The planner and the survey evaluate thousands of states at once; a Python loop
over pinocchio would spend its time in call overhead. This path walks the joint
tree once per batch in compiled code (:mod:`planner.compiled.tree_kernels`). It is
validated against pinocchio in the tests (1e-9).

Layout: structure of arrays, rotations ``(3, 3, N)`` and positions ``(3, N)`` per joint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.compiled.tree_kernels import ROOT_SLOT, tree_from_rows, walk
from planner.kinematics.joint_table import affine, joint_table
from planner.robot.model import RobotModel
from planner.stability.robot_com import BodyMasses, robot_com_batch
from planner.transforms import quat_to_matrix


@dataclass(frozen=True)
class _JointStep:
    jid: int
    parent: int
    rot0: np.ndarray | None  # None when the placement rotation is identity
    pos0: np.ndarray
    kind: str
    axis_index: int
    axis: np.ndarray
    q_col: int  # column of the wire q
    mult: float
    offset: float
    mass: float
    lever: np.ndarray

    def slot(self, parent: int) -> dict:
        """This joint as a :mod:`planner.compiled.tree_kernels` slot hanging from slot ``parent``."""
        return {"parent": parent, "R0": self.rot0, "p0": self.pos0, "kind": self.kind, "axis_index": max(self.axis_index, 0),
                "axis": self.axis, "col": self.q_col, "mult": self.mult, "offset": self.offset}


class BatchKinematics:
    """Vectorised FK/CoM over a batch of configurations of one robot."""

    def __init__(self, robot: RobotModel):
        self.robot = robot
        table = joint_table(robot)
        steps: list[_JointStep] = []
        for row in table.rows[2:]:
            if row.kind is None:
                raise ValueError(f"joint {row.name!r} of type {row.type_name} is not supported by the batch path")
            src, mult, off = row.source
            if src < 0:
                raise ValueError(f"joint {row.name!r} is driven by no configuration column")
            rot = np.array(row.placement.rotation)
            steps.append(
                _JointStep(
                    jid=row.jid, parent=row.parent,
                    rot0=None if np.allclose(rot, np.eye(3), atol=1e-15) else rot,
                    pos0=np.array(row.placement.translation), kind=row.kind,
                    axis_index=row.axis_index, axis=row.axis, q_col=src, mult=mult, offset=off,
                    mass=row.mass, lever=row.lever,
                )
            )
        self._steps = steps
        root = table.rows[1]
        self._root_mass = root.mass
        self._root_lever = root.lever
        self.total_mass = float(sum(s.mass for s in steps) + self._root_mass)
        self._njoints = table.njoints
        self._base: tuple[bytes, np.ndarray | None] = (b"", None)  # the last base pose and its rotation
        # The tree by joint id; id 1 (the floating base) is filled by forward(), id 0 (the universe) unused.
        self._tree = tree_from_rows([ROOT_SLOT, ROOT_SLOT, *(s.slot(s.parent) for s in steps)])
        massive = [(1, self._root_mass, self._root_lever)] + [(s.jid, s.mass, s.lever) for s in steps if s.mass > 0]
        self.masses = BodyMasses(slots=np.array([m[0] for m in massive], dtype=np.int64), mass=np.array([m[1] for m in massive]),
                                 lever=np.array([m[2] for m in massive]).reshape(-1, 3), base_moment=np.zeros(3),
                                 total_mass=self.total_mass)
        self._frames = {name: (jid, np.array(pl.rotation), np.array(pl.translation)) for name, (jid, pl) in table.frames.items()}

    def forward(self, base_pose: np.ndarray, Q: np.ndarray) -> tuple[list, list]:
        """World rotations ``(3, 3, N)`` and positions ``(3, N)`` of every joint frame, by pinocchio joint id.

        ``base_pose``: the floating base's pose (7,), or one per configuration (N, 7). The entries are
        views of one ``(njoints, 3, 3, N)`` block (:func:`planner.compiled.tree_kernels.walk`)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        n = Q.shape[0]
        base_pose = np.asarray(base_pose, dtype=float)
        R = np.empty((self._njoints, 3, 3, n))
        p = np.empty((self._njoints, 3, n))
        if base_pose.ndim == 1:
            key = base_pose.tobytes()
            if key != self._base[0]:  # one stance per planner: its rotation is computed once
                self._base = (key, quat_to_matrix(base_pose[3:])[:, :, None])
            R[1] = self._base[1]
            p[1] = base_pose[:3, None]
        else:
            R[1] = np.moveaxis(quat_to_matrix(base_pose[:, 3:]), 0, 2)
            p[1] = base_pose[:, :3].T
        walk(self._tree, Q, R, p, first=2, root_varies=base_pose.ndim > 1)
        return [None, *R[1:]], [None, *p[1:]]

    def com(self, base_pose: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """Robot CoM in the world for each configuration: (N, 3)."""
        Rs, ps = self.forward(base_pose, Q)
        return self._com_from(Rs, ps)

    def com_from(self, Rs: list, ps: list) -> np.ndarray:
        """Robot CoM in the world (N, 3) from a :meth:`forward` result (its frames serve other checks too)."""
        return self._com_from(Rs, ps)

    def _com_from(self, Rs: list, ps: list) -> np.ndarray:
        R, p = frames_block(Rs), frames_block(ps)
        return robot_com_batch(R, p, self.masses)

    def frame(self, Rs: list, ps: list, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World (R (N, 3, 3), p (N, 3)) of a named frame from a ``forward`` result."""
        try:
            jid, R0, p0 = self._frames[name]
        except KeyError:
            raise ValueError(f"unknown frame {name!r}") from None
        R = _rotate(Rs[jid], R0)
        p = affine(ps[jid], Rs[jid], p0)
        return np.moveaxis(R, 2, 0), p.T

    def com_and_frames(self, base_pose: np.ndarray, Q: np.ndarray, frames: list[str]) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
        Rs, ps = self.forward(base_pose, Q)
        return self._com_from(Rs, ps), {f: self.frame(Rs, ps, f) for f in frames}


def select_states(Rs: list, ps: list, rows: np.ndarray) -> tuple[list, list]:
    """The states ``rows`` of a :meth:`BatchKinematics.forward` result, as such a result (one block each); the
    result itself (not a copy) when ``rows`` are all of its states in order."""
    rows = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
    if len(rows) == ps[1].shape[-1] and np.array_equal(rows, np.arange(len(rows))):
        return Rs, ps
    # np.take allocates the selection in its own shape: indexing with [..., rows] may hand back a transposed
    # view of a buffer laid out differently, whose rows frames_block would not recognise as a block
    R, p = np.take(frames_block(Rs), rows, axis=-1), np.take(frames_block(ps), rows, axis=-1)
    return [None, *R[1:]], [None, *p[1:]]


def frames_block(frames: list) -> np.ndarray:
    """The ``(njoints, ...)`` block whose views a :meth:`BatchKinematics.forward` list holds."""
    base = frames[1].base
    if base is None or base.shape[1:] != frames[1].shape:
        raise ValueError("frames must come from BatchKinematics.forward")
    return base


def _rotate(R: np.ndarray, R0: np.ndarray) -> np.ndarray:
    """R (3, 3, N) times a constant rotation R0 (3, 3)."""
    return np.einsum("ijn,jk->ikn", R, R0)
