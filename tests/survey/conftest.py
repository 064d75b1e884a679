"""The survey tests' answers are cached in a folder of their own (planner/survey_cache.py)."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _survey_cache(tmp_path_factory):
    before = os.environ.get("REGRASP_SURVEY_CACHE_DIR")
    os.environ["REGRASP_SURVEY_CACHE_DIR"] = str(tmp_path_factory.mktemp("survey-cache"))
    yield
    if before is None:
        os.environ.pop("REGRASP_SURVEY_CACHE_DIR", None)
    else:
        os.environ["REGRASP_SURVEY_CACHE_DIR"] = before
