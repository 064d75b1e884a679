"""Shared fixtures: the robot models are loaded once per test session."""

from __future__ import annotations

import os

import pytest

# Keep caches (grasps, etc.) inside the test run, never in the user's home.
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def hrp5p():
    from planner.robot_model import load_robot

    return load_robot("hrp5p")


@pytest.fixture(scope="session")
def stances(hrp5p):
    from planner.stances import BUILTIN_STANCES, solve_stance

    return {name: solve_stance(hrp5p, name) for name in BUILTIN_STANCES}
