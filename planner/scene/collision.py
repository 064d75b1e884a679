"""Collision checking with python-fcl on the model's primitives, batched over configurations.

What is checked (each pair once, in this order, the first hit reported):

- the held object against the tables and obstacles (touching within
  ``object_env_tolerance_m`` is not a collision: an object is picked from and put on a table);
- the robot against the tables and obstacles;
- the robot against the object, resting or held, except the fingers of the hand that grasps
  or holds it (those touch it by design);
- robot self-collision, minus the pairs an SRDF would disable: geometric neighbours in the
  kinematic tree and pairs already touching in the default posture or a reference posture
  such as the stance's (computed once). The two hands are an ordinary pair, so hand against
  hand at a handover is covered.

How it is fast: every body is bounded by an oriented box. A batch of states is screened with
the world axis-aligned boxes of those, then with the separating-axis test on the oriented
boxes, all in numpy over (pairs x states). Box-box pairs are decided exactly there (the SAT is exact for boxes);
only pairs with a sphere, cylinder, capsule or mesh that pass the screen go to fcl's
narrow phase, with transforms set from the precomputed arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

import fcl
import numpy as np
import pinocchio as pin
from pydantic import BaseModel, ConfigDict, Field

from planner.compiled.box_kernels import bodies_world, screen_pairs
from planner.kinematics.batch import BatchKinematics, frames_block
from planner.robot.model import RobotModel
from planner.robot.urdf_geometry import collision_primitives
from planner.scene.bodies import (
    Body,
    EnvBox,
    environment_boxes,
    fcl_collide,
    fcl_geometry,
    half_extents,
    make_fcl_object,
    object_bodies,
    set_fcl_transform,
)
from planner.scene.hand import contact_joints
from planner.scene.objects import ObjectModel
from planner.transforms import inverse

#: Margin on the bounding-box screen; the SAT and fcl decide exactly afterwards.
_SCREEN_SLACK_M = 1e-6
#: Added to the slack of the batch-wide box screen: its sums round differently from the per-state
#: screen's, and it must pass every pair that one would.
_ENVELOPE_ROUNDING_M = 1e-9


#: Sampled postures for the "always in contact" rule of the self-collision pairs, its seed and threshold.
ALWAYS_IN_CONTACT_SAMPLES = 200
ALWAYS_IN_CONTACT_SEED = 20240
ALWAYS_IN_CONTACT_FRACTION = 0.95

class CollisionSettings(BaseModel):
    """Tolerances of the collision checker (metres)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # 5 mm: a held object put down by IK (1 mm, 0.01 rad over a 0.3 m object: ~4 mm at its far
    # edge) may sink that much at the place pose; it is also the contract's goal tolerance.
    object_env_tolerance_m: float = Field(
        0.005, ge=0, description="held object vs table/obstacle: penetration up to this is contact, not collision"
    )
    object_robot_tolerance_m: float = Field(0.0, ge=0, description="object vs robot bodies (fingers of the holding hand are skipped)")
    self_tolerance_m: float = Field(0.0, ge=0, description="robot vs robot")
    env_tolerance_m: float = Field(0.0, ge=0, description="robot vs tables and obstacles")
    default_touch_margin_m: float = Field(
        0.0, ge=0, description="self pairs closer than this in the default posture are disabled (like an SRDF)"
    )


@dataclass(frozen=True)
class Collision:
    """The first colliding pair of a state, by body name (``link`` or ``link#k``, ``env:NAME``, ``object``)."""

    body_a: str
    body_b: str
    kind: str  # "self" | "env" | "object" | "object-env"

    def __str__(self) -> str:
        return f"{self.body_a} vs {self.body_b} ({self.kind})"


































# ---------------------------------------------------------------------------------------------
# The world




@dataclass
class BatchResult:
    """Per state: whether it collides, and the first colliding pair (None when free)."""

    collides: np.ndarray
    first: list[Collision | None]


class CollisionWorld:
    """Robot + environment boxes + (optionally) the object; its shapes are fixed at construction.

    Not thread-safe: the fcl objects hold scratch transforms, so use one world per thread or
    process (building one takes a few tens of milliseconds).

    ``check``/``check_batch`` take the stance's base pose and wire configurations ``q``;
    ``check_forward`` takes a :meth:`BatchKinematics.forward` result computed elsewhere, so a
    planner that already has the joint frames pays no second FK.
    """

    def __init__(
        self,
        robot: RobotModel,
        environment: Iterable[EnvBox] = (),
        obj: ObjectModel | None = None,
        settings: CollisionSettings | None = None,
        kinematics: BatchKinematics | None = None,
        reference_postures: Sequence[tuple[np.ndarray, np.ndarray]] = (),
        moving_joints: Sequence[str] | None = None,
        progress: Callable[[str], None] | None = None,
    ):
        """``reference_postures``: (base_pose, q) pairs, such as the stance posture, whose touching
        self pairs are disabled like the default posture's. ``moving_joints``: when given (e.g. the
        waist and arms while the feet stay planted), pairs of two bodies that none of these joints
        moves are dropped: they cannot change during a plan, so check the stance once with a
        world built without ``moving_joints``. ``progress(message)`` hears of the collision matrix's computation
        (the first time a robot without an SRDF is seen)."""
        self.robot = robot
        self._reference_postures = [(np.asarray(b, float), np.asarray(q, float)) for b, q in reference_postures]
        self.settings = settings or CollisionSettings()
        self.kin = kinematics or BatchKinematics(robot)
        self.obj = obj
        model = robot.pin_model
        link_joint = {f.name: int(f.parentJoint) for f in model.frames if f.type == pin.FrameType.BODY}
        link_frame = {f.name: f for f in model.frames if f.type == pin.FrameType.BODY}
        bodies: list[Body] = []
        prims = collision_primitives(robot.urdf_path)
        per_link: dict[str, int] = {}
        for p in prims:
            per_link[p.link] = per_link.get(p.link, 0) + 1
        seen: dict[str, int] = {}
        for p in prims:
            if p.link not in link_joint:
                continue
            k = seen.get(p.link, 0)
            seen[p.link] = k + 1
            name = p.link if per_link[p.link] == 1 else f"{p.link}#{k}"
            local = link_frame[p.link].placement.homogeneous @ p.origin
            bodies.append(Body(name, "robot", p.kind, tuple(p.dims), local, half_extents(p.kind, p.dims), np.zeros(3),
                                joint=link_joint[p.link], link=p.link, geometry=fcl_geometry(p.kind, tuple(p.dims))))
        self.n_robot = len(bodies)
        self.env = tuple(environment)
        for e in self.env:
            bodies.append(Body(f"env:{e.name}", "env", "box", tuple(e.size), np.asarray(e.pose, float),
                                np.asarray(e.size, float) / 2.0, np.zeros(3), geometry=fcl.Box(*e.size)))
        self.n_env = len(self.env)
        obj_bodies = object_bodies(obj) if obj is not None else []
        bodies.extend(obj_bodies)
        self.n_obj = len(obj_bodies)
        self.bodies = bodies
        self._fcl = [make_fcl_object(b) for b in bodies]
        B = len(bodies)
        self._half = np.array([b.half for b in bodies])
        self._radius = np.linalg.norm(self._half, axis=1)
        self._is_box = np.array([b.kind == "box" for b in bodies])
        self._obb_offset = np.array([b.obb_offset for b in bodies], dtype=float).reshape(len(bodies), 3)
        self._local_R = np.array([b.local[:3, :3] for b in bodies])
        self._local_p = np.array([b.local[:3, 3] + b.local[:3, :3] @ b.obb_offset for b in bodies])
        self._robot_joints = np.array([b.joint for b in bodies[: self.n_robot]], dtype=int)
        self._uniq_joints, self._joint_slot = np.unique(self._robot_joints, return_inverse=True)
        self._env_slice = slice(self.n_robot, self.n_robot + self.n_env)
        self._obj_slice = slice(self.n_robot + self.n_env, B)
        # per side, the robot bodies that may touch an object the hand grasps or holds (hand.contact_joints)
        self._touching: dict[str, np.ndarray] = {}
        self._tcp: dict[str, str] = {}
        for side, arm in robot.spec.arms.items():
            touch = contact_joints(robot, side)
            self._touching[side] = np.array([i for i in range(self.n_robot) if bodies[i].joint in touch], dtype=int)
            self._tcp[side] = arm.tcp
        self._progress = progress
        self.disabled = self._disabled_self_pairs()
        moving = np.ones(B, dtype=bool)
        moving[self.n_robot:] = False
        moving[self._obj_slice] = True  # the object may move (held) or be placed anywhere
        if moving_joints is not None:
            mj = {int(model.getJointId(robot.joint_names[robot.joint_index(n)])) for n in moving_joints}
            for i in range(self.n_robot):
                support = {int(j) for j in model.supports[bodies[i].joint]}
                moving[i] = bool(support & mj)
        self._moving = moving
        self._build_pairs()

    # -- construction helpers -------------------------------------------------------------------

    @classmethod
    def from_scenario(cls, robot: RobotModel, scenario, obj: ObjectModel | None, **kwargs) -> "CollisionWorld":
        """World of a :class:`schemas.scenario.Scenario`: its tables and obstacles as boxes.

        Keyword arguments go to the constructor (settings, kinematics, reference_postures, moving_joints).
        """
        return cls(robot, environment_boxes(scenario), obj, **kwargs)

    def _geometric_parent(self) -> dict[str, str | None]:
        """Nearest ancestor link that has collision geometry, per link with geometry."""
        model = self.robot.pin_model
        geom_links = {b.link for b in self.bodies[: self.n_robot]}
        # parent link of each link: walk the frame tree up through joint frames to a body frame
        parent_of: dict[str, str | None] = {}
        for f in model.frames:
            if f.type != pin.FrameType.BODY:
                continue
            pf = model.frames[f.parentFrame]
            # walk up through joint frames to the body frame that carries this one
            while pf.type != pin.FrameType.BODY and pf.name != "universe":
                pf = model.frames[pf.parentFrame]
            parent_of[f.name] = None if pf.name == "universe" or pf.name == f.name else pf.name
        out: dict[str, str | None] = {}
        for link in geom_links:
            p = parent_of.get(link)
            while p is not None and p not in geom_links:
                p = parent_of.get(p)
            out[link] = p
        return out

    def _disabled_self_pairs(self) -> set[tuple[str, str]]:
        """Link pairs never checked, as an SRDF would list them: geometric neighbours (a link and the
        nearest ancestor that has geometry), pairs touching in the default posture or in one of
        the reference postures, pairs touching in nearly every sampled posture (computed once here), and
        the pairs the robot's spec disables (its SRDF's ``<disable_collisions>``)."""
        gp = self._geometric_parent()
        disabled: set[tuple[str, str]] = set()
        for link, parent in gp.items():
            if parent is not None:
                disabled.add(tuple(sorted((link, parent))))  # type: ignore[arg-type]
        robot = self.robot
        base = np.array([0, 0, robot.spec.upright.pelvis_height_m, 0, 0, 0, 1.0])
        n = self.n_robot
        ia, ib = np.triu_indices(n, 1)
        same = np.array([self.bodies[i].link == self.bodies[j].link for i, j in zip(ia, ib)], dtype=bool)
        ia, ib = ia[~same], ib[~same]
        postures = [(base, robot.default_q())] + self._reference_postures
        for pbase, pq in postures:
            Rw, pw = self._robot_world(*self.kin.forward(pbase, pq[None, :]))
            hits = self._pair_hits(Rw, pw, ia, ib, np.full(ia.size, -self.settings.default_touch_margin_m))
            for k in np.flatnonzero(hits[:, 0]):
                disabled.add(tuple(sorted((self.bodies[ia[k]].link, self.bodies[ib[k]].link))))  # type: ignore[arg-type]
        # As MoveIt's setup assistant: a pair in contact in (nearly) every sampled posture cannot be told
        # apart (links whose fitted boxes overlap across a joint); seeded, so the same pairs every time.
        rng = np.random.default_rng(ALWAYS_IN_CONTACT_SEED)
        Q = rng.uniform(robot.lower, robot.upper, (ALWAYS_IN_CONTACT_SAMPLES, robot.nq))
        Rw, pw = self._robot_world(*self.kin.forward(base, Q))
        hits = self._pair_hits(Rw, pw, ia, ib, np.zeros(ia.size))
        for k in np.flatnonzero(hits.mean(axis=1) >= ALWAYS_IN_CONTACT_FRACTION):
            disabled.add(tuple(sorted((self.bodies[ia[k]].link, self.bodies[ib[k]].link))))  # type: ignore[arg-type]
        # Without an SRDF, the matrix computed over many random configurations (cached by URDF and spec).
        if robot.spec.self_collision_matrix == "computed":
            from planner.scene.collision_matrix import cached_matrix

            disabled.update(cached_matrix(self, self._progress or (lambda message: None))[0].disabled())
        # The robot's own collision matrix (its SRDF's, or pairs its spec file lists).
        disabled.update((a, b) for a, b in robot.spec.disabled_collisions)
        return disabled

    def _build_pairs(self) -> None:
        s = self.settings
        n, B = self.n_robot, len(self.bodies)
        ia, ib = np.triu_indices(n, 1)
        keep = np.array([
            self.bodies[i].link != self.bodies[j].link and tuple(sorted((self.bodies[i].link, self.bodies[j].link))) not in self.disabled
            for i, j in zip(ia, ib)
        ], dtype=bool)
        keep &= self._moving[ia] | self._moving[ib]
        self._self_pairs = (ia[keep], ib[keep])
        er, ee = np.meshgrid(np.arange(n), np.arange(self._env_slice.start, self._env_slice.stop), indexing="ij")
        er, ee = er.ravel(), ee.ravel()
        keep = self._moving[er]
        self._env_pairs = (er[keep], ee[keep])
        orr, oo = np.meshgrid(np.arange(n), np.arange(self._obj_slice.start, B), indexing="ij")
        self._obj_pairs = (orr.ravel(), oo.ravel())
        oe_o, oe_e = np.meshgrid(np.arange(self._obj_slice.start, B), np.arange(self._env_slice.start, self._env_slice.stop), indexing="ij")
        self._objenv_pairs = (oe_o.ravel(), oe_e.ravel())
        self._tol = {"self": s.self_tolerance_m, "env": s.env_tolerance_m, "object": s.object_robot_tolerance_m,
                     "object-env": s.object_env_tolerance_m}
        self._pair_cache: dict = {}

    def self_pair_count(self) -> int:
        return int(self._self_pairs[0].size)

    # -- pose computation ------------------------------------------------------------------------

    def _robot_world(self, Rs: list, ps: list, out: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World rotation (n_robot, N, 3, 3) and OBB centre (n_robot, N, 3) of every robot body."""
        N = Rs[1].shape[2]
        n = self.n_robot
        if out is None:
            out = (np.empty((n, N, 3, 3)), np.empty((n, N, 3)))
        bodies_world(frames_block(Rs), frames_block(ps), self._robot_joints, self._local_R[:n], self._local_p[:n], *out)
        return out

    def _all_world(self, Rs: list, ps: list, T_obj: np.ndarray | None, N: int) -> tuple[np.ndarray, np.ndarray]:
        B, n = len(self.bodies), self.n_robot
        Rw = np.empty((B, N, 3, 3))
        pw = np.empty((B, N, 3))
        self._robot_world(Rs, ps, out=(Rw[:n], pw[:n]))
        if self.n_env:
            Rw[self._env_slice] = self._local_R[self._env_slice][:, None]
            pw[self._env_slice] = self._local_p[self._env_slice][:, None]
        if self.n_obj:
            # an absent object gets an identity pose: no pair involving it is tested then
            if T_obj is None:
                Rw[self._obj_slice] = self._local_R[self._obj_slice][:, None]
                pw[self._obj_slice] = self._local_p[self._obj_slice][:, None]
            else:
                Rw[self._obj_slice] = T_obj[None, :, :3, :3] @ self._local_R[self._obj_slice][:, None]
                pw[self._obj_slice] = (T_obj[None, :, :3, :3] @ self._local_p[self._obj_slice][:, None, :, None])[..., 0] + T_obj[None, :, :3, 3]
        return Rw, pw

    # -- pair testing ------------------------------------------------------------------------------

    def _pair_hits(
        self, Rw: np.ndarray, pw: np.ndarray, ia: np.ndarray, ib: np.ndarray, tol: np.ndarray, first_only: bool = False
    ) -> np.ndarray:
        """(P, N) collision matrix of body pairs over N states (box screen, SAT, then fcl).

        With ``first_only`` a state known to collide is not tested further, so its row holds
        at least one colliding pair, not necessarily all of them.
        """
        P, N = ia.size, Rw.shape[1]
        hits = np.zeros((P, N), dtype=bool)
        if P == 0:
            return hits
        # Box screens (each body's box over the whole batch, then per state: most pairs of a T-RRT batch
        # stop at the first), then the separating-axis test where boxes meet: the
        # candidates are the (pair, state)s whose oriented boxes penetrate deeper than the tolerance.
        kp, ks = screen_pairs(Rw, pw, self._half[: Rw.shape[0]], ia, ib, _SCREEN_SLACK_M - tol, tol,
                              _ENVELOPE_ROUNDING_M)
        if kp.size == 0:
            return hits
        a, b = ia[kp], ib[kp]
        exact = self._is_box[a] & self._is_box[b]  # for two boxes the test is exact
        hits[kp[exact], ks[exact]] = True
        done = np.zeros(N, dtype=bool)
        done[ks[exact]] = True
        todo = np.flatnonzero(~exact)
        # Two bodies that keep one pose over the whole batch (an idle arm, a resting object, the table) meet in
        # every state alike: fcl is asked once for their pair, and its answer holds for the batch's other states.
        involved = np.union1d(a[todo], b[todo])
        still = _still(Rw, pw, involved) if N > 1 and todo.size > 1 else {}
        answered: dict[int, bool] = {}
        # fcl wants the shape frame; our centres are OBB centres (offset only for meshes)
        frame = pw.copy()
        frame[involved] -= np.einsum("bnij,bj->bni", Rw[involved], self._obb_offset[involved])
        posed: dict[int, int] = {}  # the state each body's fcl object is posed in now (a still body: any)
        for k in todo:
            s = int(ks[k])
            if first_only and done[s]:
                continue  # this state already collides; its first pair is reported below
            ba, bb = int(a[k]), int(b[k])
            pair = int(kp[k])
            both_still = still.get(ba, False) and still.get(bb, False)
            hit = answered.get(pair) if both_still else None
            if hit is None:
                for body in (ba, bb):
                    if body not in posed or (posed[body] != s and not still.get(body, False)):
                        set_fcl_transform(self._fcl[body], Rw[body, s], frame[body, s])
                        posed[body] = s
                hit = fcl_collide(self._fcl[ba], self._fcl[bb], float(tol[pair]))
                if both_still:
                    answered[pair] = hit
            if hit:
                hits[pair, s] = True
                done[s] = True
        return hits

    def _pairs_for(self, held_sides: tuple[str, ...], grasping: str | None, object_present: bool, object_held: bool):
        key = (held_sides, grasping, object_present, object_held)
        cached = self._pair_cache.get(key)
        if cached is not None:
            return cached
        groups = []
        if object_present and object_held and self.n_env:
            groups.append(("object-env", *self._objenv_pairs))
        if self.n_env:
            groups.append(("env", *self._env_pairs))
        if object_present:
            excluded = set()
            for side in (*held_sides, *((grasping,) if grasping else ())):
                excluded |= set(self._touching[side].tolist())
            orr, oo = self._obj_pairs
            keep = np.array([r not in excluded for r in orr], dtype=bool)
            groups.append(("object", orr[keep], oo[keep]))
        groups.append(("self", *self._self_pairs))
        ia = np.concatenate([g[1] for g in groups]).astype(int)
        ib = np.concatenate([g[2] for g in groups]).astype(int)
        kinds = np.concatenate([np.full(g[1].size, i) for i, g in enumerate(groups)])
        tol = np.concatenate([np.full(g[1].size, self._tol[g[0]]) for g in groups])
        names = [g[0] for g in groups]
        out = (ia, ib, kinds, tol, names)
        self._pair_cache[key] = out
        return out

    # -- public API --------------------------------------------------------------------------------

    def object_pose_held(self, Rs: list, ps: list, side: str, T_obj_tcp: np.ndarray) -> np.ndarray:
        """World pose (N, 4, 4) of an object held by ``side`` with grasp ``T_obj_tcp``."""
        R, p = self.kin.frame(Rs, ps, self._tcp[side])
        T = np.zeros((R.shape[0], 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = p
        T[:, 3, 3] = 1.0
        return T @ inverse(np.asarray(T_obj_tcp, dtype=float))

    def check_forward(
        self,
        Rs: list,
        ps: list,
        *,
        held: Sequence[tuple[str, np.ndarray]] = (),
        free_object_pose: np.ndarray | None = None,
        grasping: str | None = None,
        held_object_poses: np.ndarray | None = None,
    ) -> BatchResult:
        """Check the N states of a :meth:`BatchKinematics.forward` result.

        ``held``: ``[(side, T_obj_tcp)]`` (one entry, or two at a handover; the object follows
        the first). ``free_object_pose``: 4x4 (or (N, 4, 4)) pose of a resting object, when
        nothing holds it. ``grasping``: the side whose fingers are at the resting object
        (approach and grasp key poses); its fingers are not checked against the object.
        ``held_object_poses`` (N, 4, 4): the held object's world poses, when each state holds it
        with its own grasp (batched probes); ``held`` then only names the sides.
        """
        N = Rs[1].shape[2]
        held = tuple(held)
        if held and free_object_pose is not None:
            raise ValueError("an object is either held or free, not both")
        T_obj = None
        if held:
            if self.n_obj == 0:
                raise ValueError("this collision world has no object to hold")
            if held_object_poses is not None:
                T_obj = np.asarray(held_object_poses, dtype=float)
            else:
                T_obj = self.object_pose_held(Rs, ps, held[0][0], held[0][1])
        elif free_object_pose is not None and self.n_obj:
            T = np.asarray(free_object_pose, dtype=float)
            T_obj = np.broadcast_to(T, (N, 4, 4)) if T.ndim == 2 else T
        Rw, pw = self._all_world(Rs, ps, T_obj, N)
        sides = tuple(sorted({h[0] for h in held}))
        ia, ib, kinds, tol, names = self._pairs_for(sides, grasping, T_obj is not None, bool(held))
        hits = self._pair_hits(Rw, pw, ia, ib, tol, first_only=True)
        collides = hits.any(axis=0)
        first: list[Collision | None] = [None] * N
        if collides.any():
            firsts = np.argmax(hits, axis=0)
            for s in np.flatnonzero(collides):
                k = firsts[s]
                first[s] = Collision(self.bodies[ia[k]].name, self.bodies[ib[k]].name, names[kinds[k]])
        return BatchResult(collides, first)

    def check_batch(self, base_pose: np.ndarray, Q: np.ndarray, **kwargs) -> BatchResult:
        """Check N configurations ``Q`` (N, n) at the stance's ``base_pose`` (see :meth:`check_forward`)."""
        Rs, ps = self.kin.forward(np.asarray(base_pose, float), np.atleast_2d(Q))
        return self.check_forward(Rs, ps, **kwargs)

    def check(self, base_pose: np.ndarray, q: np.ndarray, **kwargs) -> Collision | None:
        """First collision of one configuration, or None when it is free."""
        return self.check_batch(base_pose, np.asarray(q, float)[None, :], **kwargs).first[0]

    def object_pose_clear(self, T_world_obj: np.ndarray) -> Collision | None:
        """Whether the object at a world pose is clear of the environment (resting contact allowed)."""
        if self.n_obj == 0:
            raise ValueError("this collision world has no object")
        T = np.asarray(T_world_obj, dtype=float)[None]
        B = len(self.bodies)
        Rw = np.broadcast_to(np.eye(3), (B, 1, 3, 3)).copy()
        pw = np.zeros((B, 1, 3))
        Rw[self._env_slice, 0] = self._local_R[self._env_slice]
        pw[self._env_slice, 0] = self._local_p[self._env_slice]
        Rw[self._obj_slice] = np.einsum("nij,bjk->bnik", T[:, :3, :3], self._local_R[self._obj_slice])
        pw[self._obj_slice] = np.einsum("nij,bj->bni", T[:, :3, :3], self._local_p[self._obj_slice]) + T[None, :, :3, 3]
        ia, ib = self._objenv_pairs
        hits = self._pair_hits(Rw, pw, ia, ib, np.full(ia.size, self.settings.object_env_tolerance_m))
        if hits.any():
            k = int(np.argmax(hits[:, 0]))
            return Collision(self.bodies[ia[k]].name, self.bodies[ib[k]].name, "object-env")
        return None


def _still(Rw: np.ndarray, pw: np.ndarray, bodies: np.ndarray) -> dict[int, bool]:
    """Whether each of ``bodies`` has the same world pose, bit for bit, in every state of the batch."""
    R, p = Rw[bodies], pw[bodies]
    same = (R == R[:, :1]).all(axis=(1, 2, 3)) & (p == p[:, :1]).all(axis=(1, 2))
    return dict(zip(bodies.tolist(), same.tolist()))
