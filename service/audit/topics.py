"""Topic names, record kinds and frame prefixes of an audit file (docs/audit.md lists them).

The plan's own playback lives under ``/plan/``; what the robot reported during
execution lives under ``/robot/``; the chain's events, the log and the robot model
are at the top level.
"""

from __future__ import annotations

NS_PER_S = 1_000_000_000

TOPIC_EVENTS = "/audit/events"
TOPIC_LOG = "/log"
TOPIC_ROBOT_DESCRIPTION = "/robot_description"
#: Transforms given explicitly with :meth:`AuditWriter.transforms` (neither plan nor robot).
TOPIC_TF = "/tf"

TOPIC_PLAN_JOINTS = "/plan/joint_states"
TOPIC_PLAN_TF = "/plan/tf"
TOPIC_PLAN_COM = "/plan/markers/com"
TOPIC_PLAN_ZMP = "/plan/markers/zmp"
TOPIC_PLAN_OBJECT = "/plan/markers/object"
TOPIC_PLAN_SUPPORT = "/plan/markers/support"
#: Written once per plan: the tables and the planned CoM and ZMP ground paths.
TOPIC_PLAN_SCENE = "/plan/markers/scene"
#: One sample per playback step for Foxglove's Plot panel (margin, ZMP margin, effort).
TOPIC_PLAN_STABILITY = "/plan/stability"

#: The plan's playback again, on the execution's timeline (published at dispatch as the controller plays it),
#: so that the planned and the measured robot overlap in time.
TOPIC_EXECUTED_PLAN_JOINTS = "/executed_plan/joint_states"
TOPIC_EXECUTED_PLAN_TF = "/executed_plan/tf"
TOPIC_EXECUTED_PLAN_COM = "/executed_plan/markers/com"
TOPIC_EXECUTED_PLAN_ZMP = "/executed_plan/markers/zmp"
TOPIC_EXECUTED_PLAN_OBJECT = "/executed_plan/markers/object"
TOPIC_EXECUTED_PLAN_SUPPORT = "/executed_plan/markers/support"
TOPIC_EXECUTED_PLAN_SCENE = "/executed_plan/markers/scene"
TOPIC_EXECUTED_PLAN_STABILITY = "/executed_plan/stability"

TOPIC_ROBOT_JOINTS = "/robot/joint_states"
TOPIC_ROBOT_TF = "/robot/tf"
#: The physics plant's balance stream during execution (CoP, its margin, foot forces, base tilt).
TOPIC_ROBOT_BALANCE = "/robot/balance"
#: The measured centre of pressure as a floor marker, over the support polygon in the 3D panel.
TOPIC_ROBOT_COP = "/robot/markers/cop"

# Older names of the same topics, kept for importers.
TOPIC_JOINTS_PLAN = TOPIC_PLAN_JOINTS
TOPIC_JOINTS_EXECUTED = TOPIC_ROBOT_JOINTS
TOPIC_COM = TOPIC_PLAN_COM
TOPIC_SUPPORT = TOPIC_PLAN_SUPPORT

#: Frame prefix of the robot's reported motion in /robot/tf (the plan's frames have none,
#: so the model of /robot_description follows the plan by default).
EXECUTED_PREFIX = "executed/"

KIND_OPEN = "audit.open"
KIND_CLOSE = "audit.close"
#: First record after the records carried over from the file a restart cut short.
KIND_CONTINUED = "continued"

#: foxglove.Log levels.
LOG_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
