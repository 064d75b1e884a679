"""Robot spec files (``schema: regrasp.robot/1``): any humanoid from its own URDF.

A spec file names the URDF (relative to the file, absolute, or ``package://NAME/...`` /
``package:///NAME/...`` resolved through the file's ``packages`` map or ``ROS_PACKAGE_PATH``),
the links that carry the feet and hands, the jaws (or a rigid hand), the upright posture, the
acceleration and effort limits and the grip. :func:`derive` validates it against the URDF (every
error names the field), derives what the planner needs (the leg, arm, waist and neck chains from
the URDF's tree) and writes the derived URDF (the URDF plus the sole and TCP frames it lacks, mesh
collisions replaced by fitted boxes) to a cache folder, never beside the robot's own files: third-party
models keep their licences. A URDF that needs nothing of that (it has every frame, the soles' boxes and
no mesh collision, as the built-in ``hrp5p.urdf`` and ``jvrc1.urdf``) is used as it is, byte for byte.
"""

from __future__ import annotations

import hashlib
import os
import site
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from planner.errors import InputError
from planner.robot.spec import (
    ArmSpec,
    FootSpec,
    GripperSpec,
    GripSpec,
    RobotSpec,
    UprightSpec,
)
from planner.robot.spec_collision import parse_collision, urdf_origin, write_link_shapes
from planner.robot.urdf_checks import check_inertials, check_mesh_file

ROBOT_SCHEMA = "regrasp.robot/1"
CACHE_ENV = "REGRASP_CACHE_DIR"
DEFAULT_CACHE_DIR = Path("~/.cache/hrp-regrasp")
SOLE_THICKNESS_M = 0.02
_MOVABLE = ("revolute", "continuous", "prismatic")


class RobotSpecError(InputError):
    """A robot spec file that cannot be used; the message names the field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FootEntry(_Strict):
    frame: str
    link: str
    pose_in_link: list[float] | None = Field(None, min_length=7, max_length=7)
    size: list[float] | None = Field(None, min_length=2, max_length=2)
    #: the leg's six joints in the order hip yaw, roll, pitch, knee, ankle pitch, ankle roll (the order the
    #: stance IK lays its bent-knee start out in); default: the URDF's order from the root
    chain: list[str] | None = Field(None, min_length=6, max_length=6)


class JawEntry(_Strict):
    joints: list[str] = Field(min_length=1)
    open: float
    closed: float
    width_m: list[float] = Field(min_length=2, max_length=2)


class HandEntry(_Strict):
    frame: str
    link: str
    pose_in_link: list[float] | None = Field(None, min_length=7, max_length=7)
    jaw: JawEntry | None


class UprightEntry(_Strict):
    pelvis_height_m: float = Field(gt=0)
    foot_y_m: float = Field(gt=0)


class RobotFile(_Strict):
    schema_: Literal["regrasp.robot/1"] = Field(alias="schema")
    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
    description: str = ""
    urdf: str
    packages: dict[str, str] = Field(default_factory=dict)
    feet: dict[Literal["left", "right"], FootEntry]
    hands: dict[Literal["left", "right"], HandEntry]
    upright: UprightEntry
    acceleration_limits: dict[str, float]
    effort_limits: dict[str, float] = Field(default_factory=dict)
    grip: GripSpec | None = None
    #: ``auto`` or shapes per link, read by :func:`planner.robot.spec_collision.parse_collision` (its errors
    #: name the entry)
    collision: Any = "auto"
    #: the robot's SRDF (MoveIt's semantic description); its ``<disable_collisions>`` pairs are not checked
    srdf: str | None = None
    #: a ``<group_state>`` of the SRDF (e.g. ``half_sitting``) whose joint values start the default posture
    #: (``default_posture_rad`` overrides them)
    srdf_posture: str | None = None
    #: more link pairs not checked for self-collision, [[link_a, link_b], ...]
    disable_collisions: list[list[str]] = Field(default_factory=list)
    default_posture_rad: dict[str, float] = Field(default_factory=dict)
    limit_sources: str = ""
    license_notice: str | None = None
    #: the physics twin's servo gains, rotor inertia and contact (robot_bridge.physics.settings.SimSection reads it)
    sim: dict[str, Any] | None = None


@dataclass(frozen=True)
class DerivedRobot:
    """A spec file made usable: the planner's spec, the derived URDF and what the derivation did."""

    spec: RobotSpec
    source: Path
    urdf: Path
    #: the URDF the planner loads: the derived one in the cache folder, or ``urdf`` itself when nothing is derived
    derived_urdf: Path
    created_frames: tuple[str, ...]
    limit_sources: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    @property
    def urdf_as_is(self) -> bool:
        """Whether the URDF needed nothing derived (frames, sole boxes, fitted collisions) and is used unchanged."""
        return self.derived_urdf == self.urdf


def is_spec_path(ref: str) -> bool:
    """Whether a robot reference is a spec file path (not a registered name)."""
    return ref.endswith((".yaml", ".yml")) or "/" in ref or os.sep in ref


def cache_dir() -> Path:
    env = os.environ.get(CACHE_ENV)
    return (Path(env).expanduser() if env else DEFAULT_CACHE_DIR.expanduser()) / "robots"


def resolve_urdf(ref: str, spec_dir: Path, packages: dict[str, str]) -> Path:
    """The URDF file a spec names: relative to the spec, absolute, or a package:// URI."""
    return _resolve(ref, spec_dir, packages, "urdf")


def _resolve(ref: str, spec_dir: Path, packages: dict[str, str], what: str) -> Path:
    m = re.match(r"^package://(/?)([^/]+)/(.*)$", ref)
    if m:
        pkg, rest = m.group(2), m.group(3)
        roots = [Path(packages[pkg]).expanduser() if Path(packages[pkg]).is_absolute() else spec_dir / packages[pkg]] \
            if pkg in packages else []
        roots += [Path(p) / pkg for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
        # packages installed as Python wheels in the cmeel layout (<site-packages>/cmeel.prefix/share/PKG)
        roots += [Path(p) / "cmeel.prefix" / "share" / pkg for p in site.getsitepackages()]
        for root in roots:
            if (root / rest).exists():
                return (root / rest).resolve()
        raise RobotSpecError(f"{what}: package {pkg!r} of {ref!r} is not found; give its folder in the spec's "
                             f"`packages: {{{pkg}: DIR}}` or in ROS_PACKAGE_PATH")
    path = Path(ref).expanduser()
    path = path if path.is_absolute() else spec_dir / path
    if not path.is_file():
        raise RobotSpecError(f"{what}: no file {ref!r} (looked at {path})")
    return path.resolve()


def read_spec_file(path: str | Path) -> RobotFile:
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise RobotSpecError(f"cannot read robot spec {path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise RobotSpecError(f"robot spec {path} is not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise RobotSpecError(f"robot spec {path}: expected a mapping with schema {ROBOT_SCHEMA!r}")
    if data.get("schema") != ROBOT_SCHEMA:
        raise RobotSpecError(f"schema: expected {ROBOT_SCHEMA!r}, got {data.get('schema')!r}")
    try:
        return RobotFile.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise RobotSpecError(f"{where}: {first['msg']} (robot spec {path})") from None


@dataclass
class _Urdf:
    root: ET.Element
    links: set[str]
    joints: dict[str, ET.Element]
    parent_joint: dict[str, ET.Element]  # child link -> joint
    root_link: str

    @classmethod
    def parse(cls, path: Path) -> "_Urdf":
        try:
            root = ET.parse(path).getroot()
        except (OSError, ET.ParseError) as exc:
            raise RobotSpecError(f"urdf: cannot read {path}: {exc}") from None
        links = {el.attrib["name"] for el in root.findall("link")}
        joints = {el.attrib["name"]: el for el in root.findall("joint")}
        parent_joint = {el.find("child").attrib["link"]: el for el in joints.values()}
        roots = [name for name in links if name not in parent_joint]
        if len(roots) != 1:
            raise RobotSpecError(f"urdf: expected one root link, found {sorted(roots)}")
        return cls(root, links, joints, parent_joint, roots[0])

    def is_movable(self, joint: ET.Element) -> bool:
        return joint.attrib.get("type") in _MOVABLE and joint.find("mimic") is None

    def chain(self, link: str) -> list[str]:
        """Movable non-mimic joints from the root to ``link``, root first."""
        out = []
        while link in self.parent_joint:
            j = self.parent_joint[link]
            if self.is_movable(j):
                out.append(j.attrib["name"])
            link = j.find("parent").attrib["link"]
        return out[::-1]

    def subtree_joints(self, link: str) -> list[str]:
        """Movable non-mimic joints below ``link`` (in its subtree)."""
        out, todo = [], [link]
        while todo:
            parent = todo.pop()
            for j in self.joints.values():
                if j.find("parent").attrib["link"] == parent:
                    if self.is_movable(j):
                        out.append(j.attrib["name"])
                    todo.append(j.find("child").attrib["link"])
        return out

    def link(self, name: str) -> ET.Element | None:
        """The ``<link>`` element of that name, or None."""
        return next((e for e in self.root.findall("link") if e.attrib["name"] == name), None)

    def has_mesh_collisions(self) -> bool:
        return self.root.find("link/collision/geometry/mesh") is not None

    def effort(self, joint: str) -> float | None:
        lim = self.joints[joint].find("limit")
        if lim is None or "effort" not in lim.attrib:
            return None
        v = float(lim.attrib["effort"])
        return v if v > 0 else None


def _add_frame(urdf: _Urdf, frame: str, link: str, pose: list[float], field_name: str,
               box: tuple[float, float] | None = None) -> None:
    try:
        xyz, rpy = urdf_origin(pose)
    except ValueError:
        raise RobotSpecError(f"{field_name}.pose_in_link: the quaternion is zero") from None
    j = ET.SubElement(urdf.root, "joint", {"name": f"{frame}_frame_joint", "type": "fixed"})
    ET.SubElement(j, "parent", {"link": link})
    ET.SubElement(j, "child", {"link": frame})
    ET.SubElement(j, "origin", {"xyz": xyz, "rpy": rpy})
    el = ET.SubElement(urdf.root, "link", {"name": frame})
    if box is not None:
        _sole_box(el, box)
    urdf.links.add(frame)
    urdf.joints[j.attrib["name"]] = j
    urdf.parent_joint[frame] = j


def _place_frame(urdf: _Urdf, frame: str, link: str, pose: list[float], field_name: str, notes: list[str],
                 box: list[float] | None = None) -> bool:
    """Where the URDF has ``frame`` and the spec places it too, the spec wins: a plain frame (a massless leaf on a
    fixed joint) is moved to ``pose`` on ``link`` (its collision replaced by the sole ``box`` when given); whether it
    moved. A frame that is more than that is a conflict the spec cannot settle: refused, saying how to fix it."""
    try:
        xyz, rpy = urdf_origin(pose)
    except ValueError:
        raise RobotSpecError(f"{field_name}.pose_in_link: the quaternion is zero") from None
    joint = urdf.parent_joint.get(frame)
    el = urdf.link(frame)
    children = [j for j in urdf.joints.values() if j.find("parent").attrib["link"] == frame]
    mass_el = el.find("inertial/mass") if el is not None else None
    plain = (joint is not None and joint.attrib.get("type") == "fixed" and not children
             and (mass_el is None or float(mass_el.attrib.get("value", "0")) == 0.0))
    if not plain:
        raise RobotSpecError(f"{field_name}.frame: the URDF already has a link {frame!r} that is not a plain frame (a "
                             "massless leaf on a fixed joint), so the spec's pose_in_link cannot move it; drop "
                             f"pose_in_link to use the URDF's {frame!r}, or name another frame for the spec's")
    origin = joint.find("origin")
    old = _origin_matrix(origin)
    new = _origin_matrix(ET.Element("origin", {"xyz": xyz, "rpy": rpy}))
    same_box = box is None or _box_size(el) == (float(box[0]), float(box[1]), SOLE_THICKNESS_M)
    if joint.find("parent").attrib["link"] == link and np.allclose(old, new, atol=1e-9) and same_box:
        return False  # the URDF's frame is where the spec puts it
    before = joint.find("parent").attrib["link"]
    joint.find("parent").attrib["link"] = link
    if origin is None:
        origin = ET.SubElement(joint, "origin")
    origin.attrib.update({"xyz": xyz, "rpy": rpy})
    if box is not None:
        for col in el.findall("collision"):
            el.remove(col)
        _sole_box(el, (box[0], box[1]))
    notes.append(f"{field_name}: the URDF's {frame!r} (on {before}) is moved to the spec's pose_in_link on {link}"
                 + (f" with its {box[0]} x {box[1]} m sole box" if box is not None else "") + " (the spec wins)")
    return True


def _origin_matrix(origin: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if origin is not None:
        T[:3, :3] = _rpy_matrix([float(v) for v in origin.attrib.get("rpy", "0 0 0").split()])
        T[:3, 3] = [float(v) for v in origin.attrib.get("xyz", "0 0 0").split()]
    return T


def _box_size(link_el: ET.Element) -> tuple[float, ...] | None:
    box = link_el.find("collision/geometry/box")
    return tuple(float(v) for v in box.attrib["size"].split()) if box is not None else None


def _sole_box(link_el: ET.Element, size: tuple[float, float]) -> None:
    col = ET.SubElement(link_el, "collision")
    ET.SubElement(col, "origin", {"xyz": f"0 0 {-SOLE_THICKNESS_M / 2!r}", "rpy": "0 0 0"})
    geo = ET.SubElement(col, "geometry")
    ET.SubElement(geo, "box", {"size": f"{size[0]!r} {size[1]!r} {SOLE_THICKNESS_M!r}"})


def derive(path: str | Path, progress: Callable[[str], None] = lambda message: None) -> DerivedRobot:
    """Validate a spec file against its URDF and write the derived URDF if the URDF needs one (else it is used as
    it is); errors name the field. ``progress(message)`` hears of the slow part (fitting boxes to meshes)."""
    path = Path(path).expanduser().resolve()
    rf = read_spec_file(path)
    urdf_file = resolve_urdf(rf.urdf, path.parent, rf.packages)
    urdf = _Urdf.parse(urdf_file)
    created: list[str] = []
    sole_boxes_added: list[str] = []
    moved: list[str] = []  # frames of the URDF that the spec places elsewhere (the spec wins)
    notes: list[str] = []
    massless, point_masses = check_inertials(urdf.root, RobotSpecError)
    if massless or point_masses:
        notes.append(f"masses: {massless} massless link(s) (frames), {point_masses} point mass(es) (zero inertia)")
    for side in ("left", "right"):
        if side not in rf.feet:
            raise RobotSpecError(f"feet.{side}: missing")
        if side not in rf.hands:
            raise RobotSpecError(f"hands.{side}: missing")
    feet: dict[str, FootSpec] = {}
    for side, foot in rf.feet.items():
        where = f"feet.{side}"
        if foot.link not in urdf.links:
            raise RobotSpecError(f"{where}.link: the URDF has no link {foot.link!r}")
        if foot.frame not in urdf.links:
            if foot.pose_in_link is None or foot.size is None:
                raise RobotSpecError(f"{where}.frame: the URDF has no frame {foot.frame!r}; give pose_in_link and size "
                                     "to create it on the link")
            _add_frame(urdf, foot.frame, foot.link, foot.pose_in_link, where, box=(foot.size[0], foot.size[1]))
            created.append(foot.frame)
        else:
            if foot.pose_in_link is not None and _place_frame(urdf, foot.frame, foot.link, foot.pose_in_link, where,
                                                              notes, box=foot.size):
                moved.append(foot.frame)
            el = urdf.link(foot.frame)
            if el.find("collision/geometry/box") is None:
                if foot.size is None:
                    raise RobotSpecError(f"{where}.size: frame {foot.frame!r} carries no sole box; give the sole's size")
                _sole_box(el, (foot.size[0], foot.size[1]))
                sole_boxes_added.append(foot.frame)
                notes.append(f"sole box {foot.size} added to {foot.frame}")
        chain = urdf.chain(foot.frame)
        if len(chain) != 6:
            raise RobotSpecError(f"{where}.link: {len(chain)} movable joints lead from the root to {foot.link!r} "
                                 f"({', '.join(chain)}); a leg needs 6")
        if foot.chain is not None:
            if sorted(foot.chain) != sorted(chain):
                raise RobotSpecError(f"{where}.chain: the leg's joints in the URDF are {', '.join(chain)}; the chain "
                                     f"must list these six in the IK's order, got {', '.join(foot.chain)}")
            chain = list(foot.chain)
        feet[side] = FootSpec(frame=foot.frame, chain=chain)
    leg_joints = {j for f in feet.values() for j in f.chain}
    arm_paths: dict[str, list[str]] = {}
    grippers: dict[str, GripperSpec] = {}
    for side, hand in rf.hands.items():
        where = f"hands.{side}"
        if hand.link not in urdf.links:
            raise RobotSpecError(f"{where}.link: the URDF has no link {hand.link!r}")
        if hand.frame not in urdf.links:
            if hand.pose_in_link is None:
                raise RobotSpecError(f"{where}.frame: the URDF has no frame {hand.frame!r}; give pose_in_link to "
                                     "create it on the link")
            _add_frame(urdf, hand.frame, hand.link, hand.pose_in_link, where)
            created.append(hand.frame)
        elif hand.pose_in_link is not None and _place_frame(urdf, hand.frame, hand.link, hand.pose_in_link, where,
                                                            notes):
            moved.append(hand.frame)
        if hand.jaw is None:
            # a rigid hand: no joint opens or closes it, and a held object attaches at its TCP
            arm_paths[side] = list(urdf.chain(hand.frame))
            continue
        for k, joint in enumerate(hand.jaw.joints):
            if joint not in urdf.joints:
                raise RobotSpecError(f"{where}.jaw.joints[{k}]: the URDF has no joint {joint!r}")
        master = hand.jaw.joints[0]
        if not urdf.is_movable(urdf.joints[master]):
            raise RobotSpecError(f"{where}.jaw.joints[0]: {master!r} is not a movable joint of its own (fixed or mimic)")
        w0, w1 = hand.jaw.width_m
        if w0 != 0.0 or w1 <= 0.0 or hand.jaw.open == hand.jaw.closed:
            raise RobotSpecError(f"{where}.jaw.width_m: the jaw closes to width 0 and opens to a positive width, at "
                                 f"distinct joint values (got width_m {hand.jaw.width_m}, open {hand.jaw.open}, "
                                 f"closed {hand.jaw.closed})")
        lim = urdf.joints[master].find("limit")
        upper = float(lim.attrib.get("upper", "nan")) if lim is not None else float("nan")
        if not abs(upper - hand.jaw.open) <= 1e-9:
            raise RobotSpecError(f"{where}.jaw.open: the jaw opens at its joint's upper limit ({upper}), got "
                                 f"{hand.jaw.open}")
        grippers[side] = GripperSpec(joint=master, opening_per_unit=w1 / (hand.jaw.open - hand.jaw.closed),
                                     max_opening_m=w1, closed_value=hand.jaw.closed)
        arm_paths[side] = [j for j in urdf.chain(hand.frame) if j not in hand.jaw.joints]
    common = [a for a, b in zip(arm_paths["left"], arm_paths["right"]) if a == b]
    waist = [j for j in common if j not in leg_joints]
    arms = {side: ArmSpec(chain=p[len(common):], tcp=rf.hands[side].frame, gripper=grippers.get(side))
            for side, p in arm_paths.items()}
    for side, arm in arms.items():
        if len(arm.chain) < 6:
            raise RobotSpecError(f"hands.{side}.link: only {len(arm.chain)} arm joints lead to {rf.hands[side].link!r}; "
                                 "an arm needs at least 6")
    used = leg_joints | set(waist) | {j for a in arms.values() for j in a.chain} | {g.joint for g in grippers.values()}
    movable = [name for name, el in urdf.joints.items() if urdf.is_movable(el)]
    # a joint beyond an arm's end (a finger, a wrist camera) belongs to that hand; the rest is the neck
    beyond_hands = {j for side, hand in rf.hands.items() for j in urdf.subtree_joints(hand.link)}
    hand_joints = [j for j in movable if j not in used and j in beyond_hands]
    neck = [j for j in movable if j not in used and j not in beyond_hands]
    for fld, table in (("acceleration_limits", rf.acceleration_limits), ("effort_limits", rf.effort_limits),
                       ("default_posture_rad", rf.default_posture_rad)):
        for joint in table:
            if joint == "default" and fld == "acceleration_limits":
                continue
            if joint not in movable:
                raise RobotSpecError(f"{fld}.{joint}: the URDF has no movable joint {joint!r}")
    if "default" not in rf.acceleration_limits:
        missing = [j for j in movable if j not in rf.acceleration_limits]
        if missing:
            raise RobotSpecError(f"acceleration_limits: no limit for {', '.join(missing[:5])}; give `default` or each joint")
    limit_sources: dict[str, str] = {}
    jaws = {g.joint for g in grippers.values()}
    for joint in movable:
        if joint in jaws:
            continue
        if joint in rf.effort_limits:
            limit_sources[joint] = "spec effort_limits"
        elif urdf.effort(joint) is not None:
            limit_sources[joint] = "URDF <limit effort>"
        else:
            raise RobotSpecError(f"effort_limits.{joint}: the URDF's joint {joint!r} has no effort limit; give one")
    default_acc = rf.acceleration_limits.get("default")
    acceleration = {j: float(rf.acceleration_limits.get(j, default_acc)) for j in movable}
    srdf = _srdf_root(rf, path.parent) if rf.srdf is not None else None
    disabled = _disabled_collisions(rf, srdf, urdf, notes)
    posture = {**_srdf_posture(rf, srdf, movable, notes), **rf.default_posture_rad}
    spec = RobotSpec(
        name=rf.name, urdf="", description=rf.description, root_link=urdf.root_link, feet=feet, arms=arms, waist=waist,
        neck=neck, hand_joints=hand_joints, upright=UprightSpec(foot_y_m=rf.upright.foot_y_m, pelvis_height_m=rf.upright.pelvis_height_m),
        default_posture_rad=posture,
        acceleration_limits=acceleration,
        effort_limits=rf.effort_limits, grip=rf.grip, limit_sources=rf.limit_sources, license_notice=rf.license_notice,
        disabled_collisions=disabled, self_collision_matrix="srdf" if srdf is not None else "computed",
    )
    shapes = parse_collision(rf.collision, RobotSpecError)
    for link, link_shapes in (shapes or {}).items():
        el = urdf.link(link)
        if el is None:
            raise RobotSpecError(f"collision.{link}: the URDF has no link {link!r}")
        write_link_shapes(el, link_shapes)
        notes.append(f"collision: {len(link_shapes)} shape(s) of the spec on {link}")
    if not created and not moved and not sole_boxes_added and not shapes and not urdf.has_mesh_collisions():
        # nothing to derive: the URDF itself, so plans carry its own SHA-256 and nothing is written
        spec = spec.model_copy(update={"urdf": str(urdf_file)})
        return DerivedRobot(spec=spec, source=path, urdf=urdf_file, derived_urdf=urdf_file, created_frames=(),
                            limit_sources=limit_sources, notes=(*notes, "collision: the URDF's primitives"))
    digest = hashlib.sha256(f"derived/{DERIVATION_VERSION}/".encode() + path.read_bytes() + b"\0"
                            + urdf_file.read_bytes()).hexdigest()
    out_dir = cache_dir() / f"{rf.name}-{digest[:16]}"
    out_dir.mkdir(parents=True, exist_ok=True)
    derived = out_dir / f"{rf.name}.urdf"
    if derived.is_file():  # fitted once per spec and URDF content
        notes.append("collision: boxes fitted to the URDF's meshes (cached)")
        text = derived.read_text()
    else:
        fitted = fit_mesh_collisions(urdf, urdf_file.parent, path.parent, rf.packages, progress)
        notes.append(f"collision: {fitted} boxes fitted to the URDF's meshes" if fitted else
                     "collision: the URDF's primitives")
        text = ET.tostring(urdf.root, encoding="unicode")
    if not derived.is_file() or derived.read_text() != text:
        tmp = derived.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(text)
        tmp.replace(derived)
    spec = spec.model_copy(update={"urdf": str(derived)})
    return DerivedRobot(spec=spec, source=path, urdf=urdf_file, derived_urdf=derived, created_frames=tuple(created),
                        limit_sources=limit_sources, notes=tuple(notes))


def _srdf_root(rf: RobotFile, spec_dir: Path) -> tuple[Path, ET.Element]:
    """The spec's SRDF file and its parsed root (read once per derivation)."""
    srdf = _resolve(rf.srdf, spec_dir, rf.packages, "srdf")
    try:
        return srdf, ET.parse(srdf).getroot()
    except (OSError, ET.ParseError) as exc:
        raise RobotSpecError(f"srdf: cannot read {srdf}: {exc}") from None


def _srdf_posture(rf: RobotFile, srdf_file: tuple[Path, ET.Element] | None, movable: list[str],
                  notes: list[str]) -> dict[str, float]:
    """The joint values of the SRDF's ``<group_state>`` named by ``srdf_posture`` (movable joints of the URDF;
    a floating base's or another URDF variant's joints are left out)."""
    if rf.srdf_posture is None:
        return {}
    if srdf_file is None:
        raise RobotSpecError("srdf_posture: names a group_state of the SRDF; give `srdf`")
    srdf, root = srdf_file
    state = next((el for el in root.iter("group_state") if el.attrib.get("name") == rf.srdf_posture), None)
    if state is None:
        names = sorted({el.attrib.get("name", "") for el in root.iter("group_state")})
        raise RobotSpecError(f"srdf_posture: {srdf.name} has no group_state {rf.srdf_posture!r}"
                             + (f"; it has {', '.join(names)}" if names else ""))
    out: dict[str, float] = {}
    for el in state.iter("joint"):
        name, value = el.attrib.get("name"), el.attrib.get("value", "").split()
        if name in movable and len(value) == 1:
            out[name] = float(value[0])
    notes.append(f"srdf_posture: {len(out)} joint values of {rf.srdf_posture!r} start the default posture")
    return out


def _disabled_collisions(rf: RobotFile, srdf_file: tuple[Path, ET.Element] | None, urdf: _Urdf,
                         notes: list[str]) -> list[tuple[str, str]]:
    """The link pairs the spec says not to check for self-collision: the SRDF's ``<disable_collisions>``
    (MoveIt's collision matrix, computed on the robot's own meshes) and ``disable_collisions``, sorted."""
    pairs: set[tuple[str, str]] = set()
    if srdf_file is not None:
        srdf, root = srdf_file
        unknown = 0
        for el in root.iter("disable_collisions"):
            a, b = el.attrib.get("link1"), el.attrib.get("link2")
            if a is None or b is None:
                raise RobotSpecError(f"srdf: a <disable_collisions> of {srdf} lacks link1 or link2")
            if a in urdf.links and b in urdf.links:
                pairs.add((min(a, b), max(a, b)))
            else:
                unknown += 1
        notes.append(f"srdf: {len(pairs)} link pairs not checked for self-collision"
                     + (f" ({unknown} naming links the URDF lacks ignored)" if unknown else ""))
    for k, pair in enumerate(rf.disable_collisions):
        if len(pair) != 2:
            raise RobotSpecError(f"disable_collisions[{k}]: a pair of two link names, got {pair}")
        for link in pair:
            if link not in urdf.links:
                raise RobotSpecError(f"disable_collisions[{k}]: the URDF has no link {link!r}")
        pairs.add((min(pair), max(pair)))
    return sorted(pairs)


def fit_mesh_collisions(urdf: _Urdf, urdf_dir: Path, spec_dir: Path, packages: dict[str, str],
                        progress: Callable[[str], None] = lambda message: None) -> int:
    """Replace every mesh collision of the URDF by its oriented bounding box (trimesh); how many were fitted.

    The planner's fast collision screen works on primitives; a box per mesh keeps every link covered."""
    import trimesh

    count = 0
    meshes = len(urdf.root.findall("link/collision/geometry/mesh"))
    seen = 0
    for link in urdf.root.findall("link"):
        for col in link.findall("collision"):
            geo = col.find("geometry")
            mesh_el = geo.find("mesh") if geo is not None else None
            if mesh_el is None:
                continue
            ref = mesh_el.attrib.get("filename", "")
            seen += 1
            progress(f"fitting boxes to mesh {seen}/{meshes} ({link.attrib['name']})")
            where = f"collision: link {link.attrib['name']!r} mesh {ref!r}"
            try:
                mesh_path = _resolve(ref, urdf_dir, packages, where) if ref.startswith("package://") else \
                    _resolve(ref.removeprefix("file://"), urdf_dir, {}, where)
                unreadable = check_mesh_file(mesh_path)
                if unreadable:
                    raise RobotSpecError(f"{where}: cannot read the mesh: {unreadable}")
                mesh = trimesh.load(str(mesh_path), force="mesh")
            except RobotSpecError:
                raise
            except Exception as exc:  # a mesh trimesh cannot read
                raise RobotSpecError(f"{where}: cannot read the mesh: {exc}") from None
            scale = np.array([float(v) for v in mesh_el.attrib.get("scale", "1 1 1").split()])
            mesh.apply_scale(scale)
            origin = col.find("origin")
            xyz = np.array([float(v) for v in (origin.attrib.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
            rpy = [float(v) for v in (origin.attrib.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
            T_col = np.eye(4)
            T_col[:3, :3] = _rpy_matrix(rpy)
            T_col[:3, 3] = xyz
            link.remove(col)
            for T_box, extents in _fit_boxes(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces)):
                T = T_col @ T_box
                new = ET.SubElement(link, "collision")
                ET.SubElement(new, "origin", {"xyz": " ".join(repr(float(v)) for v in T[:3, 3]),
                                              "rpy": " ".join(repr(float(v)) for v in _matrix_rpy(T[:3, :3]))})
                ET.SubElement(ET.SubElement(new, "geometry"), "box", {"size": " ".join(repr(float(v)) for v in extents)})
                count += 1
    return count


#: a mesh whose bounding box is longer than this on some side is covered by one box per occupied octant
SPLIT_ABOVE_M = 0.15
#: Bump when the derived URDF's making changes (the mesh fit), so old cache folders are not reused.
DERIVATION_VERSION = 2


def _fit_boxes(vertices: np.ndarray, faces: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Boxes (pose (4, 4), extents (3,)) covering a mesh: its oriented bounding box, or, for a large mesh
    (a torso with its shoulder mounts), one box per octant of that box around the part of the surface in
    that octant (the triangles clipped to it), which follows the shape much more closely. Clipping the
    triangles, not only picking the vertices that fall in an octant, keeps every point of the surface
    inside a box: a triangle spanning octants is covered piece by piece."""
    import trimesh

    T, extents = trimesh.bounds.oriented_bounds(vertices)
    T = np.linalg.inv(T)  # oriented_bounds gives the transform to the box frame
    if extents.max() <= SPLIT_ABOVE_M or len(vertices) < 64 or faces is None or len(faces) == 0:
        return [(T, extents)]
    R, centre = T[:3, :3], T[:3, 3]
    out = []
    for cell in range(8):
        v, f = vertices, np.asarray(faces)
        for axis in range(3):
            sign = 1.0 if (cell >> axis) & 1 else -1.0
            v, f = trimesh.intersections.slice_faces_plane(v, f, sign * R[:, axis], centre)[:2]
            if len(f) == 0:
                break
        if len(f) == 0:
            continue
        out.append(_box_around(np.asarray(v)[np.unique(f)], R, centre))
    return out


def _box_around(points: np.ndarray, R: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The oriented bounding box of points, or, where they are too few or flat for one, their bounding box in
    the frame (R, centre)."""
    import trimesh

    try:
        Tc, ec = trimesh.bounds.oriented_bounds(points)
        if np.all(np.isfinite(ec)) and ec.min() > 1e-6:
            return np.linalg.inv(Tc), ec
    except Exception:  # noqa: BLE001 - qhull refuses flat or tiny point sets
        pass
    local = (points - centre) @ R
    lo, hi = local.min(axis=0), local.max(axis=0)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre + R @ ((lo + hi) / 2)
    return T, np.maximum(hi - lo, 1e-4)


def _rpy_matrix(rpy: list[float]) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _matrix_rpy(R: np.ndarray) -> tuple[float, float, float]:
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    if abs(np.cos(pitch)) > 1e-9:
        return float(np.arctan2(R[2, 1], R[2, 2])), pitch, float(np.arctan2(R[1, 0], R[0, 0]))
    return float(np.arctan2(-R[1, 2], R[1, 1])), pitch, 0.0
