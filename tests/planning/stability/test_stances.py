"""Stances: computed by leg IK, soles flat on the ground, CoM placed for one leg."""

from __future__ import annotations

import numpy as np
import pytest

from planner.robot.model import UnknownNameError, frame_poses
from planner.stability.robot_com import robot_com as center_of_mass
from planner.stability.stances import StanceError, load_stance_file, solve_stance
from schemas.stance import StanceDef


@pytest.mark.parametrize("name", ["upright", "staggered", "crouched", "one-legged"])
def test_soles_on_the_ground_and_level_within_1mm(hrp5p, stances, name):
    st = stances[name]
    data = hrp5p.create_data()
    for foot in st.feet:
        (M,) = frame_poses(hrp5p, data, st.base_pose, st.q, [foot.frame])
        assert np.abs(M.translation - np.array(foot.pose[:3])).max() < 1e-3
        # Level: the sole's corners differ in height by < 1 mm.
        assert abs(M.rotation[2, 0]) * 0.115 < 1e-3 and abs(M.rotation[2, 1]) * 0.065 < 1e-3
    assert np.all(st.q >= hrp5p.lower - 1e-12) and np.all(st.q <= hrp5p.upper + 1e-12)


def test_builtin_placements_follow_the_contract(stances):
    def pos(name, frame):
        return next(f.pose[:3] for f in stances[name].feet if f.frame == frame)

    assert pos("upright", "r_sole") == pytest.approx([0, -0.095, 0])
    assert pos("staggered", "r_sole") == pytest.approx([0.05, -0.095, 0])
    assert pos("staggered", "l_sole") == pytest.approx([-0.20, 0.095, 0])
    assert stances["crouched"].base_pose[2] == pytest.approx(stances["upright"].base_pose[2] - 0.15)
    left = next(f for f in stances["one-legged"].feet if f.frame == "l_sole")
    assert not left.in_contact and left.pose[2] == pytest.approx(0.05)


def test_crouched_bends_the_knees_more(hrp5p, stances):
    k = hrp5p.joint_index("RKP")
    assert stances["crouched"].q[k] > stances["upright"].q[k] + 0.3


def test_one_legged_com_above_the_right_sole(hrp5p, stances):
    st = stances["one-legged"]
    com = center_of_mass(hrp5p, hrp5p.create_data(), st.base_pose, st.q)
    assert com[:2] == pytest.approx([0.0, -0.095], abs=2e-4)


def test_unreachable_foot_says_which_and_by_how_much(hrp5p):
    sdef = StanceDef(name="split", feet=[
        {"frame": "r_sole", "pose": [0.6, -0.095, 0, 0, 0, 0, 1]},
        {"frame": "l_sole", "pose": [0, 0.095, 0, 0, 0, 0, 1]},
    ])
    with pytest.raises(StanceError, match=r"foot r_sole cannot reach its placement; it stays \d+\.\d mm short"):
        solve_stance(hrp5p, sdef)


def test_unknown_stance_and_frame_list_valid_names(hrp5p):
    with pytest.raises(UnknownNameError, match="built-in stances: upright, staggered, crouched, one-legged"):
        solve_stance(hrp5p, "kneeling")
    sdef = StanceDef(name="x", feet=[{"frame": "r_foot", "pose": [0, -0.095, 0, 0, 0, 0, 1]}])
    with pytest.raises(UnknownNameError, match="valid sole frames: l_sole, r_sole"):
        solve_stance(hrp5p, sdef)


def test_user_stance_from_yaml(hrp5p, tmp_path):
    path = tmp_path / "wide.yaml"
    path.write_text(
        "name: wide\nfeet:\n"
        "  - {frame: r_sole, pose: [0, -0.15, 0, 0, 0, 0, 1]}\n"
        "  - {frame: l_sole, pose: [0, 0.15, 0, 0, 0, 0, 1]}\n"
        "pelvis_height_m: 0.78\n"
    )
    st = solve_stance(hrp5p, load_stance_file(path))
    assert st.polygon.vertices[:, 1].max() == pytest.approx(0.215)


@pytest.mark.parametrize(
    "pose,field_msg",
    [
        ([0, 0, float("nan"), 0, 0, 0, 1], "finite"),
        ([float("inf"), 0, 0, 0, 0, 0, 1], "finite"),
        ([0, 0, 0, 0, 0, 0, 2], "unit length"),
        ([0, 0, 0, 0, 0, 1], "7 numbers"),
    ],
)
def test_bad_poses_are_rejected_naming_the_field(pose, field_msg):
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=field_msg) as info:
        StanceDef(name="bad", feet=[{"frame": "r_sole", "pose": pose}])
    assert info.value.errors()[0]["loc"][:3] == ("feet", 0, "pose")
