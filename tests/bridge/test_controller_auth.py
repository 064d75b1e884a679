"""The controller's receipt deadline on its own clock: past, or further ahead than 10 s plus the clock skew, refused."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from robot_bridge.controller_auth import CommandAuth

NOW = 1_800_000_000.0


@settings(max_examples=200, deadline=None)
@given(ahead=st.floats(-30.0, 30.0, allow_nan=False))
def test_expires_at_is_accepted_only_within_the_window(ahead):
    auth = CommandAuth(None, clock_skew_s=0.5, max_expiry_ahead_s=10.0)
    problem = auth.expiry_problem({"expires_at": NOW + ahead}, NOW)
    if ahead < -0.5:
        assert problem is not None and problem.startswith("expired")
    elif ahead > 10.5:
        assert problem is not None and "too far ahead" in problem
    else:
        assert problem is None


def test_a_missing_or_non_finite_expiry_is_refused():
    auth = CommandAuth(None, clock_skew_s=0.5, max_expiry_ahead_s=10.0)
    for bad in (None, True, float("nan"), float("inf"), "1e9"):
        assert auth.expiry_problem({"expires_at": bad}, NOW) == "no expires_at"
