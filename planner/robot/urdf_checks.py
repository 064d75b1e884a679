"""Checks of a robot's URDF that the planner's figures rest on: masses, inertias and mesh files.

A NaN, negative or infinite mass, or an inertia that is not positive definite on a link with mass,
makes every CoM and torque the planner computes meaningless, so a spec whose URDF has one is refused
naming the link. A massless link (a frame, a sensor mount) is fine: it adds nothing; so is a point mass (all
six inertia values zero) and a singular inertia (a rod's: one principal moment zero, to rounding). A mesh file is
checked before it is loaded: a binary STL whose header claims more triangles than the file holds
(2^31 of them, say) would have the mesh reader allocate that much.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Callable

import numpy as np

#: inertia values all this small (kg*m^2) are a point mass's zero inertia, written with rounding
POINT_MASS_INERTIA = 1e-12
#: a principal moment this small against the largest (relative) is a singular inertia's zero, rounded
SINGULAR_TOLERANCE = 1e-9
#: bytes of a binary STL's header (80) plus its triangle count (4), and of one triangle record
_STL_HEADER = 84
_STL_TRIANGLE = 50


def _number(text: str | None) -> float:
    try:
        return float(text) if text is not None else math.nan
    except ValueError:
        return math.nan


def check_inertials(root: ET.Element, error: Callable[[str], Exception]) -> tuple[int, int]:
    """Raise ``error(message)`` naming the first link whose mass is not finite and >= 0, or whose inertia is not
    finite and, where the link has mass, positive definite (or all zero: a point mass, as a sensor frame's few
    grams often are); the numbers of massless links and of point masses (both are fine)."""
    massless = point_masses = 0
    for link in root.iter("link"):
        name = link.attrib.get("name", "?")
        inertial = link.find("inertial")
        if inertial is None:
            massless += 1
            continue
        mass_el = inertial.find("mass")
        mass = _number(mass_el.attrib.get("value") if mass_el is not None else "0")
        if not math.isfinite(mass) or mass < 0.0:
            raise error(f"urdf: link {name!r} has mass {mass_el.attrib.get('value')!r}; a mass must be finite and "
                        ">= 0 (kg)")
        el = inertial.find("inertia")
        keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        values = {k: _number(el.attrib.get(k, "0")) if el is not None else 0.0 for k in keys}
        bad = [k for k, v in values.items() if not math.isfinite(v)]
        if bad:
            raise error(f"urdf: link {name!r} has inertia {bad[0]}={el.attrib.get(bad[0])!r}; inertias must be finite")
        if mass == 0.0:
            massless += 1
            continue
        if max(abs(v) for v in values.values()) <= POINT_MASS_INERTIA:
            point_masses += 1  # a point mass (a sensor's): physical, its inertia zero (to rounding: 1e-20 below it)
            continue
        inertia = np.array([[values["ixx"], values["ixy"], values["ixz"]],
                            [values["ixy"], values["iyy"], values["iyz"]],
                            [values["ixz"], values["iyz"], values["izz"]]])
        eig = np.linalg.eigvalsh(inertia)
        smallest = float(eig[0])
        # a rod's or a disc's inertia has a zero principal moment; written out it may round a hair below zero
        if not smallest > -(SINGULAR_TOLERANCE * float(eig[-1]) + 1e-12) or not eig[-1] > 0.0:
            raise error(f"urdf: link {name!r} has mass {mass:g} kg but its inertia is not positive definite "
                        f"(smallest eigenvalue {smallest:.3g} kg*m^2); give its inertia, or mass 0 for a frame")
    return massless, point_masses


def check_mesh_file(path: Path) -> str | None:
    """Why a mesh file cannot be read as its kind says, or None: an empty file, or a binary STL whose size is not
    its header's triangle count (checked before loading, so a bogus count allocates nothing)."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        return f"cannot read it: {exc.strerror or exc}"
    if size == 0:
        return "the file is empty"
    if path.suffix.lower() != ".stl":
        return None
    with path.open("rb") as fh:
        head = fh.read(_STL_HEADER)
    if head[:5].lower() == b"solid" and b"\0" not in head:
        return None  # an ASCII STL: the reader parses it as text
    if size < _STL_HEADER:
        return f"a binary STL of {size} bytes is shorter than its {_STL_HEADER}-byte header"
    count = int.from_bytes(head[80:84], "little")
    expected = _STL_HEADER + _STL_TRIANGLE * count
    if expected != size:
        return (f"its binary STL header claims {count} triangles ({expected} bytes) but the file has {size} bytes")
    return None
