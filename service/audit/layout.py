"""The Foxglove layout shipped with the package and attached to every audit file.

One 3D panel (the planned robot from /robot_description and /plan/tf, the robot as
it reported itself under the ``executed/`` frames, the support polygon, the tables,
CoM, ZMP and object markers), two plots (CoM margin against the threshold; ZMP
margin and effort ratio) and the log. Foxglove imports it from the file's
attachment (``regrasp-foxglove-layout.json``) or from the package
(``regrasp audit layout`` prints it).
"""

from __future__ import annotations

import hashlib
from importlib import resources

#: Name of the attachment in every audit file.
LAYOUT_ATTACHMENT = "regrasp-foxglove-layout.json"
LAYOUT_MEDIA_TYPE = "application/json"


def layout_bytes() -> bytes:
    """The layout as shipped (UTF-8 JSON)."""
    return resources.files("service.audit").joinpath("foxglove_layout.json").read_bytes()


def layout_sha256() -> str:
    return hashlib.sha256(layout_bytes()).hexdigest()
