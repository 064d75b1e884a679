"""Why a task's dual-arm configurations find a key path or not: the handover poses' heights and
the handover node validations by cause (the giver at the pose, the taker's approach, ...).

A diagnosis of the planner's own search, so it lives beside the search and reads its results;
the paper report calls :func:`handover_diagnosis` and never reaches into the task.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from planner.regrasp.graph import HandoverNode
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.search_data import SearchData
from planner.regrasp.task import Task
from planner.survey.runner import key_path, key_pose_termination
from planner.termination import never
from schemas.scenario import Scenario

#: The configurations that hand the object over.
DUAL_ARM = ("left-right", "right-left")


def handover_diagnosis(scenario: Scenario) -> dict[str, Any]:
    """Per dual-arm configuration "key path found" or the reason there is none; the handover poses' CoM
    heights; handover node validations by cause; key postures replaced by stable ones (asked, found)."""
    task = Task(scenario)
    data = SearchData(task)  # shared by both configurations, as in a plan
    out: dict[str, Any] = {"object_mass_kg": scenario.object.mass_kg, "pelvis_height_m": float(task.stance.base_pose[2]),
                           "handover_com_heights_m": sorted({round(float(h.T_world_obj[2, 3]
                                                                         + (h.T_world_obj[:3, :3] @ task.obj.com_local)[2]), 3)
                                                             for h in data.handover_poses(task)})}
    for hands in DUAL_ARM:
        path, reason = key_path(HandConfigPlanner(task, hands, key_pose_termination(task, never), data=data))
        out[hands] = "key path found" if path is not None else reason
    causes = Counter(f"{v.cause or 'valid'}: {v.detail}" if v.detail else (v.cause or "valid")
                     for k, v in data.node_cache.items() if isinstance(k, HandoverNode))
    out["handover_validations"] = dict(causes.most_common())
    out["stable_postures"] = {"asked": int(data.counters["stable_postures"]),
                              "found": int(data.counters["stable_postures_found"])}
    return out
