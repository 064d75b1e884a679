"""Fixtures of the geometry tests: objects, grasp sets and a scenario world, built once."""

from __future__ import annotations

import numpy as np
import pytest

from schemas.scenario import ObjectDef


@pytest.fixture(scope="session")
def grasp_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("grasp-cache")


@pytest.fixture(scope="session")
def box_obj():
    from planner.scene.objects import build_object

    return build_object(ObjectDef(name="box", shape="box", size=[0.06, 0.10, 0.20], mass_kg=1.0))


@pytest.fixture(scope="session")
def drill_obj():
    from planner.scene.objects import build_object

    return build_object(ObjectDef(name="drill", shape="drill", mass_kg=1.3))


@pytest.fixture(scope="session")
def box_grasps(hrp5p, box_obj, grasp_cache):
    from planner.grasping.grasps import plan_grasps

    return plan_grasps(box_obj, hrp5p, "right", cache_directory=grasp_cache)


@pytest.fixture(scope="session")
def drill_grasps(hrp5p, drill_obj, grasp_cache):
    from planner.grasping.grasps import plan_grasps

    return {side: plan_grasps(drill_obj, hrp5p, side, cache_directory=grasp_cache) for side in ("right", "left")}


@pytest.fixture(scope="session")
def table_box():
    from planner.scene.bodies import EnvBox
    from planner.transforms import make_transform

    return EnvBox("table", make_transform(p=[0.60, 0.0, 0.73]), (0.50, 1.40, 0.04))


@pytest.fixture(scope="session")
def upright_world(hrp5p, stances, table_box, drill_obj):
    from planner.scene.collision import CollisionWorld

    st = stances["upright"]
    return CollisionWorld(hrp5p, [table_box], drill_obj, reference_postures=[(st.base_pose, st.q)])


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)
