"""Derive the project's JVRC-1 URDF from the ``jvrc_description`` package.

JVRC-1 serves as a second model, a cross-check that nothing downstream is specific
to our HRP-5P-like model. The package ships a URDF with Collada meshes only and
none of the contract's frames, so this module writes a derived URDF
(``data/jvrc1.urdf``) that:

- adds ``l_sole``/``r_sole`` (fixed children of the ankle-pitch links, at the centre
  of the sole rectangle on the ground plane, z up, one collision box each) with the
  rectangle measured from the flat contact faces of the foot meshes;
- adds ``l_tcp``/``r_tcp`` between the thumb and the two fingers, z out of the palm
  (along the fingers), y along the line on which the fingers close;
- replaces every mesh (collision and visual) by a box fitted to the mesh bounds in
  the link frame, so pinocchio and fcl load it with no mesh files;
- gives each hand one jaw joint, ``L_JAW``/``R_JAW`` (prismatic, value = jaw opening
  in metres, 0 = closed), that drives the six finger joints as mimics. The package's
  master joint (``*_UTHUMB``) is at its most open at 0 and closes away from it, which a
  linear "opening = k * value" gripper cannot express; the virtual jaw joint maps
  opening to finger angles through each mimic's multiplier and offset, exact at
  both ends of its range.

Masses, inertias, joint origins, axes and limits are kept as the package has them.
Running this module rewrites ``data/jvrc1.urdf`` and ``data/JVRC1_LICENSE``; a test
checks that the committed files equal a fresh derivation. Loading Collada needs
``pycollada`` (trimesh's reader).
"""

from __future__ import annotations

import importlib.metadata
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

import robot_data
from planner.errors import DerivationError
from planner.transforms import rpy_to_matrix

DATA_DIR = robot_data.data_dir()
URDF_PATH = DATA_DIR / "jvrc1.urdf"
LICENSE_PATH = DATA_DIR / "JVRC1_LICENSE"
PACKAGE = "jvrc_description"

#: Fitted primitives are snapped outward to this grid (0.1 mm): the output then does
#: not depend on the last bits of the mesh reader's floating-point arithmetic.
GRID_M = 1e-4
#: Thickness of the sole collision box, which lies on the ground plane (as for hrp5p).
SOLE_BOX_THICKNESS_M = 0.02
#: A mesh face belongs to the sole when its normal points down within ~8 deg ...
SOLE_NORMAL_Z_MAX = -0.99
#: ... and it lies within 0.1 mm of the lowest point of the foot.
SOLE_FLAT_TOL_M = 1e-4
#: Rounding of the derived gripper figures (angles in rad, lengths in m).
HAND_DECIMALS = 6
EFFORT_JAW = 100.0

SIDE_PREFIX = {"left": "L", "right": "R"}
FOOT_LINK = "{s}_ANKLE_P_S"
WRIST_LINK = "{s}_WRIST_Y_S"
THUMB = ("{s}_UTHUMB", "{s}_LTHUMB")
FINGERS = (("{s}_UINDEX", "{s}_LINDEX"), ("{s}_ULITTLE", "{s}_LLITTLE"))


# ----------------------------------------------------------------------------- package access


def package_paths() -> tuple[Path, Path, str]:
    """(URDF, meshes folder, version) of the installed ``jvrc_description``."""
    try:
        import jvrc_description
    except ImportError as exc:  # pragma: no cover - installed with the project
        raise DerivationError("the jvrc_description package is not installed: pip install jvrc_description") from exc
    return Path(jvrc_description.urdf_path), Path(jvrc_description.meshes_path), jvrc_description.__version__


def _mesh_file(filename: str, meshes: Path) -> Path:
    """Resolve ``package://jvrc_description/meshes/X.dae`` to the installed file."""
    name = filename.rsplit("/", 1)[-1]
    path = meshes / name
    if not path.is_file():
        raise DerivationError(f"mesh {filename!r} not found at {path}")
    return path


def _origin(elem: ET.Element | None) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) of an URDF ``<origin>`` (identity when absent)."""
    if elem is None:
        return np.eye(3), np.zeros(3)
    xyz = np.array([float(v) for v in elem.attrib.get("xyz", "0 0 0").split()])
    rpy = [float(v) for v in elem.attrib.get("rpy", "0 0 0").split()]
    return rpy_to_matrix(*rpy), xyz


@lru_cache(maxsize=64)
def _load_vertices_faces(path: Path) -> tuple[np.ndarray, np.ndarray]:
    try:
        import collada  # noqa: F401  (trimesh's Collada reader needs it)
    except ImportError as exc:
        raise DerivationError("reading the JVRC-1 Collada meshes needs pycollada: pip install pycollada") from exc
    import trimesh

    mesh = trimesh.load(str(path), force="mesh")
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=int)


@dataclass(frozen=True)
class LinkMesh:
    """A link's collision mesh expressed in the link frame."""

    vertices: np.ndarray
    faces: np.ndarray

    @property
    def lower(self) -> np.ndarray:
        return self.vertices.min(axis=0)

    @property
    def upper(self) -> np.ndarray:
        return self.vertices.max(axis=0)


def link_mesh(link: ET.Element, meshes: Path) -> LinkMesh | None:
    """The mesh of a link's first collision element, moved by its ``<origin>`` into the link frame."""
    col = link.find("collision")
    if col is None:
        return None
    mesh = col.find("geometry/mesh")
    if mesh is None:
        return None
    v, f = _load_vertices_faces(_mesh_file(mesh.attrib["filename"], meshes))
    scale = np.array([float(s) for s in mesh.attrib.get("scale", "1 1 1").split()])
    R, p = _origin(col.find("origin"))
    return LinkMesh((v * scale) @ R.T + p, f)


# ----------------------------------------------------------------------------- geometry


def _snap_out(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds moved outward to the grid, so the box always contains the mesh."""
    return np.floor(lower / GRID_M - 1e-6) * GRID_M, np.ceil(upper / GRID_M + 1e-6) * GRID_M


def _snap(x: np.ndarray | float) -> np.ndarray:
    return np.round(np.asarray(x, dtype=float) / GRID_M) * GRID_M


@dataclass(frozen=True)
class Box:
    centre: np.ndarray
    size: np.ndarray


def fit_box(mesh: LinkMesh, z_min: float | None = None) -> Box:
    """Axis-aligned box (link frame) around the mesh, optionally cut from below at ``z_min``."""
    lo, hi = _snap_out(mesh.lower, mesh.upper)
    if z_min is not None:
        lo[2] = max(lo[2], z_min)
    return Box((lo + hi) / 2.0, hi - lo)


@dataclass(frozen=True)
class SoleRect:
    """The sole rectangle in the foot link frame: centre on the contact plane, x/y sizes."""

    centre: np.ndarray
    length: float
    width: float


def sole_rectangle(foot: LinkMesh) -> SoleRect:
    """Bounding rectangle of the foot's flat, downward-facing contact faces.

    The JVRC-1 sole has a heel pad and a toe pad on one plane (the arch between
    them is 6 mm higher), and its toe edge is slanted: the inner toe reaches 32 mm
    further forward than the outer one. The rectangle spans both pads and the
    longer toe; docs/jvrc1.md says what this approximates.
    """
    tri = foot.vertices[foot.faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    ok = lengths > 0
    nz = np.full(len(tri), 1.0)
    nz[ok] = normals[ok, 2] / lengths[ok]
    z0 = foot.vertices[:, 2].min()
    flat = (nz < SOLE_NORMAL_Z_MAX) & (tri[:, :, 2].max(axis=1) < z0 + SOLE_FLAT_TOL_M)
    if not flat.any():
        raise DerivationError("the foot mesh has no flat downward face at its lowest point")
    pts = tri[flat].reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = _snap(np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, z0]))
    length, width = _snap(hi[0] - lo[0]), _snap(hi[1] - lo[1])
    return SoleRect(centre, float(length), float(width))


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


@dataclass(frozen=True)
class _Finger:
    """Upper phalanx of a finger hinged on the wrist link, and the inner-face point at its knuckle."""

    joint: str
    origin: np.ndarray
    axis: np.ndarray
    knuckle: np.ndarray  # inner-face point at the distal end, in the phalanx frame
    mult: float  # package mimic relation to the master joint
    offset: float

    def point(self, master_angle: float) -> np.ndarray:
        """Knuckle point in the wrist frame with the package's master joint at ``master_angle``."""
        return self.origin + _axis_rotation(self.axis, self.mult * master_angle + self.offset) @ self.knuckle


@dataclass(frozen=True)
class HandGrip:
    """The derived gripper of one hand (all in the wrist-yaw link frame)."""

    side: str
    master: str
    open_angle: float  # package master angle with the hand open (fingers straight)
    closed_angle: float  # master angle at which thumb and fingers meet (zero opening)
    max_opening_m: float
    tcp_xyz: np.ndarray
    #: finger joint -> (multiplier, offset) relative to the package's master joint
    relations: dict[str, tuple[float, float]]

    @property
    def rad_per_m(self) -> float:
        """Master angle change per metre of jaw opening (linear between the two ends)."""
        return (self.open_angle - self.closed_angle) / self.max_opening_m


def _joints_by_name(root: ET.Element) -> dict[str, ET.Element]:
    return {j.attrib["name"]: j for j in root.iter("joint")}


def _mimic_relation(joint: ET.Element, master: str) -> tuple[float, float]:
    if joint.attrib["name"] == master:
        return 1.0, 0.0
    m = joint.find("mimic")
    if m is None or m.attrib["joint"] != master:
        raise DerivationError(f"finger joint {joint.attrib['name']} does not mimic {master}")
    return float(m.attrib.get("multiplier", 1.0)), float(m.attrib.get("offset", 0.0))


def hand_grip(root: ET.Element, side: str, meshes: Path) -> HandGrip:
    """Measure the hand: the opening between the thumb and the two fingers, and the TCP.

    The opening is the gap, along the wrist's y axis, between the thumb's inner face
    and the fingers' inner faces at the knuckle (end of the upper phalanx). It is
    largest with the fingers straight and reaches zero where the thumb and the
    fingers (which interleave in x) pass each other.
    """
    from scipy.optimize import brentq

    s = SIDE_PREFIX[side]
    joints = _joints_by_name(root)
    links = {link.attrib["name"]: link for link in root.iter("link")}
    master = THUMB[0].format(s=s)
    wrist = WRIST_LINK.format(s=s)

    def finger(upper: str, lower: str, toward_plus_y: bool) -> _Finger:
        ju, jl = joints[upper.format(s=s)], joints[lower.format(s=s)]
        if ju.find("parent").attrib["link"] != wrist:
            raise DerivationError(f"{ju.attrib['name']} is not hinged on {wrist}")
        mesh = link_mesh(links[ju.find("child").attrib["link"]], meshes)
        if mesh is None:
            raise DerivationError(f"finger {ju.attrib['name']} has no mesh")
        _, knuckle = _origin(jl.find("origin"))
        face_y = mesh.upper[1] if toward_plus_y else mesh.lower[1]
        mult, off = _mimic_relation(ju, master)
        return _Finger(
            ju.attrib["name"], _origin(ju.find("origin"))[1],
            np.array([float(v) for v in ju.find("axis").attrib["xyz"].split()]),
            np.array([knuckle[0], face_y, knuckle[2]]), mult, off,
        )

    thumb_y = _origin(joints[master].find("origin"))[1][1]
    finger_y = _origin(joints[FINGERS[0][0].format(s=s)].find("origin"))[1][1]
    sign = 1.0 if thumb_y > finger_y else -1.0  # thumb on the +y side of the fingers?
    thumb = finger(*THUMB, toward_plus_y=sign < 0)
    others = [finger(u, lo, toward_plus_y=sign > 0) for u, lo in FINGERS]

    def gap(angle: float) -> float:
        t = thumb.point(angle)[1]
        return min(sign * (t - f.point(angle)[1]) for f in others)

    limit = joints[master].find("limit")
    lo, hi = float(limit.attrib["lower"]), float(limit.attrib["upper"])
    open_angle, far = (lo, hi) if gap(lo) > gap(hi) else (hi, lo)
    if gap(open_angle) <= 0 or gap(far) >= 0:
        raise DerivationError(f"{side} hand: thumb and fingers do not close over the range of {master}")
    closed = round(brentq(gap, open_angle, far, xtol=1e-12), HAND_DECIMALS)
    max_open = round(gap(open_angle), HAND_DECIMALS)
    t_open = thumb.point(open_angle)
    f_open = np.mean([f.point(open_angle) for f in others], axis=0)
    relations: dict[str, tuple[float, float]] = {}
    for names in (THUMB, *FINGERS):
        for name in names:
            n = name.format(s=s)
            relations[n] = _mimic_relation(joints[n], master)
    return HandGrip(
        side=side, master=master, open_angle=open_angle, closed_angle=closed, max_opening_m=max_open,
        tcp_xyz=_snap((t_open + f_open) / 2.0), relations=relations,
    )


# ----------------------------------------------------------------------------- license


def license_text() -> str:
    """The notices the package ships, verbatim: URDF header, module header, metadata."""
    urdf, _, version = package_paths()
    header = re.findall(r"<!--(.*?)-->", urdf.read_text(encoding="utf-8").split("<robot", 1)[0], flags=re.S)
    copyrights = [line.strip() for block in header for line in block.splitlines() if "Copyright" in line]
    import jvrc_description

    init_lines = []
    for line in Path(jvrc_description.__file__).read_text(encoding="utf-8").splitlines():
        if line.startswith("#!") or "coding" in line:
            continue
        if not line.startswith("#"):
            break
        init_lines.append(line[2:] if line.startswith("# ") else line[1:])
    meta = importlib.metadata.metadata(PACKAGE)
    classifiers = [c for c in meta.get_all("Classifier") or [] if c.startswith("License")]
    urls = dict(u.split(", ", 1) for u in meta.get_all("Project-URL") or [] if ", " in u)
    while init_lines and not init_lines[0].strip():
        init_lines.pop(0)
    out = [
        f"The JVRC-1 model in jvrc1.urdf is derived from the {PACKAGE} package, version {version}",
        f"(PyPI; source {urls.get('Source', 'named in the package metadata')}).",
        "The package ships no separate license file. Its notices, kept here as shipped:",
        "",
        "In urdf/jvrc1.urdf (model, meshes):",
        *(f"  {c}" for c in copyrights),
        "",
        "In jvrc_description/__init__.py:",
        *(f"  {line}".rstrip() for line in init_lines),
        "",
        "In the package metadata (METADATA):",
        *(f"  Classifier: {c}" for c in classifiers),
        "",
        "Changes made by planner/robot/jvrc1_urdf.py: sole and TCP frames added, mesh geometry",
        "replaced by fitted boxes, a jaw joint per hand driving the finger joints as mimics.",
    ]
    return "\n".join(out) + "\n"


# ----------------------------------------------------------------------------- derivation


def _f(x: float) -> str:
    """Short, stable decimal form (no ``-0.0``)."""
    return repr(round(float(x), 10) + 0.0)


def _vec(v) -> str:
    return " ".join(_f(x) for x in v)


def _box_geometry(parent: ET.Element, tag: str, box: Box, material: ET.Element | None = None) -> None:
    elem = ET.SubElement(parent, tag)
    ET.SubElement(elem, "origin", {"xyz": _vec(box.centre), "rpy": "0 0 0"})
    geom = ET.SubElement(elem, "geometry")
    ET.SubElement(geom, "box", {"size": _vec(box.size)})
    if material is not None:
        elem.append(material)


def _replace_meshes(link: ET.Element, box: Box) -> None:
    material = None
    for vis in link.findall("visual"):
        material = material if material is not None else vis.find("material")
        link.remove(vis)
    for col in link.findall("collision"):
        link.remove(col)
    _box_geometry(link, "visual", box, material)
    _box_geometry(link, "collision", box)


def _fixed_joint(root: ET.Element, name: str, parent: str, child: str, xyz, rpy=(0.0, 0.0, 0.0)) -> None:
    j = ET.SubElement(root, "joint", {"name": name, "type": "fixed"})
    ET.SubElement(j, "origin", {"xyz": _vec(xyz), "rpy": _vec(rpy)})
    ET.SubElement(j, "parent", {"link": parent})
    ET.SubElement(j, "child", {"link": child})


#: TCP orientation in the wrist link: z_tcp = -z_wrist (along the fingers, out of the
#: palm), y_tcp = -y_wrist (the line of closing), x_tcp = x_wrist; as for hrp5p.
TCP_RPY = (math.pi, 0.0, 0.0)


def derive() -> tuple[str, str, dict[str, HandGrip], dict[str, SoleRect]]:
    """(URDF text, license text, grips by side, soles by side), deterministic."""
    urdf, meshes, version = package_paths()
    root = ET.parse(urdf).getroot()
    if root.tag != "robot":
        raise DerivationError(f"{urdf} is not a URDF robot")
    for joint in root.iter("joint"):
        if joint.attrib["type"] not in ("revolute", "prismatic", "fixed"):
            raise DerivationError(f"joint {joint.attrib['name']} has type {joint.attrib['type']}; extend the derivation")
    links = {link.attrib["name"]: link for link in root.iter("link")}
    soles = {side: sole_rectangle(link_mesh(links[FOOT_LINK.format(s=s)], meshes)) for side, s in SIDE_PREFIX.items()}
    grips = {side: hand_grip(root, side, meshes) for side in SIDE_PREFIX}

    # (b, e) Mesh geometry -> fitted boxes; the feet stop where the sole box begins.
    foot_links = {FOOT_LINK.format(s=s): side for side, s in SIDE_PREFIX.items()}
    for name, link in links.items():
        mesh = link_mesh(link, meshes)
        if mesh is None:
            continue
        z_min = None
        if name in foot_links:
            z_min = soles[foot_links[name]].centre[2] + SOLE_BOX_THICKNESS_M
        _replace_meshes(link, fit_box(mesh, z_min))

    joints = _joints_by_name(root)
    for side, s in SIDE_PREFIX.items():
        lower = s.lower()
        # (a) Sole frame and box.
        sole = soles[side]
        frame = f"{lower}_sole"
        link = ET.SubElement(root, "link", {"name": frame})
        box = Box(np.array([0.0, 0.0, SOLE_BOX_THICKNESS_M / 2]), np.array([sole.length, sole.width, SOLE_BOX_THICKNESS_M]))
        _box_geometry(link, "visual", box)
        _box_geometry(link, "collision", box)
        _fixed_joint(root, f"{frame}_joint", FOOT_LINK.format(s=s), frame, sole.centre)
        # (a) TCP frame.
        grip = grips[side]
        wrist = WRIST_LINK.format(s=s)
        ET.SubElement(root, "link", {"name": f"{lower}_tcp"})
        _fixed_joint(root, f"{lower}_tcp_joint", wrist, f"{lower}_tcp", grip.tcp_xyz, TCP_RPY)
        # (c, d) Jaw joint: value = opening (m); the six finger joints follow it.
        jaw, jaw_link = f"{s}_JAW", f"{s}_JAW_S"
        ET.SubElement(root, "link", {"name": jaw_link})
        j = ET.SubElement(root, "joint", {"name": jaw, "type": "prismatic"})
        ET.SubElement(j, "origin", {"xyz": _vec(grip.tcp_xyz), "rpy": _vec(TCP_RPY)})
        ET.SubElement(j, "axis", {"xyz": "0 1 0"})
        ET.SubElement(j, "parent", {"link": wrist})
        ET.SubElement(j, "child", {"link": jaw_link})
        k, b = grip.rad_per_m, grip.closed_angle
        velocity = math.inf
        for name, (mult, off) in grip.relations.items():
            fj = joints[name]
            v = float(fj.find("limit").attrib["velocity"])
            velocity = min(velocity, v / abs(mult * k))
            for old in fj.findall("mimic"):
                fj.remove(old)
            ET.SubElement(fj, "mimic", {"joint": jaw, "multiplier": _f(round(mult * k, HAND_DECIMALS)),
                                        "offset": _f(round(mult * b + off, HAND_DECIMALS))})
        ET.SubElement(j, "limit", {"effort": _f(EFFORT_JAW), "lower": "0", "upper": _f(grip.max_opening_m),
                                   "velocity": _f(round(velocity, 4))})

    ET.indent(root, "  ")
    body = ET.tostring(root, encoding="unicode")
    lic = license_text()
    notice = "\n".join(f"  {line}".rstrip() for line in lic.splitlines())
    header = (
        '<?xml version="1.0" encoding="utf-8"?>\n'
        f"<!-- Generated by planner/robot/jvrc1_urdf.py from {PACKAGE} {version}; do not edit, regenerate:\n"
        "     python -m planner.robot.jvrc1_urdf -->\n"
        f"<!--\n{notice.replace('--', '- -')}\n-->\n"
    )
    return header + body + "\n", lic, grips, soles


def main() -> None:
    text, lic, grips, soles = derive()
    DATA_DIR.mkdir(parents=True, exist_ok=True)
    URDF_PATH.write_text(text, encoding="utf-8")
    LICENSE_PATH.write_text(lic, encoding="utf-8")
    for side, g in grips.items():
        print(f"{side} hand: opening 0..{g.max_opening_m * 1000:.1f} mm, {g.master} closed at {g.closed_angle:.4f} rad, "
              f"TCP {g.tcp_xyz.round(4).tolist()}")
    for side, s in soles.items():
        print(f"{side} sole: {s.length * 1000:.1f} x {s.width * 1000:.1f} mm at {s.centre.round(4).tolist()}")
    print(URDF_PATH)


if __name__ == "__main__":
    main()
