"""`regrasp plan`'s summary table counts regrasps and handovers from the plan's segments."""

from __future__ import annotations

from .summary import summary_cells


def _plan(kinds: list[str]) -> dict:
    return {"status": "solved", "hands": "left-right", "threshold_m": 0.06, "min_margin_m": 0.07,
            "segments": [{"kind": k} for k in kinds], "trajectory": [{"t": 0.0}, {"t": 5.0}],
            "stats": {"cost": 1.0, "time_s": 1.0, "failures": {}}}


PICK = ["transit", "approach", "approach", "transfer"]
PLACE = ["transfer", "retreat", "retreat", "transit"]
HANDOVER = ["transit", "approach", "handover", "handover", "retreat", "transit"]


def test_direct_pick_and_place_has_no_regrasp():
    c = summary_cells(_plan(PICK + PLACE))
    assert (c["regrasps"], c["handovers"]) == ("0", "0")


def test_a_handover_is_not_counted_as_a_regrasp():
    c = summary_cells(_plan(PICK + HANDOVER + PLACE))
    assert (c["regrasps"], c["handovers"]) == ("0", "1")


def test_a_place_and_re_pick_before_a_handover_is_one_regrasp():
    c = summary_cells(_plan(PICK + PLACE + PICK + HANDOVER + PLACE))
    assert (c["regrasps"], c["handovers"]) == ("1", "1")
