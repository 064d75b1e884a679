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

Batched layout: vectors ``(3, N)``, so each component is one contiguous array. The
CoM and frame origins are carried from the leaves up (see :meth:`BatchFK.com_and_points`):
rotated vectors, never 3 x 3 matrix products.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np

from robot_bridge.errors import BridgeError

_MOVABLE = ("revolute", "continuous", "prismatic")
#: States per evaluation chunk: large enough to amortise the per-chunk work, small enough that the moving
#: joints' temporaries stay in the CPU cache.
CHUNK = 8192
_SUPPORTED = (*_MOVABLE, "fixed")


class UrdfError(BridgeError, ValueError):
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


def rotate(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R (3, 3, N) times vectors v (3, N), (3, 1) or one constant vector (3,): (3, N). A constant vector's zero
    components are skipped (adding their zero terms changes no finite value)."""
    if np.ndim(v) == 1:
        terms = [R[:, k] * v[k] for k in range(3) if v[k] != 0.0]
        return sum(terms[1:], terms[0]) if terms else np.zeros(R.shape[::2])
    return R[:, 0] * v[0] + R[:, 1] * v[1] + R[:, 2] * v[2]


def _principal(axis: np.ndarray) -> tuple[int, float] | None:
    """(index, sign) when the axis is +-x, +-y or +-z, else None."""
    k = int(np.argmax(np.abs(axis)))
    if abs(abs(axis[k]) - 1.0) < 1e-12 and np.count_nonzero(np.abs(axis) > 1e-15) == 1:
        return k, float(np.sign(axis[k]))
    return None


@dataclass(frozen=True)
class _Step:
    joint: UrdfJoint
    src: int  # column of Q, -1 for fixed joints
    mult: float
    offset: float
    origin_identity: bool
    origin_nonzero: bool  # origin_xyz is not zero: the joint adds an offset
    principal: tuple[int, float] | None


class BatchFK:
    """Batched CoM and frame origins of one URDF model over N states.

    ``joint_order`` is the order of the joint columns passed in (the plan's
    ``robot.joint_names``); it must name exactly the model's movable non-mimic joints.
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
                origin_nonzero=bool(np.any(j.origin_xyz)),
                principal=_principal(j.axis) if j.type != "fixed" else None,
            ))
        self._steps = tuple(steps)
        self._massive = tuple((link.name, link.mass, link.com_local) for link in model.links.values() if link.mass > 0.0)
        self.total_mass = model.total_mass
        below: dict[str, float] = {name: link.mass for name, link in model.links.items()}
        for j in reversed(model.joints):  # children before parents
            below[j.parent] += below[j.child]
        self._subtree_mass = tuple(below[st.joint.child] for st in steps)

    def com_and_points(self, base_pose: np.ndarray, columns: Sequence[np.ndarray], n: int,
                       frames: Sequence[str] = ()) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """CoM (n, 3) and world origins (n, 3) of the named frames, from the leaves up, with vectors only.

        ``columns`` holds one array per joint of ``joint_order``: its n values, or a single
        value when the joint holds still in every state (then the joint costs one scalar
        cos/sin instead of n). ``base_pose`` is one pose [7] or one per state (n, 7).

        Why from the leaves: the CoM only needs each subtree's first mass moment carried
        into its parent's frame (``M o + R_o R(q) h``, h in the child's frame), and a frame
        origin only its chain of ``o + R_o R(q) x``: rotated vectors instead of the 3 x 3
        rotation products of a root-to-leaf pass. A subtree that holds still in the batch
        (a leg, the head) is carried up once as one constant vector, so the per-state work
        is only along the paths from the moving joints to the root. The tests compare the
        result with the planner's kinematics, pinocchio and a per-state reference.
        """
        if len(columns) != len(self.joint_order):
            raise UrdfError(f"expected {len(self.joint_order)} joint columns, got {len(columns)}")
        cols = [np.atleast_1d(np.asarray(c, dtype=float)) for c in columns]
        for name, c in zip(self.joint_order, cols):
            if c.ndim != 1 or c.shape[0] not in (1, n):
                raise UrdfError(f"joint {name}: expected {n} values or one, got shape {c.shape}")
        missing = [f for f in frames if f not in self.model.links]
        if missing:
            raise UrdfError(f"robot {self.model.name!r} has no frame {missing[0]!r}")
        base = np.asarray(base_pose, dtype=float)
        # A joint moves its output in the batch when its own column does or its child's subtree does.
        moves = [False] * len(self._steps)
        subtree_moves = {name: False for name in self.model.links}
        for k in range(len(self._steps) - 1, -1, -1):  # children before parents
            st = self._steps[k]
            moves[k] = subtree_moves[st.joint.child] or (st.src >= 0 and cols[st.src].shape[0] > 1)
            subtree_moves[st.joint.parent] |= moves[k]
        # What holds still is carried up once for the whole batch; only the moving joints per chunk.
        moment = {name: (mass * local)[:, None] for name, mass, local in self._massive}
        points: dict[str, dict[str, np.ndarray]] = {}
        for f in frames:
            points.setdefault(f, {})[f] = np.zeros((3, 1))
        self._upward(cols, [not m for m in moves], moment, points)
        com = np.empty((n, 3))
        out = {f: np.empty((n, 3)) for f in frames}
        per_sample = base.ndim != 1
        if not per_sample:  # one constant pose: its rotation once for the whole batch
            R0, p0 = quaternion_matrix(base[3:]), base[:3, None]
            world = lambda v, w: R0 @ v + w * p0  # noqa: E731
        for start in range(0, max(n, 1), CHUNK):
            stop = min(n, start + CHUNK)
            part = [c if c.shape[0] == 1 else c[start:stop] for c in cols]
            m_part, p_part = dict(moment), {link: dict(v) for link, v in points.items()}
            self._upward(part, moves, m_part, p_part)
            if per_sample:  # one pose per state: this chunk's rotations
                Rs = np.moveaxis(quaternion_matrix(base[start:stop, 3:]), 0, 2)
                ps = base[start:stop, :3].T
                world = lambda v, w: rotate(Rs, v) + w * ps  # noqa: E731
            root_m = m_part.get(self.model.root, np.zeros((3, 1)))
            com[start:stop] = (world(root_m, self.total_mass) / self.total_mass).T
            root_p = p_part.get(self.model.root, {})
            for f in frames:
                out[f][start:stop] = world(root_p[f], 1.0).T
        return com, out

    def _upward(self, cols: list[np.ndarray], select: list[bool], moment: dict[str, np.ndarray],
                points: dict[str, dict[str, np.ndarray]]) -> None:
        """Carry the selected joints' child data (first mass moments, frame origins) into their parents, leaves first.

        ``moment[link]`` (3, m) and ``points[link][frame]`` (3, m) are in ``link``'s frame,
        m being the chunk's size or 1; both dicts are updated in place.
        """
        for k in range(len(self._steps) - 1, -1, -1):
            if not select[k]:
                continue
            st = self._steps[k]
            j = st.joint
            h = moment.pop(j.child, None)
            pts = points.pop(j.child, None)
            if h is None and not pts:
                continue
            value = None
            if st.src >= 0:
                value = cols[st.src]
                if st.mult != 1.0 or st.offset != 0.0:
                    value = value * st.mult + st.offset
            if h is not None:
                h = self._joint_up(st, h, self._subtree_mass[k], value)
                moment[j.parent] = h if j.parent not in moment else moment[j.parent] + h
            if pts:
                up = points.setdefault(j.parent, {})
                for f, v in pts.items():
                    up[f] = self._joint_up(st, v, 1.0, value)

    @staticmethod
    def _joint_up(st: "_Step", v: np.ndarray, w: float, value: np.ndarray | None) -> np.ndarray:
        """A vector of the child's frame (a moment of weight ``w``, or a point: w = 1) in the parent's frame."""
        j = st.joint
        if value is not None:
            if j.type == "prismatic":
                v = v + (w * j.axis)[:, None] * value
            elif st.principal is not None:
                k, sign = st.principal
                i, jj = ((1, 2), (2, 0), (0, 1))[k]
                c, s = np.cos(value), sign * np.sin(value)
                out = np.empty((3, max(v.shape[1], value.shape[0])))
                out[k] = v[k]
                out[i] = c * v[i] - s * v[jj]
                out[jj] = s * v[i] + c * v[jj]
                v = out
            else:
                c, s = np.cos(value), np.sin(value)
                a = j.axis[:, None]
                v = c * v + s * np.cross(a, v, axis=0) + (1.0 - c) * a * (a * v).sum(axis=0)
        if not st.origin_identity:
            v = j.origin_rot @ v
        if st.origin_nonzero:
            v = v + (w * j.origin_xyz)[:, None]
        return v
