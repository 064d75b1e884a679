"""The whole body's momentum rate along a path, which the multibody ZMP rows of the timing use, against finite
differences of pinocchio's centroidal momentum on the URDF (an independent computation: ``ccrba`` through
``computeCentroidalMomentum``, not the recursive Newton-Euler algorithm)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.stability.inertial_torques import InertialTorques


def _momentum_about_origin(robot, base_pose, q, dq) -> np.ndarray:
    """[P; L about the world origin] of the robot moving with joint velocities dq, its base fixed."""
    model = robot.pin_model
    data = model.createData()
    qp = robot.to_pin_q(base_pose, q)
    v = np.zeros(model.nv)
    eps = 1e-7  # the joint velocity in pinocchio's space, by differentiating the configuration map
    v_full = pin.difference(model, qp, robot.to_pin_q(base_pose, q + eps * dq)) / eps
    v[6:] = v_full[6:]
    h = pin.computeCentroidalMomentum(model, data, qp, v)
    c = data.com[0]
    P, L = h.linear, h.angular
    return np.r_[P, L + np.cross(c, P)]


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_the_momentum_rate_matches_finite_differences_of_the_momentum(robot, upright, right_active, seed):
    rng = np.random.default_rng(seed)
    q0 = robot.default_q()
    d = np.zeros_like(q0)
    d[right_active] = rng.uniform(-1.0, 1.0, right_active.size)
    q0 = np.clip(q0, robot.lower + 0.5, robot.upper - 0.5)
    inert = InertialTorques(robot, upright.base_pose)
    # a straight path q(s) = q0 + s d timed by s(t) = t^2 / 2: s_ddot = 1, s_dot = t
    t, h = 0.7, 1e-4
    A, B = inert.momentum_rate(inert.along_path(q0[None] + 0.245 * d[None], d[None], np.zeros((1, len(d)))))
    predicted = A[0] * 1.0 + B[0] * t ** 2

    def momentum(tt):
        return _momentum_about_origin(robot, upright.base_pose, q0 + 0.5 * tt ** 2 * d, tt * d)

    measured = (momentum(t + h) - momentum(t - h)) / (2 * h)
    assert np.allclose(predicted, measured, rtol=2e-3, atol=2e-3 * np.abs(measured).max())
