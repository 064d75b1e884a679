"""The stability core: equation 1, the support polygon and the signed margin."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.stability.com import object_com_world, system_com
from planner.stability.support_polygon import (
    DegeneratePolygonError,
    SupportPolygon,
    convex_hull_ccw,
    support_polygon,
)

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def test_point_mass_shifts_the_com_by_m_d_over_M_plus_m(hrp5p, stances):
    st_ = stances["upright"]
    M, m = hrp5p.total_mass, 8.0
    robot_com = st_.robot_com
    d = np.array([0.45, 0.0, 0.0])
    combined = system_com(robot_com, M, robot_com + d, m)
    assert combined - robot_com == pytest.approx(m * d / (M + m), abs=1e-12)
    # The reference figure: 10 kg held 0.45 m forward shifts the system CoM by ~41 mm.
    assert np.linalg.norm(system_com(robot_com, M, robot_com + d, 10.0) - robot_com) == pytest.approx(0.0407, abs=5e-4)


def test_object_com_follows_the_object_pose():
    poses = np.repeat(np.eye(4)[None], 2, axis=0)
    poses[0, :3, 3] = [1.0, 0.0, 0.1]
    poses[1, :3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # 90 degrees about z
    poses[1, :3, 3] = [0.0, 2.0, 0.1]
    com = object_com_world(poses, np.array([0.0, 0.05, 0.0]))
    assert com == pytest.approx(np.array([[1.0, 0.05, 0.1], [-0.05, 2.0, 0.1]]))
    assert object_com_world(poses[1], np.array([0.0, 0.05, 0.0])) == pytest.approx(com[1])


@pytest.mark.parametrize(
    "point,expected",
    [((0.5, 0.5), 0.5), ((0.1, 0.5), 0.1), ((1.0, 0.3), 0.0), ((1.5, 0.5), -0.5), ((2.0, 2.0), -np.sqrt(2)), ((0.5, -0.25), -0.25)],
)
def test_margin_geometric_cases(point, expected):
    poly = SupportPolygon(SQUARE)
    assert poly.margin(np.array([point]))[0] == pytest.approx(expected)
    assert poly.margin_one(*point) == pytest.approx(expected)


def test_one_foot_polygon_is_the_sole(stances):
    poly = stances["one-legged"].polygon
    assert len(poly.vertices) == 4
    assert poly.inradius == pytest.approx(0.065, abs=1e-6)


def test_two_feet_hull_and_inradius(stances):
    poly = stances["upright"].polygon
    assert poly.vertices[:, 1].min() == pytest.approx(-0.16)
    assert poly.vertices[:, 1].max() == pytest.approx(0.16)
    assert poly.inradius == pytest.approx(0.115, abs=1e-6)


def test_degenerate_polygons_are_rejected():
    with pytest.raises(DegeneratePolygonError):
        SupportPolygon(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]))
    with pytest.raises(DegeneratePolygonError):
        SupportPolygon(np.array([[0.0, 0.0], [1.0, 1.0]]))
    with pytest.raises(DegeneratePolygonError, match="no foot"):
        support_polygon([(np.eye(3), np.zeros(3), 0.2, 0.1, False)])


def test_hull_drops_interior_and_collinear_points():
    pts = np.array([[0, 0], [1, 0], [0.5, 0], [1, 1], [0, 1], [0.5, 0.5]], dtype=float)
    hull = convex_hull_ccw(pts)
    assert len(hull) == 4
    area = 0.5 * np.sum(hull[:, 0] * np.roll(hull[:, 1], -1) - np.roll(hull[:, 0], -1) * hull[:, 1])
    assert area == pytest.approx(1.0)


coord = st.floats(-2, 3, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(coord, coord)
def test_batched_and_single_margins_agree(x, y):
    poly = SupportPolygon(SQUARE)
    assert poly.margin(np.array([[x, y]]))[0] == pytest.approx(poly.margin_one(x, y), abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.05, 0.95), st.floats(0.05, 0.95),  # robot CoM inside
    st.floats(0.0, 1.0), st.floats(0.0, 1.0),  # added mass position inside
    st.floats(0.1, 50.0),
)
def test_adding_mass_inside_never_lowers_margin_below_the_smaller(rx, ry, ox, oy, m):
    """The margin is concave over a convex polygon: the mixture stays above the smaller margin."""
    poly = SupportPolygon(SQUARE)
    M = 101.0
    c = system_com(np.array([rx, ry, 0.9]), M, np.array([ox, oy, 1.0]), m)
    lower = min(poly.margin_one(rx, ry), poly.margin_one(ox, oy))
    assert poly.margin_one(c[0], c[1]) >= lower - 1e-12


@settings(max_examples=100, deadline=None)
@given(st.floats(0.0, 0.2), st.floats(0.0, 0.2))
def test_raising_the_threshold_never_makes_a_state_stable(t1, t2):
    poly = SupportPolygon(SQUARE)
    pts = np.random.default_rng(0).uniform(-0.5, 1.5, size=(200, 2))
    m = poly.margin(pts)
    lo, hi = sorted((t1, t2))
    assert not np.any((m >= hi) & ~(m >= lo))
