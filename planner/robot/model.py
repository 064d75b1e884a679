"""The robot model: an immutable description loaded once, plus scratch data per computation.

Like pinocchio's ``Model``/``Data`` split, :class:`RobotModel` says what the robot
is (URDF, spec, joint order, limits, mimic map) and can be shared by every planner
thread; :meth:`RobotModel.create_data` gives the buffers one computation needs.

Configurations on the wire (``q``) list the non-mimic joints in ``joint_names``
order; mimic joints follow their master through the URDF's multiplier and offset
when the pinocchio configuration is built.
"""

from __future__ import annotations

import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, TypeVar

import numpy as np
import pinocchio as pin

from planner.errors import UnknownNameError

T = TypeVar("T")
from planner.robot.registry import load_spec, urdf_path, urdf_sha256
from planner.robot.spec import RobotSpec, Side


class DerivedTables:
    """The tables derived from one robot model, each built once.

    Threads share a model, so a table is built under a lock (re-entrant: one table's build may ask
    for another) and then only read. Pickled without the lock, as its tables.
    """

    def __init__(self) -> None:
        self._tables: dict[Any, Any] = {}
        self._lock = threading.RLock()

    def get(self, key: Any, build: Callable[[], T]) -> T:
        """The table under ``key``, built by ``build()`` the first time any thread asks."""
        try:
            return self._tables[key]
        except KeyError:
            pass
        with self._lock:
            if key not in self._tables:
                self._tables[key] = build()
            return self._tables[key]

    def __getstate__(self) -> dict[Any, Any]:
        with self._lock:
            return dict(self._tables)

    def __setstate__(self, tables: dict[Any, Any]) -> None:
        self._tables = dict(tables)
        self._lock = threading.RLock()


@dataclass(frozen=True)
class RobotModel:
    name: str
    spec: RobotSpec
    urdf_path: Path
    urdf_sha256: str
    pin_model: pin.Model = field(repr=False)
    joint_names: tuple[str, ...]
    lower: np.ndarray = field(repr=False)
    upper: np.ndarray = field(repr=False)
    velocity_limit: np.ndarray = field(repr=False)
    acceleration_limit: np.ndarray = field(repr=False)
    total_mass: float
    #: pinocchio q index (after the 7 free-flyer numbers) <- mult * q[src] + offset
    pin_q_index: np.ndarray = field(repr=False)
    q_source: np.ndarray = field(repr=False)
    q_mult: np.ndarray = field(repr=False)
    q_offset: np.ndarray = field(repr=False)
    mimic: dict[str, tuple[str, float, float]] = field(default_factory=dict, repr=False)
    #: Tables derived from this model once and read-only after (see :meth:`derived`).
    _derived: DerivedTables = field(default_factory=DerivedTables, init=False, repr=False, compare=False)

    def derived(self, key: Any, build: Callable[[], T]) -> T:
        """The table ``build()`` derives from this model, built on first use and kept with the model.

        For immutable data that depends on the model alone (joint tables for the compiled
        kernels, a hand's collision shapes): the pinocchio Model/Data split, with the derived
        tables on the model side. Scratch buffers never go here; each computation owns its own.
        """
        return self._derived.get(key, build)

    @property
    def nq(self) -> int:
        return len(self.joint_names)

    def create_data(self) -> pin.Data:
        return self.pin_model.createData()

    def joint_index(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise UnknownNameError(
                f"robot {self.name!r} has no joint {name!r}; valid joints: {', '.join(self.joint_names)}"
            ) from None

    def joint_indices(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        return np.array([self.joint_index(n) for n in names], dtype=int)

    def frame_id(self, frame: str) -> int:
        if not self.pin_model.existFrame(frame):
            names = sorted({f.name for f in self.pin_model.frames if f.name != "universe"})
            raise UnknownNameError(f"robot {self.name!r} has no frame {frame!r}; valid frames: {', '.join(names)}")
        return self.pin_model.getFrameId(frame)

    def to_pin_q(self, base_pose: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Pinocchio configuration: free-flyer ``[x y z qx qy qz qw]`` then every joint, mimics included; of a
        state ``q`` (n,), or one row per state of ``q`` (N, n)."""
        q = np.asarray(q)
        if q.ndim == 1:  # one state, the common call (kinematics, IK steps): plain indexing, half the cost of ``...``
            out = np.empty(self.pin_model.nq)
            out[:7] = base_pose
            out[self.pin_q_index] = self.q_mult * q[self.q_source] + self.q_offset
            return out
        out = np.empty((len(q), self.pin_model.nq))
        out[:, :7] = base_pose
        out[:, self.pin_q_index] = self.q_mult * q[:, self.q_source] + self.q_offset
        return out

    def default_q(self) -> np.ndarray:
        """Zero posture moved inside the limits, then the spec's default posture."""
        q = np.clip(np.zeros(self.nq), self.lower, self.upper)
        for joint, value in self.spec.default_posture_rad.items():
            q[self.joint_index(joint)] = value
        return q

    def arm_indices(self, side: Side) -> np.ndarray:
        return self.joint_indices(self.spec.arms[side].chain)

    def waist_indices(self) -> np.ndarray:
        return self.joint_indices(self.spec.waist)

    def check_q(self, q: np.ndarray, what: str = "q") -> None:
        """Raise ValueError naming the first bad element of a configuration."""
        if q.shape != (self.nq,):
            raise ValueError(f"{what} has {q.size} values, robot {self.name!r} has {self.nq} joints")
        bad = np.flatnonzero(~np.isfinite(q))
        if bad.size:
            raise ValueError(f"{what}[{bad[0]}] ({self.joint_names[bad[0]]}) is {q[bad[0]]}; values must be finite")


def _parse_mimics(path: Path) -> dict[str, tuple[str, float, float]]:
    mimics: dict[str, tuple[str, float, float]] = {}
    for joint in ET.parse(path).getroot().iter("joint"):
        m = joint.find("mimic")
        if m is not None:
            mimics[joint.attrib["name"]] = (
                m.attrib["joint"],
                float(m.attrib.get("multiplier", 1.0)),
                float(m.attrib.get("offset", 0.0)),
            )
    return mimics


@lru_cache(maxsize=16)
def load_robot(name: str = "hrp5p") -> RobotModel:
    """Load a robot by name, once per process (a bounded cache: a process plans for a few robots)."""
    spec = load_spec(name)
    path = urdf_path(name)
    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    mimics = _parse_mimics(path)
    joint_names: list[str] = []
    for jid in range(2, model.njoints):
        jname = model.names[jid]
        if model.nqs[jid] != 1:
            raise ValueError(f"robot {name!r}: joint {jname!r} has {model.nqs[jid]} coordinates; only 1-DoF joints are supported")
        if jname not in mimics:
            joint_names.append(jname)
    index = {n: i for i, n in enumerate(joint_names)}
    pin_idx, src, mult, off = [], [], [], []
    for jid in range(2, model.njoints):
        jname = model.names[jid]
        master, k, b = mimics.get(jname, (jname, 1.0, 0.0))
        pin_idx.append(model.idx_qs[jid])
        src.append(index[master])
        mult.append(k)
        off.append(b)
    vids = [model.idx_vs[model.getJointId(n)] for n in joint_names]
    qids = [model.idx_qs[model.getJointId(n)] for n in joint_names]
    lower = np.array(model.lowerPositionLimit)[qids]
    upper = np.array(model.upperPositionLimit)[qids]
    vel = np.array(model.velocityLimit)[vids]
    acc = np.array([spec.acceleration_limit(n) for n in joint_names])
    robot = RobotModel(
        name=spec.name,
        spec=spec,
        urdf_path=path,
        urdf_sha256=urdf_sha256(name),
        pin_model=model,
        joint_names=tuple(joint_names),
        lower=lower,
        upper=upper,
        velocity_limit=vel,
        acceleration_limit=acc,
        total_mass=float(pin.computeTotalMass(model)),
        pin_q_index=np.array(pin_idx, dtype=int),
        q_source=np.array(src, dtype=int),
        q_mult=np.array(mult),
        q_offset=np.array(off),
        mimic=mimics,
    )
    if not spec.default_posture_rad:
        # the spec names no posture: a ready posture is derived (arms down, hands clear; cached)
        from planner.robot.ready_posture import cached_ready_posture

        robot = replace(robot, spec=spec.model_copy(update={"default_posture_rad": cached_ready_posture(robot)}))
    return robot


def frame_poses(
    robot: RobotModel, data: pin.Data, base_pose: np.ndarray, q: np.ndarray, frames: list[str]
) -> list[pin.SE3]:
    """World placements of the named frames, one state."""
    model = robot.pin_model
    pin.forwardKinematics(model, data, robot.to_pin_q(base_pose, q))
    out = []
    for f in frames:
        fid = robot.frame_id(f)
        out.append(pin.updateFramePlacement(model, data, fid).copy())
    return out
