"""The physics plant's payload check through a real dispatcher and controller-sim: the segments carry the plan's
object mass, the twin's wrist force/torque sensors read what the hand really holds, and a load far from the planned
one ends the job ``aborted`` with a ``payload_mismatch`` reason; the planned load is carried to the end."""

from __future__ import annotations

import pytest

from .plans import build_plan
from .test_fault_matrix import run

pytestmark = [pytest.mark.host_pauses(limit_s=0.2), pytest.mark.usefixtures("plant")]


@pytest.fixture(scope="module")
def plant() -> str:
    """The controllers of this module run the MuJoCo twin (at speed 1)."""
    return "physics"


@pytest.fixture(scope="module")
def holding_plan() -> dict:
    """1.6 s with a 2 kg object in the right hand from the first point (the weight comes on as playback starts)."""
    return build_plan({"RSP": -0.3}, duration_s=1.5, holding="right", mass_kg=2.0)


@pytest.mark.parametrize("flags,outcome", [((), "succeeded"), (("--object-mass-kg", "12"), "aborted")],
                         ids=["the planned 2 kg", "12 kg in the hand"])
def test_a_held_load_unlike_the_planned_one_faults_the_controller(bridge, holding_plan, flags, outcome):
    ctl, disp, spy = bridge(*flags, speed=1.0)
    res, rec = run(disp, holding_plan)
    assert res.status == outcome, res.reason
    sent = [s for s in spy.trajectory]
    assert sent and all(s["object_mass_kg"] == 2.0 for s in sent)  # the plan's mass reached the controller
    if outcome == "aborted":
        assert "torque_saturation: payload_mismatch" in res.reason, res.reason
        assert "the planned 2.00 kg object weighs 19.6 N" in res.reason, res.reason
