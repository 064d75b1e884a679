"""The joint torques that accelerating the robot along a path adds to the static ones.

Along a path ``q(s)`` timed by ``s(t)``, inverse dynamics without gravity is linear in
``s_ddot`` and ``s_dot^2``: ``tau = M(q) q' s_ddot + (M(q) q'' + C(q, q') q') s_dot^2``.
The stance fixes the feet and the legs do not move, so the pelvis is fixed and pinocchio's
recursive Newton-Euler algorithm on the free-flyer model with zero base velocity and
acceleration gives the torques of the moving joints (waist and arms). The held object is a
point mass fixed to the holding hand's TCP (while both hands hold it, to the left one, as its
pose is); gravity on it and on the links is the static part (:mod:`planner.stability.effort`).
The torques come out per checked wire joint, in the order of the effort table.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from planner.kinematics.joint_table import joint_table
from planner.robot.model import RobotModel
from planner.stability.effort import effort_table


class InertialTorques:
    """Along a path (:meth:`along_path`), the inertial torques ``A s_ddot + B s_dot^2`` (:meth:`coefficients`) and the
    rate of the body's momentum (:meth:`momentum_rate`); at samples, the torques themselves (:meth:`torques`)."""

    def __init__(self, robot: RobotModel, base_pose: np.ndarray, object_mass: float = 0.0,
                 tcp_frame: str | None = None, T_tcp_obj: np.ndarray | None = None, com_local: np.ndarray | None = None):
        self.robot = robot
        self.base_pose = np.asarray(base_pose, dtype=float)
        model = pin.Model(robot.pin_model)
        model.gravity = pin.Motion.Zero()
        if object_mass > 0.0 and tcp_frame is not None:
            frame = model.frames[model.getFrameId(tcp_frame)]
            T = np.asarray(T_tcp_obj, dtype=float)
            c_tcp = T[:3, :3] @ np.asarray(com_local, dtype=float) + T[:3, 3]
            c_joint = frame.placement.act(c_tcp)
            model.appendBodyToJoint(frame.parentJoint, pin.Inertia(float(object_mass), c_joint, np.zeros((3, 3))),
                                    pin.SE3.Identity())
        self.model = model
        self.data = model.createData()
        rows = joint_table(robot).rows
        table = effort_table(robot)
        self.fold = table.fold  # (K, J)
        self.limit = table.limit
        self.checked = table.checked
        # wire velocity -> pinocchio velocity (mimic joints follow their master with the multiplier)
        self._v_index = np.array([model.idx_vs[r.jid] for r in rows[2:] if r.source[0] >= 0], dtype=int)
        self._v_source = np.array([r.source[0] for r in rows[2:] if r.source[0] >= 0], dtype=int)
        self._v_mult = np.array([r.source[1] for r in rows[2:] if r.source[0] >= 0], dtype=float)
        self._jid_v = np.array([model.idx_vs[j] if j >= 2 else -1 for j in range(len(rows))], dtype=int)

    def _pin_states(self, Q: np.ndarray, *rates: np.ndarray) -> tuple[np.ndarray, ...]:
        """Pinocchio's configurations (N, nq) of the wire states Q (N, n), and each of ``rates`` (N, n: joint
        velocities or accelerations) in its velocity space (N, nv), mimic joints following their master with the
        multiplier: the rates all rows at once, so that the loop over the points (:meth:`_rnea`) only calls RNEA."""
        out = [self.robot.to_pin_q(self.base_pose, Q)]
        for rate in rates:
            v = np.zeros((len(Q), self.model.nv))
            v[:, self._v_index] = self._v_mult * rate[:, self._v_source]
            out.append(v)
        return tuple(out)

    def _per_checked(self, tau: np.ndarray) -> np.ndarray:
        """Torques (N, nv) of pinocchio's velocity space -> (N, K) of the checked wire joints."""
        per_joint = np.zeros((len(tau), len(self._jid_v)))
        ok = self._jid_v >= 0
        per_joint[:, ok] = tau[:, self._jid_v[ok]]
        return per_joint @ self.fold.T

    def along_path(self, Q: np.ndarray, dQ: np.ndarray, ddQ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(A, B), each (N, nv) in pinocchio's velocity space, at the path points Q with path derivatives dQ, ddQ
        (N, n): recursive Newton-Euler without gravity, ``A = rnea(q, 0, q')`` and ``B = rnea(q, q', q'')``, so that
        the generalized forces are ``A s_ddot + B s_dot^2``. Their first six rows are the free-flyer's wrench
        (:meth:`momentum_rate`), the rest the joints' torques (:meth:`coefficients`): one sweep serves both."""
        qp, v1, a2 = self._pin_states(Q, dQ, ddQ)
        return self._rnea(qp, np.zeros_like(v1), v1), self._rnea(qp, v1, a2)

    def _rnea(self, qp: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Pinocchio's RNEA (this model: no gravity, the held object included) row by row: (N, nv)."""
        out = np.empty((len(qp), self.model.nv))
        for i in range(len(qp)):
            out[i] = pin.rnea(self.model, self.data, qp[i], v[i], a[i])
        return out

    def coefficients(self, along: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(A, B), each (N, K): the checked wire joints' inertial torques ``A s_ddot + B s_dot^2`` along a path
        (``along``: :meth:`along_path`)."""
        return self._per_checked(along[0]), self._per_checked(along[1])

    @property
    def total_mass(self) -> float:
        """The robot's mass plus the held object's (when one is held)."""
        return float(pin.computeTotalMass(self.model))

    def momentum_rate(self, along: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(A, B), each (N, 6): the rate of change of the whole body's momentum along a path (``along``:
        :meth:`along_path`), world frame, ``[P_dot; L_dot about the world origin] = A s_ddot + B s_dot^2``. With the
        base fixed and no gravity it is the wrench the free-flyer joint carries (pinocchio's RNEA, base frame), moved
        to the world origin: what the ground must add to the weight, so the multibody ZMP (the arms' angular momentum
        included, which the cart-table model leaves out) follows from it."""
        A, B = along[0][:, :6], along[1][:, :6]
        x, y, z, w = self.base_pose[3:7]
        R = pin.Quaternion(float(w), float(x), float(y), float(z)).toRotationMatrix()
        p = self.base_pose[:3]
        out = []
        for W in (A, B):
            f = W[:, :3] @ R.T
            out.append(np.hstack([f, W[:, 3:] @ R.T + np.cross(p[None], f)]))
        return out[0], out[1]

    def torques(self, Q: np.ndarray, dQ: np.ndarray, ddQ: np.ndarray) -> np.ndarray:
        """Inertial torques (N, K) of states Q moving with joint velocities dQ and accelerations ddQ."""
        return self._per_checked(self._rnea(*self._pin_states(Q, dQ, ddQ)))
