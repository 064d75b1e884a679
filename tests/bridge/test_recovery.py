"""The recover job's planner (``planner/recovery.py``) judged by the independent safety gate.

From a measured posture the plan goes back to the stance posture, starts exactly at the measured
state and ends at rest in the stance posture; its margin never falls below the threshold where it
starts above it, and never below its start where it starts below it: the gate, told the plan is a
recovery, recomputes that from the URDF and passes it, and vetoes the same plan as an ordinary one.
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.jobs.recovery import RecoverySettings, plan_recovery
from robot_bridge.gate import SafetyGate

from .plans import stance_state, true_min_margin


@pytest.fixture(scope="module")
def gate() -> SafetyGate:
    return SafetyGate()


def _posture(**deltas: float) -> tuple[list[str], np.ndarray, np.ndarray]:
    names, q, _ = stance_state()
    q0 = np.array(q)
    q1 = q0.copy()
    for joint, d in deltas.items():
        q1[names.index(joint)] += d
    return names, q0, q1


def _check_ends(plan: dict, names: list[str], start: np.ndarray, stance_q: np.ndarray) -> None:
    order = [names.index(n) for n in plan["robot"]["joint_names"]]
    Q = np.array([p["q"] for p in plan["trajectory"]])
    assert np.array_equal(Q[0], start[order])
    assert np.allclose(Q[-1], stance_q[order], atol=1e-9)
    assert np.array_equal(Q[0], Q[1]) and np.array_equal(Q[-1], Q[-2])  # from rest to rest


def test_from_mid_motion_the_recovery_keeps_the_threshold(gate):
    names, q0, q1 = _posture(RSP=-0.4, LSP=-0.3, REP=-0.5)
    plan = plan_recovery("hrp5p", "upright", names, q1.tolist(), settings=RecoverySettings(threshold_m=0.06))
    assert plan["status"] == "solved", plan["failure"]
    _check_ends(plan, names, q1, q0)
    assert true_min_margin(plan) >= 0.06 - 1e-4
    verdict = gate.check(plan, offline=True, recovery=True)
    assert verdict.passed, verdict.summary()


def test_from_below_the_threshold_the_recovery_never_lowers_the_margin(gate):
    names, q0, q1 = _posture(WP=0.6)  # leaning forward: below the 60 mm threshold
    plan = plan_recovery("hrp5p", "upright", names, q1.tolist(), settings=RecoverySettings(threshold_m=0.06))
    assert plan["status"] == "solved", plan["failure"]
    start = plan["stats"]["recovery"]["start_margin_m"]
    assert start < 0.06 and plan["stats"]["recovery"]["floor_m"] == start
    _check_ends(plan, names, q1, q0)
    assert true_min_margin(plan) >= start - 1e-4
    assert plan["trajectory"][-1]["margin_m"] > 0.06
    assert gate.check(plan, offline=True, recovery=True).passed
    ordinary = gate.check(plan, offline=True)
    assert not ordinary.passed and ordinary.check == "com_margin" and ordinary.sample_index == 0


def test_the_gate_holds_a_recovery_to_its_floor(gate):
    """A recover job's plan whose margin falls below where it started is vetoed: here one that starts below its
    threshold (0.2 m) and leans forward, lowering the margin further."""
    from .plans import build_plan

    plan = build_plan({"WP": 0.3}, duration_s=1.5, threshold_m=0.2)
    start = plan["trajectory"][0]["margin_m"]
    assert start < 0.2 and true_min_margin(plan) < start - 1e-3
    verdict = gate.check(plan, offline=True, recovery=True)
    assert not verdict.passed and verdict.check == "com_margin" and verdict.sample_index > 0, verdict.summary()
    assert verdict.stats["com_margin"]["recovery_floor_m"] == pytest.approx(start, abs=1e-9)


@pytest.mark.parametrize("case, code", [("names", "BAD_STATE"), ("limits", "BAD_STATE"), ("holding", "HOLDING_UNKNOWN_OBJECT")])
def test_unrecoverable_states_are_infeasible_with_their_reason(case, code):
    names, q0, q1 = _posture(RSP=-0.2)
    kwargs = {}
    if case == "names":
        names = names[:-1] + ["NOT_A_JOINT"]
    elif case == "limits":
        q1[names.index("RSP")] = 100.0
    else:
        kwargs["holding"] = "right"
    plan = plan_recovery("hrp5p", "upright", names, q1.tolist(), **kwargs)
    assert plan["status"] == "infeasible" and plan["failure"]["code"] == code, plan["failure"]


def test_a_held_object_counts_in_the_recovery_and_stays_held(gate):
    """Holding a 3 kg object in the right hand (its pose as the aborted plan had it): the recovery moves it with
    the hand, keeps the jaws as they are, and the gate (which recomputes the system CoM with the object) passes it."""
    from .plans import build_plan

    aborted = build_plan({"RSP": -0.4, "RJAW": -0.02}, duration_s=1.0, holding="right", mass_kg=3.0)
    at = len(aborted["trajectory"]) - 1
    names = aborted["robot"]["joint_names"]
    q1 = aborted["trajectory"][at]["q"]
    obj = {"mass_kg": 3.0, "com_local": aborted["object"]["com_local"], "pose": aborted["trajectory"][at]["object_pose"]}
    plan = plan_recovery("hrp5p", "upright", names, q1, holding="right", obj=obj)
    assert plan["status"] == "solved", plan["failure"]
    assert {p["holding"] for p in plan["trajectory"]} == {"right"}
    jaw = names.index("RJAW")
    assert q1[jaw] == pytest.approx(0.021) and {p["q"][jaw] for p in plan["trajectory"]} == {q1[jaw]}  # the jaw stays closed
    assert plan["object"]["mass_kg"] == 3.0
    assert np.allclose(plan["trajectory"][0]["object_pose"][:3], obj["pose"][:3], atol=1e-9)
    assert not np.allclose(plan["trajectory"][-1]["object_pose"][:3], obj["pose"][:3], atol=1e-3)  # it moved along
    verdict = gate.check(plan, offline=True, recovery=True)
    assert verdict.passed, verdict.summary()
