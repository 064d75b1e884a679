"""A ready posture for a robot whose spec gives none: arms down, hands clear of the body.

The planner starts every task from the default posture. A URDF's zero posture is often no posture to start
from (arms straight ahead at table height, through any table in front). When the spec names no posture
(neither ``default_posture_rad`` nor ``srdf_posture``), the zero posture (within the limits) is kept if its
arms already hang down (each TCP half the arm's length below its shoulder, at most a quarter ahead of it) with
the forearms and hands clear of the body; otherwise each arm's joints are solved
(position IK from seeded starts, within the joint limits) to put its TCP below the shoulder, a little forward
and out (the same for both arms, mirrored, so the arms keep the CoM over the polygon's centre sideways), and of
the solutions whose forearm and hand stay clear of the body the one nearest its target with the least joint
motion is kept. Then the legs stand the body over the feet: with the pelvis upright at the spec's pelvis height
and both soles flat at the upright stance's placements, the hip, knee and ankle joints (within their limits)
lean it until the CoM is over the centre of the support polygon (:func:`planner.stability.standing.centred_legs`:
the CoM is computed in planner/stability; that module takes the robot as an argument and imports nothing from
this package, so the loader can call it without an import cycle). Jaws are open. The hands then hang well behind any table whose near
edge is in front of them (the fitted tasks put it there), and the posture is printed by ``robot check`` so it
can be pasted into the spec. Results are cached by the URDF's and the spec's content.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pinocchio as pin

from planner.errors import StanceError
from planner.robot.urdf_geometry import collision_primitives
from planner.stability.standing import centred_legs

#: the TCP's target below the shoulder, forward and out, as shares of the arm's length
DOWN, FORWARD, OUT = 0.8, 0.12, 0.12
#: the arm "hangs down" when its TCP is at least this share of the arm's length below the shoulder
HANGS_BELOW = 0.5
#: ... and its TCP at most this share of the arm's length ahead of the shoulder
AHEAD_AT_MOST = 0.25
#: the forearm and hand points must stay this far outside the body's boxes (m)
CLEARANCE_M = 0.02
STARTS, ITERATIONS, SEED = 16, 150, 7
POSTURE_VERSION = 3


def _posture_key(robot) -> str:  # type: ignore[no-untyped-def]
    h = hashlib.sha256(f"ready-posture/{POSTURE_VERSION}/".encode())
    h.update(Path(robot.urdf_path).read_bytes())
    h.update(b"\0" + robot.spec.model_dump_json().encode())
    return h.hexdigest()


def cached_ready_posture(robot) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """The derived ready posture of ``robot`` (a :class:`planner.robot.model.RobotModel` whose spec gives none),
    from the cache folder or derived now and stored there."""
    from planner.robot.spec_file import cache_dir

    path = cache_dir() / "ready-postures" / f"{robot.name}-{_posture_key(robot)[:20]}.json"
    if path.is_file():
        try:
            return {str(k): float(v) for k, v in json.loads(path.read_text()).items()}
        except (OSError, ValueError, AttributeError):
            pass
    posture = derive_ready_posture(robot)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(posture))
    tmp.replace(path)
    return posture


def _subtree_links(model: pin.Model, joint_id: int) -> set[str]:
    """Body frames carried by ``joint_id`` or a joint below it."""
    below = {j for j in range(model.njoints) if joint_id in model.supports[j]}
    return {f.name for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint in below}


class _Body:
    """The robot's primitives as boxes (frame, local pose, half extents) and their bounding points."""

    def __init__(self, robot) -> None:  # type: ignore[no-untyped-def]
        model = robot.pin_model
        self.frame = {}
        self.items = []
        for p in collision_primitives(robot.urdf_path):
            if not model.existFrame(p.link):
                continue
            fid = model.getFrameId(p.link)
            pts = p.local_points()
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            self.items.append((p.link, fid, pts, (lo + hi) / 2, (hi - lo) / 2))


def _world_points(model: pin.Model, data: pin.Data, fid: int, pts: np.ndarray) -> np.ndarray:
    T = data.oMf[fid]
    return pts @ T.rotation.T + T.translation


def _clear(model: pin.Model, data: pin.Data, body: _Body, moving: set[str], fixed: set[str]) -> bool:
    """Whether every bounding point of the ``moving`` links is CLEARANCE_M outside each box of the ``fixed`` links
    (and each fixed box's points outside the moving boxes)."""
    mov = [(fid, pts, c, h) for link, fid, pts, c, h in body.items if link in moving]
    fix = [(fid, pts, c, h) for link, fid, pts, c, h in body.items if link in fixed]
    for fa, pa, ca, ha in mov:
        wa = _world_points(model, data, fa, pa)
        for fb, pb, cb, hb in fix:
            Tb = data.oMf[fb]
            local = (wa - Tb.translation) @ Tb.rotation - cb
            if np.any(np.all(np.abs(local) < hb + CLEARANCE_M, axis=1)):
                return False
            wb = _world_points(model, data, fb, pb)
            Ta = data.oMf[fa]
            local = (wb - Ta.translation) @ Ta.rotation - ca
            if np.any(np.all(np.abs(local) < ha + CLEARANCE_M, axis=1)):
                return False
    return True


def derive_ready_posture(robot) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Joint values (arm, leg and jaw joints) of a ready posture (module docstring), rounded to 0.1 mrad."""
    model, data = robot.pin_model, robot.create_data()
    spec = robot.spec
    q = np.clip(np.zeros(robot.nq), robot.lower, robot.upper)
    for arm in spec.arms.values():
        if arm.gripper is not None:
            j = robot.joint_index(arm.gripper.joint)
            q[j] = robot.upper[j] if arm.gripper.opening_per_unit > 0 else robot.lower[j]
    base = np.array([0, 0, spec.upright.pelvis_height_m, 0, 0, 0, 1.0])
    pin.framesForwardKinematics(model, data, robot.to_pin_q(base, q))
    soles = [data.oMf[model.getFrameId(f.frame)] for f in spec.feet.values()]
    forward = np.mean([s.rotation[:, 0] for s in soles], axis=0)
    forward[2] = 0.0
    forward /= np.linalg.norm(forward)
    left = np.cross([0.0, 0.0, 1.0], forward)
    body = _Body(robot)
    all_links = {f.name for f in model.frames if f.type == pin.FrameType.BODY}
    arm_links = {side: _subtree_links(model, model.getJointId(arm.chain[0])) for side, arm in spec.arms.items()}
    rng = np.random.default_rng(SEED)
    out: dict[str, float] = {}
    for side, arm in spec.arms.items():
        sign = 1.0 if side == "left" else -1.0
        idx = robot.joint_indices(arm.chain)
        jids = [model.getJointId(n) for n in arm.chain]
        cols = [model.idx_vs[j] for j in jids]
        tcp = model.getFrameId(arm.tcp)
        shoulder = data.oMi[jids[0]].translation.copy()
        points = [data.oMi[j].translation for j in jids] + [data.oMf[tcp].translation]
        length = float(sum(np.linalg.norm(b - a) for a, b in zip(points, points[1:])))
        # the forearm and hand: links below the arm's middle joint, against everything but this arm
        moving = _subtree_links(model, jids[len(jids) // 2])
        fixed = all_links - arm_links["left"] - arm_links["right"]
        tcp_now = data.oMf[tcp].translation
        hangs = (shoulder[2] - tcp_now[2] >= HANGS_BELOW * length
                 and float((tcp_now - shoulder) @ forward) <= AHEAD_AT_MOST * length)
        if hangs and _clear(model, data, body, moving, fixed):
            continue  # the zero posture's arm already hangs down, clear of the body
        target = shoulder + length * (FORWARD * forward + OUT * sign * left - DOWN * np.array([0, 0, 1.0]))
        best, best_score = None, np.inf
        starts = [q[idx].copy()] + [rng.uniform(robot.lower[idx], robot.upper[idx]) for _ in range(STARTS - 1)]
        for start in starts:
            qq = q.copy()
            qq[idx] = start
            for _ in range(ITERATIONS):
                qp = robot.to_pin_q(base, qq)
                pin.computeJointJacobians(model, data, qp)
                pin.updateFramePlacements(model, data)
                err = target - data.oMf[tcp].translation
                if np.linalg.norm(err) < 1e-4:
                    break
                J = pin.getFrameJacobian(model, data, tcp, pin.LOCAL_WORLD_ALIGNED)[:3, cols]
                dq = J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(3), err)
                qq[idx] = np.clip(qq[idx] + dq, robot.lower[idx], robot.upper[idx])
            pin.framesForwardKinematics(model, data, robot.to_pin_q(base, qq))
            error = float(np.linalg.norm(target - data.oMf[tcp].translation))
            if error > 0.05 * length or not _clear(model, data, body, moving, fixed):
                continue
            # the arms' own balance: the hand's sideways and forward offset from its target weighs like the error
            score = error + 0.05 * float(np.linalg.norm(qq[idx]))
            if score < best_score:
                best, best_score = qq[idx].copy(), score
        if best is None:
            continue  # nothing better found: the zero posture's arm stays (robot check reports its collisions)
        q[idx] = best
    try:
        # the legs then lean the body over the feet (planner/stability stands it: the CoM is computed there)
        q = centred_legs(robot, q)
    except StanceError:
        pass  # the legs cannot: they stay as they are (robot check reports the upright stance's error)
    for k, name in enumerate(robot.joint_names):
        value = float(np.clip(round(float(q[k]), 4), robot.lower[k], robot.upper[k]))
        if value != 0.0:
            out[name] = value
    return out
