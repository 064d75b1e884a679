"""The safety gate's own forward kinematics and centre of mass, straight from the URDF.

An independent channel: the URDF is parsed here with ``xml.etree`` and the
kinematic tree is evaluated with numpy, batched over many states, without the
planner's code or pinocchio. A bug in the planner's kinematics therefore cannot
hide itself from the gate; a test shows the two agree to 1e-9 on random states.

Conventions (URDF): a joint's child frame is ``T_parent * T_origin * T_motion``,
``T_origin`` from ``<origin xyz rpy>`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)``;
revolute/continuous joints rotate about ``<axis>``, prismatic ones slide along
it, mimic joints follow ``multiplier * master + offset``. The root link is a free
flyer at a pose ``[x, y, z, qx, qy, qz, qw]``.

Batched layout: rotations ``(3, 3, N)`` and positions ``(3, N)``, so each matrix
entry is one contiguous vector and a product is 27 vector multiply-adds.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np

_MOVABLE = ("revolute", "continuous", "prismatic")
#: States per evaluation chunk (cache-sized temporaries; measured best on 2-core x86).
CHUNK = 2048
_SUPPORTED = (*_MOVABLE, "fixed")


class UrdfError(ValueError):
    """A URDF the gate cannot use (malformed, unsupported joint type, unknown name)."""


def _floats(text: str | None, default: tuple[float, ...], what: str) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=float)
    try:
        values = np.array([float(v) for v in text.split()], dtype=float)
    except ValueError as exc:
        raise UrdfError(f"{what}: {text!r} is not a list of numbers") from exc
    if values.shape != (len(default),) or not np.all(np.isfinite(values)):
        raise UrdfError(f"{what}: expected {len(default)} finite numbers, got {text!r}")
    return values


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def quaternion_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions ``[qx, qy, qz, qw]`` (normalised first): (..., 4) -> (..., 3, 3)."""
    qv = np.asarray(quat, dtype=float)
    qv = qv / np.linalg.norm(qv, axis=-1, keepdims=True)
    x, y, z, w = (qv[..., i] for i in range(4))
    R = np.empty(qv.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[..., 0, 1] = 2.0 * (x * y - w * z)
    R[..., 0, 2] = 2.0 * (x * z + w * y)
    R[..., 1, 0] = 2.0 * (x * y + w * z)
    R[..., 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[..., 1, 2] = 2.0 * (y * z - w * x)
    R[..., 2, 0] = 2.0 * (x * z - w * y)
    R[..., 2, 1] = 2.0 * (y * z + w * x)
    R[..., 2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return R


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    origin_xyz: np.ndarray
    origin_rot: np.ndarray
    axis: np.ndarray
    lower: float
    upper: float
    velocity: float
    mimic: tuple[str, float, float] | None  # (master, multiplier, offset)


@dataclass(frozen=True)
class UrdfLink:
    name: str
    mass: float
    com_local: np.ndarray
    boxes: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]  # (size (3,), origin xyz, origin R)


@dataclass(frozen=True)
class UrdfModel:
    """What the robot is, parsed once: links, joints in tree order, limits, mass."""

    name: str
    path: Path
    root: str
    links: dict[str, UrdfLink]
    joints: tuple[UrdfJoint, ...]  # parents before children
    joint_names: tuple[str, ...]  # movable, non-mimic, in tree order
    lower: np.ndarray = field(repr=False)
    upper: np.ndarray = field(repr=False)
    velocity_limit: np.ndarray = field(repr=False)
    total_mass: float = 0.0

    @classmethod
    def from_file(cls, path: str | Path) -> "UrdfModel":
        path = Path(path)
        try:
            root_el = ET.parse(path).getroot()
        except (OSError, ET.ParseError) as exc:
            raise UrdfError(f"cannot read URDF {path}: {exc}") from exc
        links: dict[str, UrdfLink] = {}
        for el in root_el.findall("link"):
            name = el.attrib.get("name")
            if not name:
                raise UrdfError(f"{path}: a <link> has no name")
            mass, com = 0.0, np.zeros(3)
            inertial = el.find("inertial")
            if inertial is not None:
                m = inertial.find("mass")
                mass = float(m.attrib["value"]) if m is not None else 0.0
                if not math.isfinite(mass) or mass < 0:
                    raise UrdfError(f"{path}: link {name} has mass {mass}")
                o = inertial.find("origin")
                com = _floats(o.attrib.get("xyz") if o is not None else None, (0.0, 0.0, 0.0), f"link {name} inertial origin")
            boxes = []
            for col in el.findall("collision"):
                box = col.find("geometry/box")
                if box is None:
                    continue
                o = col.find("origin")
                xyz = _floats(o.attrib.get("xyz") if o is not None else None, (0.0, 0.0, 0.0), f"link {name} collision origin")
                rpy = _floats(o.attrib.get("rpy") if o is not None else None, (0.0, 0.0, 0.0), f"link {name} collision rpy")
                boxes.append((_floats(box.attrib.get("size"), (0.0, 0.0, 0.0), f"link {name} box size"), xyz, rpy_matrix(rpy)))
            links[name] = UrdfLink(name=name, mass=mass, com_local=com, boxes=tuple(boxes))
        by_parent: dict[str, list[UrdfJoint]] = {}
        children: set[str] = set()
        for el in root_el.findall("joint"):
            name = el.attrib.get("name", "")
            jtype = el.attrib.get("type", "")
            if jtype not in _SUPPORTED:
                raise UrdfError(f"{path}: joint {name!r} has type {jtype!r}; the gate supports {', '.join(_SUPPORTED)}")
            parent_el, child_el = el.find("parent"), el.find("child")
            if parent_el is None or child_el is None:
                raise UrdfError(f"{path}: joint {name!r} lacks <parent> or <child>")
            parent, child = parent_el.attrib["link"], child_el.attrib["link"]
            if parent not in links or child not in links:
                raise UrdfError(f"{path}: joint {name!r} names an unknown link")
            o = el.find("origin")
            xyz = _floats(o.attrib.get("xyz") if o is not None else None, (0.0, 0.0, 0.0), f"joint {name} origin xyz")
            rpy = _floats(o.attrib.get("rpy") if o is not None else None, (0.0, 0.0, 0.0), f"joint {name} origin rpy")
            a = el.find("axis")
            axis = _floats(a.attrib.get("xyz") if a is not None else None, (1.0, 0.0, 0.0), f"joint {name} axis")
            if jtype in _MOVABLE:
                norm = float(np.linalg.norm(axis))
                if norm < 1e-12:
                    raise UrdfError(f"{path}: joint {name!r} has a zero axis")
                axis = axis / norm
            lim = el.find("limit")
            lower, upper, vel = -math.inf, math.inf, math.inf
            if lim is not None and jtype != "continuous":
                lower = float(lim.attrib.get("lower", 0.0))
                upper = float(lim.attrib.get("upper", 0.0))
            if lim is not None and "velocity" in lim.attrib:
                vel = float(lim.attrib["velocity"])
            if jtype in ("revolute", "prismatic") and lim is None:
                raise UrdfError(f"{path}: joint {name!r} ({jtype}) has no <limit>")
            mim = el.find("mimic")
            mimic = None
            if mim is not None:
                mimic = (mim.attrib["joint"], float(mim.attrib.get("multiplier", 1.0)), float(mim.attrib.get("offset", 0.0)))
            if child in children:
                raise UrdfError(f"{path}: link {child!r} has two parent joints")
            children.add(child)
            by_parent.setdefault(parent, []).append(
                UrdfJoint(name, jtype, parent, child, xyz, rpy_matrix(rpy), axis, lower, upper, vel, mimic)
            )
        roots = [n for n in links if n not in children]
        if len(roots) != 1:
            raise UrdfError(f"{path}: expected one root link, found {roots}")
        ordered: list[UrdfJoint] = []
        stack = list(reversed(by_parent.get(roots[0], [])))
        while stack:  # depth-first, children in file order (parents always before children)
            joint = stack.pop()
            ordered.append(joint)
            stack.extend(reversed(by_parent.get(joint.child, [])))
        movable = [j for j in ordered if j.type in _MOVABLE and j.mimic is None]
        names = tuple(j.name for j in movable)
        for j in ordered:
            if j.mimic is not None and j.mimic[0] not in names:
                raise UrdfError(f"{path}: mimic joint {j.name!r} follows {j.mimic[0]!r}, which is not a movable joint")
        return cls(
            name=root_el.attrib.get("name", path.stem), path=path, root=roots[0], links=links, joints=tuple(ordered),
            joint_names=names,
            lower=np.array([j.lower for j in movable]), upper=np.array([j.upper for j in movable]),
            velocity_limit=np.array([j.velocity for j in movable]),
            total_mass=float(sum(link.mass for link in links.values())),
        )

    def sole_box(self, frame: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(size, origin xyz, origin R) of the collision box carried by a sole frame."""
        link = self.links.get(frame)
        if link is None:
            raise UrdfError(f"robot {self.name!r} has no frame {frame!r}")
        if not link.boxes:
            raise UrdfError(f"robot {self.name!r}: sole frame {frame!r} carries no collision box")
        return link.boxes[0]


@lru_cache(maxsize=8)
def load_urdf(path: str) -> UrdfModel:
    """Parse a URDF once per process (keyed by its path)."""
    return UrdfModel.from_file(path)


def _mul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Batched product of A (3, 3, N) by B (3, 3, N) or by a constant B (3, 3)."""
    out = np.empty((3, 3, A.shape[2]))
    for i in range(3):
        a0, a1, a2 = A[i, 0], A[i, 1], A[i, 2]
        for k in range(3):
            out[i, k] = a0 * B[0, k] + a1 * B[1, k] + a2 * B[2, k]
    return out


def _apply(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R (3, 3, N) times a constant vector (3,): (3, N)."""
    return R[:, 0] * v[0] + R[:, 1] * v[1] + R[:, 2] * v[2]


def _axis_rotation(axis: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rodrigues rotation about a unit axis for each angle: (3, 3, N)."""
    kx, ky, kz = axis
    c, s = np.cos(theta), np.sin(theta)
    v = 1.0 - c
    R = np.empty((3, 3, theta.shape[0]))
    R[0, 0] = c + kx * kx * v
    R[0, 1] = kx * ky * v - kz * s
    R[0, 2] = kx * kz * v + ky * s
    R[1, 0] = ky * kx * v + kz * s
    R[1, 1] = c + ky * ky * v
    R[1, 2] = ky * kz * v - kx * s
    R[2, 0] = kz * kx * v - ky * s
    R[2, 1] = kz * ky * v + kx * s
    R[2, 2] = c + kz * kz * v
    return R


def _principal(axis: np.ndarray) -> tuple[int, float] | None:
    """(index, sign) when the axis is +-x, +-y or +-z, else None."""
    k = int(np.argmax(np.abs(axis)))
    if abs(abs(axis[k]) - 1.0) < 1e-12 and np.count_nonzero(np.abs(axis) > 1e-15) == 1:
        return k, float(np.sign(axis[k]))
    return None


def _rotate_principal(R: np.ndarray, k: int, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """R @ Rot_k(theta) for a principal axis k: two column updates instead of a product."""
    i, j = ((1, 2), (2, 0), (0, 1))[k]
    out = np.empty(np.broadcast_shapes(R.shape, (3, 3, c.shape[0])))
    Ri, Rj = R[:, i], R[:, j]
    out[:, k] = R[:, k]
    out[:, i] = Ri * c + Rj * s
    out[:, j] = Rj * c - Ri * s
    return out


@dataclass(frozen=True)
class _Step:
    joint: UrdfJoint
    src: int  # column of Q, -1 for fixed joints
    mult: float
    offset: float
    origin_identity: bool
    origin_nonzero: tuple[int, ...]  # components of origin_xyz that are not zero
    principal: tuple[int, float] | None


def _curvature_bound(model: UrdfModel) -> float:
    """L such that any link point x(q) along a straight joint-space segment dq bends by at most
    ``L * (sum_j w_j |dq_j|)**2``: a second derivative of a point with respect to two joint angles
    is at most its distance to a joint axis (2 x the reach from the root), 1 for prismatic terms."""
    path = {model.root: 0.0}
    for j in model.joints:
        travel = max(abs(j.lower), abs(j.upper)) if j.type == "prismatic" else 0.0
        path[j.child] = path[j.parent] + float(np.linalg.norm(j.origin_xyz)) + travel
    reach = max(path[name] + float(np.linalg.norm(link.com_local)) for name, link in model.links.items())
    return max(2.0 * reach, 1.0)


class BatchFK:
    """Batched forward kinematics and CoM of one URDF model over N states.

    ``joint_order`` is the column order of the ``Q`` arrays passed in (the plan's
    ``robot.joint_names``); it must name exactly the model's movable non-mimic joints.

    A link whose pose is the same in every state (a still leg under a fixed base) is
    computed once with a batch size of 1 and broadcast: plans move a few joints at a
    time, so this halves the work without changing a single digit of the result.
    """

    def __init__(self, model: UrdfModel, joint_order: Sequence[str] | None = None):
        self.model = model
        order = tuple(joint_order) if joint_order is not None else model.joint_names
        if len(set(order)) != len(order) or sorted(order) != sorted(model.joint_names):
            extra = sorted(set(order) - set(model.joint_names))
            missing = sorted(set(model.joint_names) - set(order))
            raise UrdfError(
                f"joint names do not match the URDF of {model.name!r}: unknown {extra}, missing {missing}, "
                f"{len(order)} given for {len(model.joint_names)}"
            )
        col = {n: i for i, n in enumerate(order)}
        self.joint_order = order
        steps = []
        for j in model.joints:
            if j.type == "fixed":
                src, mult, off = -1, 0.0, 0.0
            elif j.mimic is not None:
                src, mult, off = col[j.mimic[0]], j.mimic[1], j.mimic[2]
            else:
                src, mult, off = col[j.name], 1.0, 0.0
            steps.append(_Step(
                joint=j, src=src, mult=mult, offset=off,
                origin_identity=bool(np.array_equal(j.origin_rot, np.eye(3))),
                origin_nonzero=tuple(int(i) for i in np.flatnonzero(j.origin_xyz)),
                principal=_principal(j.axis) if j.type != "fixed" else None,
            ))
        self._steps = tuple(steps)
        self.column_weight = np.zeros(len(order))  # how many joint angles a column drives (mimics included)
        for st in steps:
            if st.src >= 0:
                self.column_weight[st.src] += abs(st.mult)
        self.curvature_bound = _curvature_bound(model)
        self._massive = tuple((link.name, link.mass, link.com_local, tuple(int(i) for i in np.flatnonzero(link.com_local)))
                              for link in model.links.values() if link.mass > 0.0)
        self.total_mass = model.total_mass

    def forward(self, base_pose: np.ndarray, Q: np.ndarray, still_columns: np.ndarray | None = None) -> tuple[dict, dict]:
        """World rotations (3, 3, n) and positions (3, n) of every link; n is N, or 1 for a link still in every state.

        ``still_columns`` (bool per column of Q): columns known to hold one value in every state.
        """
        Q = np.asarray(Q, dtype=float)
        if Q.ndim != 2 or Q.shape[1] != len(self.joint_order):
            raise UrdfError(f"Q must be (N, {len(self.joint_order)}), got {Q.shape}")
        base = np.asarray(base_pose, dtype=float)
        if base.ndim == 1:
            R0 = quaternion_matrix(base[3:])[:, :, None]
            p0 = base[:3, None].copy()
        else:
            R0 = np.moveaxis(quaternion_matrix(base[:, 3:]), 0, 2).copy()
            p0 = base[:, :3].T.copy()
        Rs = {self.model.root: R0}
        ps = {self.model.root: p0}
        QT = np.ascontiguousarray(Q.T)
        if still_columns is None:
            still_columns = np.all(Q == Q[:1], axis=0) if len(Q) else np.ones(Q.shape[1], dtype=bool)
        for st in self._steps:
            j = st.joint
            Rp, pp = Rs[j.parent], ps[j.parent]
            p = pp
            for i in st.origin_nonzero:
                p = p + Rp[:, i] * j.origin_xyz[i]
            R = Rp if st.origin_identity else _mul(Rp, j.origin_rot)
            if st.src >= 0:
                value = QT[st.src][:1] if (still_columns[st.src] and R.shape[2] == 1) else QT[st.src]
                if st.mult != 1.0 or st.offset != 0.0:
                    value = value * st.mult + st.offset
                if j.type == "prismatic":
                    if st.principal is not None:
                        k, sign = st.principal
                        p = p + R[:, k] * (sign * value)
                    else:
                        p = p + (R[:, 0] * j.axis[0] + R[:, 1] * j.axis[1] + R[:, 2] * j.axis[2]) * value
                elif st.principal is not None:
                    k, sign = st.principal
                    R = _rotate_principal(R, k, np.cos(value), sign * np.sin(value))
                else:
                    R = _mul(R, _axis_rotation(j.axis, value))
            Rs[j.child], ps[j.child] = R, p
        return Rs, ps

    def com_from(self, Rs: dict, ps: dict, n: int) -> np.ndarray:
        """Mass-weighted mean of the link CoMs: (n, 3)."""
        acc = np.zeros((3, n))
        for name, mass, local, nonzero in self._massive:
            c = ps[name]
            R = Rs[name]
            for i in nonzero:
                c = c + R[:, i] * local[i]
            acc += mass * c
        return (acc / self.total_mass).T

    def frame(self, Rs: dict, ps: dict, name: str, n: int) -> tuple[np.ndarray, np.ndarray]:
        """World (R (n, 3, 3), p (n, 3)) of a link/frame from a ``forward`` result."""
        if name not in Rs:
            raise UrdfError(f"robot {self.model.name!r} has no frame {name!r}")
        R = np.broadcast_to(Rs[name], (3, 3, n))
        p = np.broadcast_to(ps[name], (3, n))
        return np.moveaxis(R, 2, 0).copy(), p.T.copy()

    def com_and_frames(self, base_pose: np.ndarray, Q: np.ndarray, frames: Sequence[str]) -> tuple[np.ndarray, dict]:
        """CoM (N, 3) and world (R (N, 3, 3), p (N, 3)) of the named frames.

        Evaluated in chunks of ``CHUNK`` states: the temporaries then stay in the CPU
        cache instead of being fresh pages from the kernel at every operation, which
        is worth a factor of two on large batches.
        """
        Q = np.asarray(Q, dtype=float)
        base = np.asarray(base_pose, dtype=float)
        n = Q.shape[0] if Q.ndim == 2 else 0
        com = np.empty((n, 3))
        out = {f: (np.empty((n, 3, 3)), np.empty((n, 3))) for f in frames}
        still = np.all(Q == Q[:1], axis=0) if n else None  # once for the whole batch
        for start in range(0, max(n, 1), CHUNK):
            stop = min(n, start + CHUNK)
            Rs, ps = self.forward(base if base.ndim == 1 else base[start:stop], Q[start:stop], still)
            m = stop - start
            com[start:stop] = self.com_from(Rs, ps, m)
            for f in frames:
                R, p = self.frame(Rs, ps, f, m)
                out[f][0][start:stop], out[f][1][start:stop] = R, p
        return com, out
