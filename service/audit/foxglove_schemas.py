"""JSON Schemas for the Foxglove message types the audit file uses.

Foxglove recognises a channel by its schema *name* (``foxglove.Log``,
``foxglove.SceneUpdate`` ...) with ``jsonschema`` encoding; the schema text itself
only feeds its message-path completion. The texts are built here from a few
small pieces so each type reads like the Foxglove schema reference
(https://docs.foxglove.dev/docs/sdk/schemas) without carrying a copy of it.

Every audit message also has an ``audit`` object (sequence number and the
previous record's SHA-256, see :mod:`service.audit.chain`); Foxglove ignores
fields it does not know, so the chain rides along in each message.
"""

from __future__ import annotations

import json
from typing import Any

JSON = dict[str, Any]

#: Schema names Foxglove recognises for JSON-encoded channels.
LOG = "foxglove.Log"
SCENE_UPDATE = "foxglove.SceneUpdate"
FRAME_TRANSFORMS = "foxglove.FrameTransforms"
JOINT_STATES = "foxglove.JointStates"
#: The URDF layer of Foxglove's 3D panel reads the ``data`` string of any
#: message on the ``/robot_description`` topic (a ROS ``std_msgs/String``).
ROBOT_DESCRIPTION = "std_msgs/String"
#: The project's own event record (state changes, requests, plans, verdicts...).
AUDIT_EVENT = "regrasp.audit.Event"
#: One playback sample of a plan's stability figures (Foxglove's Plot panel reads its fields).
PLAN_SAMPLE = "regrasp.plan.Sample"
#: One balance sample the physics plant reported during execution (state/balance, docs/contract.md section 6).
ROBOT_BALANCE = "regrasp.robot.Balance"


def _obj(properties: JSON, title: str | None = None, description: str | None = None) -> JSON:
    doc: JSON = {"type": "object", "properties": properties}
    if title:
        doc["title"] = title
    if description:
        doc["description"] = description
    return doc


def _num(description: str) -> JSON:
    return {"type": "number", "description": description}


def _arr(items: JSON, description: str) -> JSON:
    return {"type": "array", "items": items, "description": description}


TIME = _obj(
    {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
    title="time",
)
DURATION = _obj(
    {"sec": {"type": "integer"}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
    title="duration",
)
VECTOR3 = _obj({"x": _num("x (m)"), "y": _num("y (m)"), "z": _num("z (m)")}, title="foxglove.Vector3")
POINT3 = _obj({"x": _num("x (m)"), "y": _num("y (m)"), "z": _num("z (m)")}, title="foxglove.Point3")
QUATERNION = _obj({"x": _num("x"), "y": _num("y"), "z": _num("z"), "w": _num("w")}, title="foxglove.Quaternion")
POSE = _obj({"position": VECTOR3, "orientation": QUATERNION}, title="foxglove.Pose")
COLOR = _obj({c: _num(f"{c} in [0, 1]") for c in "rgba"}, title="foxglove.Color")

AUDIT_FIELD = _obj(
    {
        "seq": {"type": "integer", "minimum": 0, "description": "record index in the chain"},
        "prev": {"type": "string", "description": "SHA-256 (hex) of the previous record"},
    },
    title="regrasp.audit.Link",
    description="Hash-chain link: every record names the SHA-256 of the one before it",
)

_LINE = _obj(
    {
        "type": {"type": "integer", "description": "0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST"},
        "pose": POSE,
        "thickness": _num("line width"),
        "scale_invariant": {"type": "boolean"},
        "points": _arr(POINT3, "vertices"),
        "color": COLOR,
        "colors": _arr(COLOR, "per-vertex colours"),
        "indices": _arr({"type": "integer"}, "vertex indices"),
    },
    title="foxglove.LinePrimitive",
)
_SPHERE = _obj({"pose": POSE, "size": VECTOR3, "color": COLOR}, title="foxglove.SpherePrimitive")
_TEXT = _obj(
    {
        "pose": POSE,
        "billboard": {"type": "boolean"},
        "font_size": _num("font size"),
        "scale_invariant": {"type": "boolean"},
        "color": COLOR,
        "text": {"type": "string"},
    },
    title="foxglove.TextPrimitive",
)
_ENTITY = _obj(
    {
        "timestamp": TIME,
        "frame_id": {"type": "string"},
        "id": {"type": "string"},
        "lifetime": DURATION,
        "frame_locked": {"type": "boolean"},
        "metadata": _arr(_obj({"key": {"type": "string"}, "value": {"type": "string"}}), "key/value pairs"),
        "arrows": _arr({"type": "object"}, "arrow primitives"),
        "cubes": _arr({"type": "object"}, "cube primitives"),
        "spheres": _arr(_SPHERE, "sphere primitives"),
        "cylinders": _arr({"type": "object"}, "cylinder primitives"),
        "lines": _arr(_LINE, "line primitives"),
        "triangles": _arr({"type": "object"}, "triangle primitives"),
        "texts": _arr(_TEXT, "text primitives"),
        "models": _arr({"type": "object"}, "model primitives"),
    },
    title="foxglove.SceneEntity",
)

SCHEMAS: dict[str, JSON] = {
    LOG: _obj(
        {
            "timestamp": TIME,
            "level": {"type": "integer", "description": "0 UNKNOWN, 1 DEBUG, 2 INFO, 3 WARNING, 4 ERROR, 5 FATAL"},
            "message": {"type": "string"},
            "name": {"type": "string", "description": "process or component name"},
            "file": {"type": "string"},
            "line": {"type": "integer", "minimum": 0},
            "audit": AUDIT_FIELD,
        },
        title=LOG,
        description="A log message",
    ),
    SCENE_UPDATE: _obj(
        {
            "deletions": _arr(
                _obj({"timestamp": TIME, "type": {"type": "integer"}, "id": {"type": "string"}}),
                "entities to delete",
            ),
            "entities": _arr(_ENTITY, "entities to add or replace"),
            "audit": AUDIT_FIELD,
        },
        title=SCENE_UPDATE,
        description="An update to the entities displayed in a 3D scene",
    ),
    FRAME_TRANSFORMS: _obj(
        {
            "transforms": _arr(
                _obj(
                    {
                        "timestamp": TIME,
                        "parent_frame_id": {"type": "string"},
                        "child_frame_id": {"type": "string"},
                        "translation": VECTOR3,
                        "rotation": QUATERNION,
                    },
                    title="foxglove.FrameTransform",
                ),
                "transforms",
            ),
            "audit": AUDIT_FIELD,
        },
        title=FRAME_TRANSFORMS,
        description="A list of frame transforms",
    ),
    JOINT_STATES: _obj(
        {
            "timestamp": TIME,
            "joints": _arr(
                _obj(
                    {
                        "name": {"type": "string"},
                        "position": _num("rad (revolute) or m (prismatic)"),
                        "velocity": _num("rad/s or m/s"),
                    },
                    title="foxglove.JointState",
                ),
                "joint states",
            ),
            "audit": AUDIT_FIELD,
        },
        title=JOINT_STATES,
        description="The state of a set of joints at one instant",
    ),
    ROBOT_DESCRIPTION: _obj(
        {"data": {"type": "string", "description": "URDF XML"}, "audit": AUDIT_FIELD},
        title=ROBOT_DESCRIPTION,
        description="The robot's URDF, for Foxglove's 3D panel",
    ),
    AUDIT_EVENT: _obj(
        {
            "timestamp": TIME,
            "job_id": {"type": "string"},
            "kind": {"type": "string", "description": "what happened, e.g. state, request, plan, approval, gate"},
            "payload": {"type": "object"},
            "audit": AUDIT_FIELD,
        },
        title=AUDIT_EVENT,
        description="One audited event of a job",
    ),
    PLAN_SAMPLE: _obj(
        {
            "timestamp": TIME,
            "index": {"type": "integer", "minimum": 0, "description": "index of the plan point"},
            "t": _num("time from the plan's start (s)"),
            "margin_m": _num("CoM margin to the support polygon's edge, inside positive (m)"),
            "threshold_m": _num("the plan's margin threshold (m)"),
            "zmp_margin_m": _num("ZMP distance to the support polygon's edge, inside positive (m)"),
            "effort_ratio": _num("max over joints of |static torque| / effort limit"),
            "holding": {"type": "string", "description": "none | left | right | both"},
            "segment": {"type": "string", "description": "kind/hand of the segment the point is in"},
            "audit": AUDIT_FIELD,
        },
        title=PLAN_SAMPLE,
        description="A plan's stability figures at one playback sample",
    ),
    ROBOT_BALANCE: _obj(
        {
            "timestamp": TIME,
            "cop_x": _num("centre of pressure, x (m, world)"),
            "cop_y": _num("centre of pressure, y (m, world)"),
            "cop_margin_m": _num("CoP distance to the support polygon's edge, inside positive (m)"),
            "force_left_n": _num("left sole's normal force (N)"),
            "force_right_n": _num("right sole's normal force (N)"),
            "base_tilt_rad": _num("the base's tilt from upright (rad)"),
            "min_cop_margin_m": _num("smallest CoP margin so far (m)"),
            "audit": AUDIT_FIELD,
        },
        title=ROBOT_BALANCE,
        description="The robot's balance as the controller's physics plant measured it",
    ),
}


def schema_bytes(name: str) -> bytes:
    """The schema text of ``name`` as MCAP stores it (UTF-8 JSON)."""
    return json.dumps(SCHEMAS[name], sort_keys=True).encode("utf-8")
