"""Generate the project's own HRP-5P-like URDF from public figures.

No public URDF of HRP-5P exists, so the model is built here from the published
figures (AIST press release 2018-11-16; Kaneko et al., RA-L 2019; the authors'
public controller/research configurations), see ``NOTES.md`` beside the data.
Running this module rewrites ``data/hrp5p.urdf``; a test checks that the committed
file equals a fresh generation, so the two never drift apart.

Units: the tables below are written in the units of the public sources
(millimetres, degrees, kilograms) and converted to SI once, here, at the edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

import robot_data

DATA_DIR = robot_data.data_dir()
URDF_PATH = DATA_DIR / "hrp5p.urdf"

MM = 1e-3
DEG = math.pi / 180.0

#: Official total mass (AIST press release); the published link masses sum to
#: 85.3 kg, the rest is pelvis (~10 kg) and batteries/covers placed in the torso.
TOTAL_MASS_KG = 101.0
PELVIS_MASS_KG = 10.0

#: Conservative velocity limits (no public figures): rad/s (m/s for the jaw).
VEL_LEG = 0.5
VEL_UPPER = 1.0
VEL_JAW = 0.1
EFFORT = 300.0

#: Half of the 82 mm jaw opening: each finger travels 0..41 mm.
JAW_HALF_OPENING_M = 0.041
#: TCP distance from the hand-yaw joint (published: 187 mm to the fingertip centre).
TCP_OFFSET_M = 0.187
#: Sole rectangle around the ankle (right foot), x in [-100, 130], y in [-75, 55] mm.
SOLE_LENGTH_M = 0.230
SOLE_WIDTH_M = 0.130
SOLE_CENTRE_FROM_ANKLE_MM = (15.0, -10.0, -90.0)


@dataclass
class Geom:
    """A collision/visual primitive: box (size xyz), cylinder (radius, length) or sphere."""

    kind: str
    dims: tuple[float, ...]
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass
class Link:
    name: str
    mass: float = 0.0
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Box extents used for a plausible inertia m(b^2+c^2)/12 about the CoM.
    inertia_box: tuple[float, float, float] = (0.05, 0.05, 0.05)
    geoms: list[Geom] = field(default_factory=list)


@dataclass
class Joint:
    name: str
    kind: str  # revolute | prismatic | fixed
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    lower: float = 0.0
    upper: float = 0.0
    velocity: float = 0.0
    mimic: tuple[str, float, float] | None = None  # (master, multiplier, offset)


AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}

# --- Published tables (right side; mm, deg, kg) -------------------------------------
# (HRP name suffix, axis, lower deg, upper deg, vector from this joint to the next (mm), link mass kg)
LEG = [
    ("CY", "z", -45.0, 45.0, (0.0, 0.0, 0.0), 1.036),
    ("CR", "x", -45.0, 45.0, (0.0, 0.0, 0.0), 0.355),
    ("CP", "y", -125.0, 77.0, (0.0, -35.0, -380.0), 7.049),
    ("KP", "y", 0.0, 150.0, (0.0, 0.0, -380.0), 3.982),
    ("AP", "y", -85.0, 55.0, (0.0, 0.0, 0.0), 0.470),
    ("AR", "x", -45.0, 50.0, (0.0, 0.0, -90.0), 1.565),
]
ARM = [
    ("SC", "z", -20.0, 60.0, (0.0, -130.0, 0.0), 1.136),
    ("SP", "y", -200.0, 70.0, (0.0, 0.0, 0.0), 0.576),
    ("SR", "x", -95.0, 25.0, (0.0, -20.0, 0.0), 1.668),
    ("SY", "z", -92.0, 120.0, (50.0, 0.0, -295.8), 2.639),
    ("EP", "y", -180.0, -16.2, (-50.0, 0.0, -295.8), 1.133),
    ("WRY", "z", -122.0, 182.0, (0.0, 0.0, 0.0), 1.289),
    ("WRR", "x", -47.0, 70.0, (0.0, 0.0, 0.0), 0.047),
    ("WRP", "y", -42.0, 42.0, (0.0, 17.3, -78.8), 0.363),
    ("HDY", "x", -150.0, 150.0, (0.0, 0.0, -187.0), 1.140),
]
HIP_OFFSET_MM = (0.0, -60.0, 0.0)
SHOULDER_FROM_PELVIS_MM = (87.0, -80.0, 542.0)
#: Waist joints sit 100 mm above the pelvis origin (approximation: not published).
WAIST_FROM_PELVIS_MM = (0.0, 0.0, 100.0)
#: Waist and neck ranges are not published: conservative choices (deg).
WAIST = [("WP", "y", -10.0, 60.0), ("WR", "x", -30.0, 30.0), ("WY", "z", -60.0, 60.0)]
NECK = [("HY", "z", -70.0, 70.0), ("HP", "y", -30.0, 60.0)]
NECK_FROM_CHEST_MM = (0.0, 0.0, 500.0)
#: Chest chain: 36.38 kg published = torso 23.7 + head 3.5 + waist/neck links 9.18.
TORSO_MASS_KG = 23.7
TORSO_COM_MM = (-90.0, 0.0, 248.0)
HEAD_MASS_KG = 3.5
WAIST_LINK_MASS_KG = 4.09
NECK_LINK_MASS_KG = 1.0
FINGER_MASS_KG = 0.05  # taken out of the published 1.140 kg hand


def _v(mm: tuple[float, float, float]) -> tuple[float, float, float]:
    return (mm[0] * MM, mm[1] * MM, mm[2] * MM)


def _mirror(v: tuple[float, float, float]) -> tuple[float, float, float]:
    return (v[0], -v[1], v[2])


def _limits(axis: str, lo: float, hi: float, left: bool) -> tuple[float, float]:
    """Mirror a right-side range for the left side: roll (x) and yaw (z) flip sign."""
    if left and axis in ("x", "z"):
        lo, hi = -hi, -lo
    return lo * DEG, hi * DEG


def _mid(v: tuple[float, float, float]) -> tuple[float, float, float]:
    return (v[0] / 2, v[1] / 2, v[2] / 2)


def build_leg(side: str) -> tuple[list[Link], list[Joint]]:
    left = side == "L"
    sgn = _mirror if left else (lambda v: v)
    links: list[Link] = []
    joints: list[Joint] = []
    parent = "PELVIS"
    offset = sgn(_v(HIP_OFFSET_MM))
    names = {"CY": "HIP_Y", "CR": "HIP_R", "CP": "THIGH", "KP": "SHANK", "AP": "ANKLE_P", "AR": "FOOT"}
    for suffix, axis, lo, hi, vec_mm, mass in LEG:
        vec = sgn(_v(vec_mm))
        lo_r, hi_r = _limits(axis, lo, hi, left)
        child = f"{side}_{names[suffix]}_LINK"
        link = Link(child, mass=mass, com=_mid(vec))
        if suffix == "CP":
            link.inertia_box = (0.14, 0.14, 0.38)
            link.geoms.append(Geom("cylinder", (0.075, 0.26), _mid(vec)))
        elif suffix == "KP":
            link.inertia_box = (0.12, 0.12, 0.38)
            link.geoms.append(Geom("cylinder", (0.065, 0.26), _mid(vec)))
        elif suffix == "AR":
            sole = sgn(_v(SOLE_CENTRE_FROM_ANKLE_MM))
            link.com = (sole[0], sole[1], -0.06)
            link.inertia_box = (SOLE_LENGTH_M, SOLE_WIDTH_M, 0.08)
            # Foot body above the sole plate (the sole box itself lives on *_sole).
            link.geoms.append(Geom("box", (SOLE_LENGTH_M, SOLE_WIDTH_M, 0.05), (sole[0], sole[1], -0.045)))
        links.append(link)
        joints.append(
            Joint(f"{side}{suffix}", "revolute", parent, child, offset, axis=AXES[axis], lower=lo_r, upper=hi_r, velocity=VEL_LEG)
        )
        parent, offset = child, vec
    # Sole frame: centre of the sole rectangle, on the ground plane when the foot is flat.
    sole_name = f"{side.lower()}_sole"
    sole_xyz = sgn(_v(SOLE_CENTRE_FROM_ANKLE_MM))
    links.append(Link(sole_name, geoms=[Geom("box", (SOLE_LENGTH_M, SOLE_WIDTH_M, 0.02), (0.0, 0.0, 0.01))]))
    joints.append(Joint(f"{side}_SOLE_FIXED", "fixed", parent, sole_name, sole_xyz))
    return links, joints


def build_arm(side: str) -> tuple[list[Link], list[Joint]]:
    left = side == "L"
    sgn = _mirror if left else (lambda v: v)
    links: list[Link] = []
    joints: list[Joint] = []
    parent = "CHEST_LINK"
    # The shoulder chain starts at (87, -80, 542) mm from the pelvis; the chest frame
    # sits at the waist joints, 100 mm above the pelvis.
    sh = SHOULDER_FROM_PELVIS_MM
    offset = sgn(_v((sh[0], sh[1], sh[2] - WAIST_FROM_PELVIS_MM[2])))
    names = {
        "SC": "SCAPULA", "SP": "SHOULDER_P", "SR": "SHOULDER_R", "SY": "UPPER_ARM", "EP": "FOREARM",
        "WRY": "WRIST_Y", "WRR": "WRIST_R", "WRP": "WRIST_P", "HDY": "HAND",
    }
    for suffix, axis, lo, hi, vec_mm, mass in ARM:
        vec = sgn(_v(vec_mm))
        lo_r, hi_r = _limits(axis, lo, hi, left)
        child = f"{side}_{names[suffix]}_LINK"
        link = Link(child, mass=mass, com=_mid(vec))
        if suffix == "SR":
            link.geoms.append(Geom("sphere", (0.07,), (0.0, 0.0, 0.0)))
        elif suffix == "SY":
            link.inertia_box = (0.1, 0.1, 0.3)
            link.geoms.append(Geom("cylinder", (0.05, 0.20), (vec[0] / 2, 0.0, -0.15)))
        elif suffix == "EP":
            link.inertia_box = (0.09, 0.09, 0.3)
            # Forearm: elbow to just above the wrist (the wrist joints are compact; the palm starts below).
            link.geoms.append(Geom("cylinder", (0.045, 0.14), (vec[0] / 2, 0.0, -0.12)))
        elif suffix == "WRY":
            link.geoms.append(Geom("sphere", (0.05,), (0.0, 0.0, 0.0)))
        elif suffix == "HDY":
            hand_mass = mass - 2 * FINGER_MASS_KG
            link.mass = hand_mass
            link.com = (0.0, 0.0, -0.09)
            link.inertia_box = (0.08, 0.11, 0.12)
            # Palm: between 150 and 50 mm behind the TCP along the approach axis.
            link.geoms.append(Geom("box", (0.08, 0.12, 0.10), (0.0, 0.0, -(TCP_OFFSET_M - 0.10))))
        links.append(link)
        joints.append(
            Joint(f"{side}{suffix}", "revolute", parent, child, offset, axis=AXES[axis], lower=lo_r, upper=hi_r, velocity=VEL_UPPER)
        )
        parent, offset = child, vec
    hand = parent
    tcp_name = f"{side.lower()}_tcp"
    # TCP: z = approach (out of the palm, along -z of the hand), y = closing direction.
    tcp_xyz = (0.0, 0.0, -TCP_OFFSET_M)
    tcp_rpy = (math.pi, 0.0, 0.0)
    links.append(Link(tcp_name))
    joints.append(Joint(f"{side}_TCP_FIXED", "fixed", hand, tcp_name, tcp_xyz, rpy=tcp_rpy))
    # Parallel jaw: finger A slides +y (tcp frame) by q, finger B mirrors it (mimic, -1).
    for finger, sign in (("A", 1.0), ("B", -1.0)):
        fname = f"{side}_FINGER_{finger}_LINK"
        links.append(
            Link(
                fname,
                mass=FINGER_MASS_KG,
                com=(0.0, sign * 0.0075, -0.015),
                inertia_box=(0.02, 0.015, 0.07),
                geoms=[Geom("box", (0.02, 0.015, 0.07), (0.0, sign * 0.0075, -0.015))],
            )
        )
        master = f"{side}JAW"
        joints.append(
            Joint(
                master if finger == "A" else f"{side}JAW_MIMIC",
                "prismatic",
                hand,
                fname,
                tcp_xyz,
                rpy=tcp_rpy,
                axis=(0.0, sign, 0.0),
                lower=0.0,
                upper=JAW_HALF_OPENING_M,
                velocity=VEL_JAW,
                mimic=None if finger == "A" else (master, 1.0, 0.0),
            )
        )
    return links, joints


def build_trunk() -> tuple[list[Link], list[Joint]]:
    links: list[Link] = [
        Link(
            "PELVIS",
            mass=PELVIS_MASS_KG,
            com=(0.0, 0.0, 0.0),
            inertia_box=(0.22, 0.30, 0.15),
            geoms=[Geom("box", (0.22, 0.26, 0.14), (0.0, 0.0, 0.0))],
        )
    ]
    joints: list[Joint] = []
    parent, offset = "PELVIS", _v(WAIST_FROM_PELVIS_MM)
    waist_links = ["WAIST_P_LINK", "WAIST_R_LINK", "CHEST_LINK"]
    for (suffix, axis, lo, hi), child in zip(WAIST, waist_links):
        links.append(Link(child, mass=WAIST_LINK_MASS_KG, com=(0.0, 0.0, 0.0), inertia_box=(0.15, 0.2, 0.1)))
        joints.append(
            Joint(suffix, "revolute", parent, child, offset, axis=AXES[axis], lower=lo * DEG, upper=hi * DEG, velocity=VEL_UPPER)
        )
        parent, offset = child, (0.0, 0.0, 0.0)
    chest = links[-1]
    chest.com = _v(TORSO_COM_MM)
    chest.inertia_box = (0.30, 0.36, 0.50)
    chest.geoms.append(Geom("box", (0.30, 0.24, 0.44), (-0.04, 0.0, 0.26)))
    parent, offset = "CHEST_LINK", _v(NECK_FROM_CHEST_MM)
    for (suffix, axis, lo, hi), child in zip(NECK, ["NECK_Y_LINK", "HEAD_LINK"]):
        links.append(Link(child, mass=NECK_LINK_MASS_KG, inertia_box=(0.08, 0.08, 0.08)))
        joints.append(
            Joint(suffix, "revolute", parent, child, offset, axis=AXES[axis], lower=lo * DEG, upper=hi * DEG, velocity=VEL_UPPER)
        )
        parent, offset = child, (0.0, 0.0, 0.0)
    head = links[-1]
    head.mass = HEAD_MASS_KG
    head.com = (0.0, 0.0, 0.15)
    head.inertia_box = (0.22, 0.20, 0.30)
    # Head box top at 370 mm above the neck: 1.82 m with straight legs.
    head.geoms.append(Geom("box", (0.22, 0.20, 0.30), (0.0, 0.0, 0.22)))
    return links, joints


def build_model() -> tuple[list[Link], list[Joint]]:
    links, joints = build_trunk()
    for part in (build_leg("R"), build_leg("L"), build_arm("R"), build_arm("L")):
        links += part[0]
        joints += part[1]
    # Batteries and covers: the published link masses sum to ~85.3 kg; the balance
    # to the official 101 kg (after the pelvis) goes to the torso at its CoM.
    chest = next(link for link in links if link.name == "CHEST_LINK")
    chest.mass = TORSO_MASS_KG
    rest = sum(link.mass for link in links)
    chest.mass += TOTAL_MASS_KG - rest
    return links, joints


def _f(x: float) -> str:
    s = f"{x:.9g}"
    return "0" if s == "-0" else s


def _vec(v: tuple[float, ...]) -> str:
    return " ".join(_f(x) for x in v)


def _geom_xml(g: Geom) -> str:
    if g.kind == "box":
        shape = f'<box size="{_vec(g.dims)}"/>'
    elif g.kind == "cylinder":
        shape = f'<cylinder radius="{_f(g.dims[0])}" length="{_f(g.dims[1])}"/>'
    elif g.kind == "sphere":
        shape = f'<sphere radius="{_f(g.dims[0])}"/>'
    else:  # pragma: no cover - generator tables only use the three kinds
        raise ValueError(g.kind)
    return f'<origin xyz="{_vec(g.xyz)}" rpy="{_vec(g.rpy)}"/><geometry>{shape}</geometry>'


def _inertia(mass: float, box: tuple[float, float, float]) -> tuple[float, float, float]:
    a, b, c = box
    return (mass * (b * b + c * c) / 12.0, mass * (a * a + c * c) / 12.0, mass * (a * a + b * b) / 12.0)


def to_urdf(links: list[Link], joints: list[Joint]) -> str:
    out = ['<?xml version="1.0"?>', "<!-- Generated by planner/robots/hrp5p_urdf.py; do not edit by hand. -->", '<robot name="hrp5p">']
    for link in links:
        out.append(f"  <link name={quoteattr(link.name)}>")
        if link.mass > 0:
            ixx, iyy, izz = _inertia(link.mass, link.inertia_box)
            out.append(
                f'    <inertial><origin xyz="{_vec(link.com)}" rpy="0 0 0"/><mass value="{_f(link.mass)}"/>'
                f'<inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(iyy)}" iyz="0" izz="{_f(izz)}"/></inertial>'
            )
        for g in link.geoms:
            out.append(f"    <visual>{_geom_xml(g)}</visual>")
            out.append(f"    <collision>{_geom_xml(g)}</collision>")
        out.append("  </link>")
    for j in joints:
        out.append(f"  <joint name={quoteattr(j.name)} type={quoteattr(j.kind)}>")
        out.append(f"    <parent link={quoteattr(j.parent)}/><child link={quoteattr(j.child)}/>")
        out.append(f'    <origin xyz="{_vec(j.xyz)}" rpy="{_vec(j.rpy)}"/>')
        if j.kind != "fixed":
            out.append(f'    <axis xyz="{_vec(j.axis)}"/>')
            out.append(
                f'    <limit lower="{_f(j.lower)}" upper="{_f(j.upper)}" velocity="{_f(j.velocity)}" effort="{_f(EFFORT)}"/>'
            )
        if j.mimic:
            out.append(f'    <mimic joint="{j.mimic[0]}" multiplier="{_f(j.mimic[1])}" offset="{_f(j.mimic[2])}"/>')
        out.append("  </joint>")
    out.append("</robot>")
    return "\n".join(out) + "\n"


def generate() -> str:
    """The URDF text, deterministic (same input tables give byte-identical output)."""
    return to_urdf(*build_model())


def main() -> None:
    DATA_DIR.mkdir(parents=True, exist_ok=True)
    URDF_PATH.write_text(generate())
    print(URDF_PATH)


if __name__ == "__main__":
    main()
