"""Shared field types of the wire contract: poses, finite vectors, names.

Every pose on the wire is ``[x, y, z, qx, qy, qz, qw]`` in metres with a unit
quaternion (docs/contract.md). Validation happens here once, so NaN, Inf and
non-unit quaternions are rejected with a message naming the field before any
planning starts.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict

#: Tolerance on the quaternion norm: poses typed by hand with 4-6 digits pass.
QUAT_NORM_TOL = 1e-3

HandConfig = Literal["left-left", "right-right", "left-right", "right-left"]
HandsChoice = Literal["auto", "left-left", "right-right", "left-right", "right-left"]
HAND_CONFIGS: tuple[HandConfig, ...] = ("left-left", "right-right", "left-right", "right-left")
Holding = Literal["none", "left", "right", "both"]


def _finite(values: list[float]) -> list[float]:
    for i, v in enumerate(values):
        if not math.isfinite(v):
            raise ValueError(f"element {i} is {v!r}; every value must be finite")
    return values


def _pose(values: list[float]) -> list[float]:
    if len(values) != 7:
        raise ValueError(f"a pose has 7 numbers [x, y, z, qx, qy, qz, qw], got {len(values)}")
    _finite(values)
    norm = math.sqrt(sum(v * v for v in values[3:]))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise ValueError(f"quaternion [qx, qy, qz, qw] has norm {norm:.6f}; it must be unit length")
    return [*values[:3], *(v / norm for v in values[3:])]


def _vec3(values: list[float]) -> list[float]:
    if len(values) != 3:
        raise ValueError(f"expected 3 numbers [x, y, z], got {len(values)}")
    return _finite(values)


def _vec2(values: list[float]) -> list[float]:
    if len(values) != 2:
        raise ValueError(f"expected 2 numbers [x, y], got {len(values)}")
    return _finite(values)


def _finite_scalar(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError(f"value is {v!r}; it must be finite")
    return v


Pose7 = Annotated[list[float], AfterValidator(_pose)]
Vec3 = Annotated[list[float], AfterValidator(_vec3)]
Vec2 = Annotated[list[float], AfterValidator(_vec2)]
FiniteVector = Annotated[list[float], AfterValidator(_finite)]
Finite = Annotated[float, AfterValidator(_finite_scalar)]

IDENTITY_QUAT = [0.0, 0.0, 0.0, 1.0]


class StrictModel(BaseModel):
    """Base of all wire models: unknown fields are errors (typos surface at once)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class OpenModel(BaseModel):
    """Base of wire models that tolerate extra fields (forward compatibility of outputs)."""

    model_config = ConfigDict(extra="allow", populate_by_name=True)
