"""Time-optimal timing (TOPP-RA) of joint paths: the analytic bang-bang case, the ZMP constraint where it binds,
and torques recomputed independently along the timed path."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest
import toppra.constraint
from hypothesis import given, settings
from hypothesis import strategies as st
from toppra.constraint import DiscretizationType
from toppra.constraint.linear_constraint import canlinear_colloc_to_interpolate

from planner.motion.timing import zmp_cart_table
from planner.motion.topp import BlendedPath, LinearRows, SplinePath, gridpoints_for, parameterize, profile_times
from planner.regrasp.plan_assembly import MotionPiece
from planner.regrasp.timing.plan_timer import PlanTimer
from planner.regrasp.timing.runs import Run
from planner.regrasp.timing.settings import PlanTimingSettings
from planner.stability.effort import EffortEvaluator, effort_limits
from planner.stability.evaluator import HoldSpec, StateEvaluator

DT = 0.005


def bang_bang_duration(D: np.ndarray, vmax: np.ndarray, amax: np.ndarray) -> float:
    """Rest-to-rest time along the straight line D with every joint on it: accelerate at the largest path
    acceleration the joints allow, cruise at the largest path speed, brake."""
    L = float(np.linalg.norm(D))
    u = np.abs(D) / L
    u[u < 1e-12] = 0.0
    V = float(np.min(vmax[u > 0] / u[u > 0]))
    A = float(np.min(amax[u > 0] / u[u > 0]))
    if V * V / A >= L:  # the cruise speed is never reached
        return 2.0 * np.sqrt(L / A)
    return L / V + V / A


@settings(max_examples=25, deadline=None)
@given(D=st.lists(st.floats(-2.0, 2.0), min_size=1, max_size=4).filter(lambda d: np.linalg.norm(d) > 0.05),
       v=st.floats(0.2, 2.0), a=st.floats(0.3, 4.0), ratio=st.floats(0.5, 2.0))
def test_a_straight_two_waypoint_path_takes_the_bang_bang_time(D, v, a, ratio):
    D = np.asarray(D)
    n = len(D)
    vmax = np.full(n, v)
    vmax[0] *= ratio  # the joints need not share their limits
    amax = np.full(n, a)
    path = BlendedPath(np.array([np.zeros(n), D]), np.zeros(0))
    grid = gridpoints_for(path, 0.002, 5000)
    sd = parameterize(path, grid, vmax, amax, [])
    assert sd is not None and sd[0] == 0.0 and sd[-1] == 0.0
    T = profile_times(grid, sd)[-1]
    assert T == pytest.approx(bang_bang_duration(D, vmax, amax), rel=2e-3)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), corners=st.integers(1, 3))
def test_the_default_grid_times_a_blended_path_within_0_3_percent_of_a_converged_one(seed, corners):
    """TOPP-RA's interpolation discretisation holds each row at both ends of an interval with s'' constant across
    it: a coarser grid is slower where the limits change along the path (the blends), not quicker (to the converged
    grid's own 1e-5). The plan timing's default grid stays within 0.3 % of a 0.0005 rad grid's time (over 600 such
    paths at most 0.15 %; a 0.02 rad grid up to 0.58 %, over 0.3 % on one path in twenty)."""
    rng = np.random.default_rng(seed)
    n = 3
    W = np.cumsum(rng.uniform(-1.2, 1.2, (corners + 2, n)), axis=0)
    path = BlendedPath(W, np.full(corners, 0.7), True)
    vmax, amax = rng.uniform(0.5, 1.5, n), rng.uniform(0.5, 3.0, n)
    timing = PlanTimingSettings()

    def duration(step: float, most: int) -> float:
        grid = gridpoints_for(path, step, most)
        sd = parameterize(path, grid, vmax, amax, [])
        assert sd is not None
        return float(profile_times(grid, sd)[-1])

    converged = duration(0.0005, 100_000)
    default = duration(timing.grid_step_rad, timing.max_gridpoints)
    assert converged * (1 - 1e-5) <= default <= converged * 1.003


class _RowsPerGridpoint(toppra.constraint.LinearConstraint):
    """The reference form of the same rows: TOPP-RA's general constraint, its own ``F_i = [I; -I]`` and
    ``g_i = [upper_i; -lower_i]`` at every gridpoint."""

    def __init__(self, a, b, c, lower, upper):
        super().__init__()
        self.a, self.b, self.c = a, b, c
        m = a.shape[1]
        self.F = np.repeat(np.vstack([np.eye(m), -np.eye(m)])[None], len(a), axis=0)
        self.g = np.hstack([upper, -lower])
        self.set_discretization_type(DiscretizationType.Interpolation)

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        return canlinear_colloc_to_interpolate(self.a, self.b, self.c, self.F, self.g, None, None, gridpoints)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), m=st.integers(1, 4), one_sided=st.lists(st.booleans(), min_size=4, max_size=4))
def test_the_rows_give_the_profile_of_the_same_rows_set_per_gridpoint(seed, m, one_sided):
    rng = np.random.default_rng(seed)
    W = rng.uniform(-1.0, 1.0, (3, 3))
    path = BlendedPath(W, np.array([0.3]))
    grid = gridpoints_for(path, 0.02, 1000)
    n = len(grid)
    a, b = rng.normal(0.0, 0.5, (n, m)), rng.normal(0.0, 0.5, (n, m))
    c = rng.normal(0.0, 0.1, (n, m))
    upper = np.abs(c) + rng.uniform(0.5, 2.0, (n, m))  # at rest (u = x = 0) within the bounds
    lower = -np.abs(c) - rng.uniform(0.5, 2.0, (n, m))
    lower[:, np.array(one_sided[:m])] = -np.inf
    vmax, amax = np.full(3, 1.5), np.full(3, 3.0)
    ours = parameterize(path, grid, vmax, amax, [LinearRows(grid, a, b, c, lower, upper)])
    reference = parameterize(path, grid, vmax, amax, [_RowsPerGridpoint(a, b, c, lower, upper)])
    assert (ours is None) == (reference is None)
    if ours is not None:
        np.testing.assert_allclose(ours, reference, rtol=1e-9, atol=1e-12)


def test_a_row_bound_finite_at_some_gridpoints_and_infinite_at_others_is_refused():
    grid = np.linspace(0.0, 1.0, 5)
    a = np.ones((5, 1))
    upper = np.array([[1.0], [np.inf], [1.0], [1.0], [1.0]])
    with pytest.raises(ValueError, match="finite at every gridpoint or infinite at all"):
        LinearRows(grid, a, a, 0.0 * a, -upper, upper)


def _arm_move_from(robot, stance) -> np.ndarray:
    """The right hand carrying a heavy object from close to the chest to far in front (the CoM goes forward), the
    rest of the body in the stance's posture: the two waypoints."""
    q0, q1 = stance.q.copy(), stance.q.copy()
    j = robot.joint_index
    q0[j("RSP")], q0[j("REP")] = 0.2, -1.6
    q1[j("RSP")], q1[j("REP")] = -0.9, -0.3
    return np.array([q0, q1])


@pytest.fixture(scope="module")
def arm_move(hrp5p, stances):
    """That arm move in the upright stance."""
    return stances["upright"], _arm_move_from(hrp5p, stances["upright"])


def _timer(robot, stance, mass, com_local, zmp_margin, limits=True, **timing):
    ev = StateEvaluator(robot, stance, 0.0, mass, com_local)
    task = SimpleNamespace(robot=robot, evaluator=ev, stance=stance, constrained=False,
                           obj=SimpleNamespace(mass_kg=mass, com_local=com_local),
                           limits=EffortEvaluator(robot, stance, mass, com_local) if limits else None)
    return PlanTimer(task, PlanTimingSettings(**timing), 1.0, zmp_margin, DT), ev


def test_where_the_zmp_binds_it_is_held_at_its_margin_and_never_beyond(hrp5p, arm_move):
    stance, W = arm_move
    mass, com_local = 10.0, np.array([0.05, 0.0, 0.0])
    hold = HoldSpec("right", np.eye(4))
    line = W[0] + np.linspace(0.0, 1.0, 60)[:, None] * (W[1] - W[0])
    _, ev = _timer(hrp5p, stance, mass, com_local, 0.0)
    need = float(ev.evaluate(line, hold).margin.min()) - 0.001  # 1 mm of room where the CoM is closest to the edge
    run = Run([MotionPiece("transfer", "right", W, "right", hold, path=W)], "right", hold, None)

    def zmp_margins(zmp_margin):
        timer, ev = _timer(hrp5p, stance, mass, com_local, zmp_margin, zmp_reserve_share=0.0)
        part = timer.time_part(run, W, np.zeros(0))
        assert part is not None
        com = ev.evaluate(part.Q, hold).com  # the samples' CoM and the ZMP as the plan checker computes it
        return ev.polygon.margin(zmp_cart_table(com, DT)), len(part.Q)

    free, n_free = zmp_margins(0.0)
    assert free.min() < need - 0.0002  # unconstrained, braking at the end takes the ZMP past that margin
    held, n_held = zmp_margins(need)
    assert held.min() >= need  # never violated
    assert held.min() <= need + 0.001  # and active: within 1 mm somewhere along the path
    assert n_held > n_free  # it costs time


def test_the_reserve_keeps_the_zmp_a_share_of_the_runs_tightest_static_margin_inside(hrp5p, arm_move):
    """With a ZMP margin of 0, the reserve share alone holds the ZMP: at least that share of the smallest static
    CoM margin along the run inside the polygon, active within 1 mm where it binds; a larger share takes longer."""
    stance, W = arm_move
    mass, com_local = 10.0, np.array([0.05, 0.0, 0.0])
    hold = HoldSpec("right", np.eye(4))
    line = W[0] + np.linspace(0.0, 1.0, 400)[:, None] * (W[1] - W[0])
    _, ev = _timer(hrp5p, stance, mass, com_local, 0.0)
    tightest = float(ev.evaluate(line, hold).margin.min())
    run = Run([MotionPiece("transfer", "right", W, "right", hold, path=W)], "right", hold, None)
    out = {}
    for share in (0.0, 0.5, 0.9):
        timer, ev = _timer(hrp5p, stance, mass, com_local, 0.0, zmp_reserve_share=share)
        part = timer.time_part(run, W, np.zeros(0))
        assert part is not None
        zmp = ev.polygon.margin(zmp_cart_table(ev.evaluate(part.Q, hold).com, DT))
        out[share] = (zmp.min(), len(part.Q))
    assert out[0.0][0] < 0.9 * tightest - 0.0001  # without a reserve the ZMP goes past it (braking at the end)
    for share in (0.5, 0.9):
        assert out[share][0] >= share * tightest - 1e-4  # never violated (to the plan check's tolerance)
    assert out[0.9][0] <= 0.9 * tightest + 0.001  # and active
    assert out[0.0][1] <= out[0.5][1] <= out[0.9][1] and out[0.0][1] < out[0.9][1]


def _timed_swing(robot, stance, **timing) -> tuple[np.ndarray, StateEvaluator, HoldSpec]:
    """The heavy arm move from ``stance`` (10 kg in the right hand) timed alone with these timing settings and a ZMP
    margin of 0: its timed samples, the evaluator and the hold."""
    W = _arm_move_from(robot, stance)
    hold = HoldSpec("right", np.eye(4))
    run = Run([MotionPiece("transfer", "right", W, "right", hold, path=W)], "right", hold, None)
    timer, ev = _timer(robot, stance, 10.0, np.array([0.05, 0.0, 0.0]), 0.0, **timing)
    part = timer.time_part(run, W, np.zeros(0))
    assert part is not None
    return part.Q, ev, hold


def test_on_one_foot_the_reserve_keeps_the_zmp_its_own_larger_share_inside(hrp5p, stances):
    """A stance with one sole on the ground takes ``zmp_reserve_share_one_foot`` (0.95), two take
    ``zmp_reserve_share`` (0.9); a reserve turned off (share 0) is off on one foot too. Timed on one foot, the ZMP
    stays at least 0.95 of the run's tightest static CoM margin inside (active within 1 mm), and the run takes longer
    than with the two-foot share."""
    one, two = stances["one-legged"], stances["upright"]
    assert sum(f.in_contact for f in one.feet) == 1 and sum(f.in_contact for f in two.feet) == 2
    mass, com_local = 10.0, np.array([0.05, 0.0, 0.0])
    assert _timer(hrp5p, one, mass, com_local, 0.0)[0].reserve_share == 0.95
    assert _timer(hrp5p, two, mass, com_local, 0.0)[0].reserve_share == 0.9
    assert _timer(hrp5p, one, mass, com_local, 0.0, zmp_reserve_share=0.0)[0].reserve_share == 0.0

    W = _arm_move_from(hrp5p, one)
    line = W[0] + np.linspace(0.0, 1.0, 400)[:, None] * (W[1] - W[0])
    _, ev = _timer(hrp5p, one, mass, com_local, 0.0)
    tightest = float(ev.evaluate(line, HoldSpec("right", np.eye(4))).margin.min())
    assert tightest > 0.01
    out = {}
    for share in (0.9, 0.95):
        Q, ev, hold = _timed_swing(hrp5p, one, zmp_reserve_share_one_foot=share)
        out[share] = (ev.polygon.margin(zmp_cart_table(ev.evaluate(Q, hold).com, DT)).min(), len(Q))
    assert out[0.95][0] >= 0.95 * tightest - 1e-4  # never violated (to the plan check's tolerance)
    assert out[0.95][0] <= 0.95 * tightest + 0.001  # and active
    assert out[0.9][0] < 0.95 * tightest - 1e-4  # the two-foot share lets it go farther out
    assert out[0.95][1] > out[0.9][1]


def test_on_one_foot_the_zmp_keeps_a_share_of_the_coms_own_margin_at_every_sample(hrp5p, stances):
    """On one foot the ZMP also keeps ``zmp_local_share_one_foot`` (0.9) of the CoM's own static margin at each
    point, not only the run's floor: at every timed sample the ZMP (as the plan checker computes it) is at least 0.9
    of that sample's CoM margin inside, active within 1 mm where it binds. Without it the swing brakes with its ZMP
    farther out than that, and it is quicker. Two feet, or the reserve off, take none."""
    one, two = stances["one-legged"], stances["upright"]
    mass, com_local = 10.0, np.array([0.05, 0.0, 0.0])
    assert _timer(hrp5p, one, mass, com_local, 0.0)[0].local_share == 0.9
    assert _timer(hrp5p, two, mass, com_local, 0.0)[0].local_share == 0.0
    assert _timer(hrp5p, one, mass, com_local, 0.0, zmp_reserve_share=0.0)[0].local_share == 0.0

    out = {}
    for local in (0.0, 0.9):
        Q, ev, hold = _timed_swing(hrp5p, one, zmp_local_share_one_foot=local)
        com = ev.evaluate(Q, hold).com
        zmp = ev.polygon.margin(zmp_cart_table(com, DT))
        out[local] = (zmp - 0.9 * ev.polygon.margin(com[:, :2]), len(Q))
    assert out[0.9][0].min() >= -1e-6  # never violated, at any sample
    assert out[0.9][0].min() <= 0.001  # and active
    assert out[0.0][0].min() < -0.001  # the run's floor alone lets the ZMP step farther ahead of the CoM
    assert out[0.9][1] > out[0.0][1]


@settings(max_examples=60, deadline=None)
@given(static=st.lists(st.floats(-0.02, 0.15), min_size=1, max_size=12), floor=st.floats(0.0, 0.08),
       inner=st.floats(0.0, 0.002), plan_min=st.one_of(st.none(), st.floats(0.0, 0.1)))
def test_the_local_share_asks_no_more_than_the_com_has_and_no_more_than_the_cap(hrp5p, stances, static, floor, inner,
                                                                              plan_min):
    """What the ZMP must keep at each point on one foot: never more than the CoM's own margin there (the ZMP at the
    CoM is always allowed), never less than the run's floor asks, at least 0.9 of the CoM's margin up to the
    reserve's cap, and what the cap may change is told to :meth:`PlanTimer._once` (the largest share asked)."""
    timer, _ = _timer(hrp5p, stances["one-legged"], 10.0, np.zeros(3), 0.0, limits=False)
    timer.plan_static_min_m = plan_min
    timer._asked = []
    m = np.array(static)
    inside = np.maximum(m, 0.0)
    need = timer._zmp_need(m, floor, inner)
    assert np.all(need <= inside + 1e-12)
    assert np.all(need >= np.minimum(floor + inner, inside) - 1e-12)
    assert np.all(need >= np.minimum(np.minimum(0.9 * inside, timer._reserve_cap()), inside) - 1e-12)
    assert timer._asked == [pytest.approx(0.9 * inside.max())]
    if plan_min is not None:
        cap = 0.75 * plan_min + 0.019
        assert np.all(need <= np.maximum(np.minimum(floor + inner, inside), np.minimum(cap + inner, inside)) + 1e-12)


def test_the_zmp_step_bound_keeps_each_step_of_the_planned_zmp_within_it(hrp5p, arm_move):
    """Without a bound, the ZMP of a heavy straight swing steps where the profile switches from speeding up to
    braking; with ``zmp_step_m``, the cart-table ZMP as the plan checker computes it moves by at most that (plus
    0.5 mm for the speed term's change) along every edge normal from one sample to the next, and the run takes
    longer."""
    stance, W = arm_move
    mass, com_local = 10.0, np.array([0.05, 0.0, 0.0])
    hold = HoldSpec("right", np.eye(4))
    run = Run([MotionPiece("transfer", "right", W, "right", hold, path=W)], "right", hold, None)
    out = {}
    for step in (0.0, 0.004):
        timer, ev = _timer(hrp5p, stance, mass, com_local, 0.0, zmp_reserve_share=0.0, zmp_step_m=step)
        part = timer.time_part(run, W, np.zeros(0))
        assert part is not None
        zmp = zmp_cart_table(ev.evaluate(part.Q, hold).com, DT)
        moves = np.abs(np.diff(zmp @ ev.polygon.normals.T, axis=0)).max()
        out[step] = (moves, len(part.Q))
    assert out[0.0][0] > 0.004 + 0.0005  # unbounded, the switch steps farther
    assert out[0.004][0] <= 0.004 + 0.0005
    assert out[0.004][1] > out[0.0][1]


def test_the_reserve_asks_no_more_than_its_cap_once_the_plans_margin_is_known(hrp5p, arm_move):
    """With the plan's smallest static margin known, the reserve asks at most ``zmp_reserve_cap_share`` of it plus
    ``zmp_overshoot_m`` (never less than the ZMP margin); without it the cap does nothing. A capped run keeps its ZMP
    at the capped floor and is no slower than the uncapped one."""
    stance, W = arm_move
    mass, com_local = 10.0, np.array([0.05, 0.0, 0.0])
    hold = HoldSpec("right", np.eye(4))
    timer, ev = _timer(hrp5p, stance, mass, com_local, 0.004, zmp_reserve_cap_share=0.75, zmp_overshoot_m=0.01)
    static = np.array([0.12, 0.09, 0.1])
    assert timer._zmp_floor(static) == pytest.approx(0.9 * 0.09)  # the plan's margin not known yet: uncapped
    timer.plan_static_min_m = 0.06
    assert timer._zmp_floor(static) == pytest.approx(0.75 * 0.06 + 0.01)  # capped
    assert timer._zmp_floor(np.array([0.03])) == pytest.approx(0.9 * 0.03)  # a tighter run keeps its own share
    timer.plan_static_min_m = 0.0
    assert timer._zmp_floor(static) == pytest.approx(0.01)  # never below the cap's overshoot
    timer.plan_static_min_m, timer.zmp_margin_m = 0.0, 0.02
    assert timer._zmp_floor(static) == pytest.approx(0.02)  # nor below the ZMP margin

    run = Run([MotionPiece("transfer", "right", W, "right", hold, path=W)], "right", hold, None)
    line = W[0] + np.linspace(0.0, 1.0, 400)[:, None] * (W[1] - W[0])
    tightest = float(ev.evaluate(line, hold).margin.min())

    def timed(plan_static_min):
        timer, ev = _timer(hrp5p, stance, mass, com_local, 0.0, zmp_reserve_cap_share=0.75, zmp_overshoot_m=0.002)
        timer.plan_static_min_m = plan_static_min
        part = timer.time_part(run, W, np.zeros(0))
        assert part is not None
        return ev.polygon.margin(zmp_cart_table(ev.evaluate(part.Q, hold).com, DT)).min(), len(part.Q)

    uncapped, n_uncapped = timed(None)
    capped, n_capped = timed(0.6 * tightest)
    assert uncapped >= 0.9 * tightest - 1e-4 and capped >= 0.75 * 0.6 * tightest + 0.002 - 1e-4
    assert n_capped <= n_uncapped


def test_a_users_own_zmp_margin_replaces_the_reserve():
    from planner.jobs.plan_job import timing_settings
    from planner.scene.scenarios import load_builtin

    scenario = load_builtin("upright")
    settings = PlanTimingSettings()
    assert timing_settings(scenario, settings).zmp_reserve_share == 0.9
    own = scenario.model_copy(update={"zmp_margin_m": 0.04})
    assert timing_settings(own, settings).zmp_reserve_share == 0.0


@pytest.mark.parametrize("share", [-0.1, 1.1, float("nan")])
def test_a_reserve_share_outside_0_1_is_refused(share):
    with pytest.raises(ValueError):
        PlanTimingSettings(zmp_reserve_share=share)


@pytest.mark.parametrize("share", [-0.1, 1.0, 1.1, float("nan")])
def test_a_local_share_outside_0_1_is_refused(share):
    """1 is refused too: the ZMP at the CoM's own margin everywhere leaves no braking towards an edge."""
    with pytest.raises(ValueError, match="zmp_local_share_one_foot"):
        PlanTimingSettings(zmp_local_share_one_foot=share)


def test_torques_stay_within_the_effort_limits_along_the_timed_path(hrp5p, arm_move):
    """Static plus inertial torques of the waist and arm joints, recomputed with pinocchio's inverse dynamics on a
    fixed-base model of the URDF with the object as a point mass in the hand, from finite differences of the samples.
    The timing may use 47 % of the limits here: the static torques alone take 46 % at the far end."""
    stance, W = arm_move
    mass, com_local = 12.0, np.array([0.05, 0.0, 0.0])
    share = 0.47
    hold = HoldSpec("right", np.eye(4))
    timer, ev = _timer(hrp5p, stance, mass, com_local, 0.0, effort_scale=share)
    run = Run([MotionPiece("transfer", "right", W, "right", hold, path=W)], "right", hold, None)
    part = timer.time_part(run, W, np.zeros(0))
    assert part is not None
    Q = np.vstack([part.Q[:1], part.Q, part.Q[-1:]])  # at rest before and after, as in a plan

    model = pin.buildModelFromUrdf(str(hrp5p.urdf_path))  # fixed base at the pelvis: the legs do not move
    tcp = model.getFrameId(hrp5p.spec.arms["right"].tcp)
    frame = model.frames[tcp]
    model.appendBodyToJoint(frame.parentJoint, pin.Inertia(mass, frame.placement.act(com_local), np.zeros((3, 3))),
                            pin.SE3.Identity())
    base_R = pin.XYZQUATToSE3(np.asarray(stance.base_pose)).rotation
    model.gravity = pin.Motion(base_R.T @ np.array([0.0, 0.0, -9.81]), np.zeros(3))  # in the pelvis frame
    data = model.createData()
    names = hrp5p.joint_names
    moving = [names[k] for k in np.flatnonzero(np.abs(W[1] - W[0]) > 0)] + ["WP", "WR", "WY", "RSC", "RSR", "RSY"]
    limit = effort_limits(hrp5p)
    idx = {name: (model.idx_qs[model.getJointId(name)], model.idx_vs[model.getJointId(name)]) for name in moving}
    worst = inertial = 0.0
    for i in range(1, len(Q) - 1):
        q = pin.neutral(model)
        v = np.zeros(model.nv)
        a = np.zeros(model.nv)
        for name, (iq, iv) in idx.items():
            k = names.index(name)
            q[iq] = Q[i, k]
            v[iv] = (Q[i + 1, k] - Q[i - 1, k]) / (2 * DT)
            a[iv] = (Q[i + 1, k] - 2 * Q[i, k] + Q[i - 1, k]) / DT**2
        for name in set(names) - set(idx):  # the other joints at their (fixed) values
            jid = model.getJointId(name)
            if jid < model.njoints and model.joints[jid].nq == 1:
                q[model.idx_qs[jid]] = Q[i, names.index(name)]
        tau = pin.rnea(model, data, q, v, a)
        worst = max(worst, max(abs(tau[iv]) / limit[name] for name, (_, iv) in idx.items()))
        inertial = max(inertial, float(np.abs(tau - pin.rnea(model, data, q, 0 * v, 0 * a)).max()))
    assert worst <= share
    assert inertial > 1.0  # the motion's own torques were part of it (N m)


@settings(max_examples=40, deadline=None)
@given(lengths=st.lists(st.floats(0.02, 1.5), min_size=3, max_size=6), seed=st.integers(0, 10_000),
       cap=st.floats(0.05, 1.0))
def test_filled_blends_share_each_segment_and_keep_the_path_smooth_and_near_its_corners(lengths, seed, cap):
    rng = np.random.default_rng(seed)
    n = 3
    steps = rng.normal(size=(len(lengths), n))
    steps *= (np.asarray(lengths) / np.linalg.norm(steps, axis=1))[:, None]
    W = np.vstack([np.zeros(n), np.cumsum(steps, axis=0)])
    cap_all = np.full(len(W) - 2, cap)
    half = BlendedPath(W, cap_all)
    full = BlendedPath(W, cap_all, fill=True)
    L = np.linalg.norm(np.diff(W, axis=0), axis=1)
    d = np.r_[0.0, full.blend, 0.0]
    assert np.all(d[:-1] + d[1:] <= L + 1e-12)  # a segment's two blends fit in it
    assert np.all(full.blend <= cap + 1e-12)
    # never less than its share of each neighbouring segment, the segment's length split between its two corners in
    # proportion to how sharply they turn (|u_out - u_in|; a corner at the path's end takes none)
    unit = np.diff(W, axis=0) / L[:, None]
    turn = np.r_[0.0, np.linalg.norm(unit[1:] - unit[:-1], axis=1), 0.0]
    both = turn[:-1] + turn[1:]
    first_share = np.where(both > 0, L * turn[:-1] / np.where(both > 0, both, 1.0), 0.5 * L)  # segment j, corner j
    second_share = L - first_share  # segment j, corner j + 1
    lower = np.minimum(cap, np.minimum(second_share[:-1], first_share[1:]))
    assert np.all(full.blend >= lower * (1 - 1e-6) - 1e-12)
    # C1 at unit speed: position and direction continuous across every break, the ends exactly the waypoints
    b = full.breaks[1:-1]
    for eps_side in (0, 1):
        assert np.allclose(full(b - 1e-9, eps_side), full(b + 1e-9, eps_side), atol=1e-6)
    s = np.linspace(0.0, full.length, 2001)
    speed = np.linalg.norm(full(s, 1), axis=1)
    assert speed.max() <= 1.0 + 1e-9 and speed.min() > 0.0  # unit on the lines, between the two directions on a blend
    assert np.allclose(full(0.0), W[0]) and np.allclose(full(full.length), W[-1])
    # every point within d/2 of its corner on a blend, on the polyline elsewhere
    Q = full(s)
    seg_dist = np.full(len(s), np.inf)
    for i in range(len(W) - 1):
        a_, u = W[i], W[i + 1] - W[i]
        t = np.clip(((Q - a_) @ u) / (u @ u), 0.0, 1.0)
        seg_dist = np.minimum(seg_dist, np.linalg.norm(Q - (a_ + t[:, None] * u), axis=1))
    assert seg_dist.max() <= 0.5 * max(full.blend.max(), 0.0) + 1e-9


@settings(max_examples=40, deadline=None)
@given(lengths=st.lists(st.floats(0.02, 1.5), min_size=2, max_size=7), seed=st.integers(0, 10_000))
def test_the_spline_starts_and_ends_at_rest_points_tangent_to_its_end_legs_and_is_c2(lengths, seed):
    rng = np.random.default_rng(seed)
    steps = rng.normal(size=(len(lengths), 4))
    steps *= (np.asarray(lengths) / np.linalg.norm(steps, axis=1))[:, None]
    W = np.vstack([np.zeros(4), np.cumsum(steps, axis=0)])
    path = SplinePath(W)
    assert np.allclose(path(0.0), W[0]) and np.allclose(path(path.length), W[-1])
    for end, leg in ((0.0, W[1] - W[0]), (path.length, W[-1] - W[-2])):  # tangent to the first and last legs
        d = path(end, 1)
        assert np.allclose(d / np.linalg.norm(d), leg / np.linalg.norm(leg), atol=1e-9)
    s = np.linspace(0.0, path.length, 4001)
    Q, d1, d2 = path(s), path(s, 1), path(s, 2)
    ds = s[1] - s[0]
    assert np.allclose(np.diff(Q, axis=0) / ds, 0.5 * (d1[1:] + d1[:-1]), atol=1e-3 * (1 + np.abs(d2).max()))
    inner = np.unique(path.knots[(path.knots > 0) & (path.knots < 1)]) * path.length
    eps = 1e-7 * path.length  # no jump in the second derivative at any knot (C2)
    assert np.allclose(path(inner - eps, 2), path(inner + eps, 2), atol=1e-4 * (1 + np.abs(d2).max()))
    # the parameter is the arc length on average, and each waypoint's path position grows along the path
    assert np.sum(np.linalg.norm(np.diff(Q, axis=0), axis=1)) == pytest.approx(path.length, rel=1e-3)
    assert np.all(np.diff(path.waypoint_s) > 0) and path.waypoint_s[0] == 0 and path.waypoint_s[-1] == pytest.approx(path.length)
    # inside the box of its waypoints (a B-spline lies in the convex hull of its control points)
    assert np.all(Q >= W.min(axis=0) - 1e-9) and np.all(Q <= W.max(axis=0) + 1e-9)
    cols = np.array([0, 2])
    assert np.allclose(path.columns(cols)(s, 2), d2[:, cols])


def test_a_sharp_corner_takes_more_of_a_short_segment_than_the_gentle_one_beside_it():
    """A 90 degree corner and a 20 degree one share a 0.2 rad segment: split in proportion to how sharply each
    turns, the sharp one's blend is 1.4 / (1.4 + 0.35) of it, where halving gave it 0.1 rad."""
    turn = np.radians(20.0)
    W = np.array([[0.0, -1.0], [0.0, 0.0], [0.2, 0.0], [0.2 + np.cos(turn), np.sin(turn)]])
    blends = BlendedPath(W, np.full(2, 0.5), fill=True).blend
    sharp, gentle = np.sqrt(2.0), 2.0 * np.sin(turn / 2)
    assert blends[0] == pytest.approx(0.2 * sharp / (sharp + gentle), rel=1e-9)
    assert blends[0] + blends[1] == pytest.approx(0.2, rel=1e-12)
    assert BlendedPath(W, np.full(2, 0.5)).blend[0] == pytest.approx(0.1)  # half each, without filling


def test_a_short_segment_next_to_the_end_no_longer_halves_its_corner():
    W = np.array([[0.0, 0.0], [0.1, 0.0], [0.1, 1.0], [1.1, 1.0]])  # a 0.1 rad first segment
    assert BlendedPath(W, np.full(2, 0.3)).blend[0] == pytest.approx(0.05)
    assert BlendedPath(W, np.full(2, 0.3), fill=True).blend[0] == pytest.approx(0.1, rel=1e-6)


@settings(max_examples=40, deadline=None)
@given(length=st.floats(0.05, 1.5), turn=st.floats(0.3, 3.0), extra=st.floats(0.0, 0.5))
def test_a_blend_that_takes_its_whole_segment_leaves_the_gridpoints_inside_the_path(length, turn, extra):
    """A blend that asks at least its end segment's length takes all of it (``fill``): to rounding, no line is left
    before it, and the gridpoints (the break's neighbour just before it included) stay within [0, L], so TOPP-RA
    takes them and times the path."""
    W = np.array([[0.0, 0.0], [length, 0.0], [length + length * np.cos(turn), length * np.sin(turn)]])
    path = BlendedPath(W, np.full(1, length + extra), fill=True)
    assert path.blend[0] == pytest.approx(length)
    grid = gridpoints_for(path, 0.02, 400)
    assert grid[0] == 0.0 and grid[-1] == path.length and np.all(np.diff(grid) > 0)
    sd = parameterize(path, grid, np.ones(2), np.full(2, 2.0), [])
    assert sd is not None and profile_times(grid, sd)[-1] > 0.0
