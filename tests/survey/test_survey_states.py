"""A survey that counts unstable states as well as stable ones, checked from its stored states.

The scenario (tests/data/one-legged-box.yaml) stands on one leg with a 50 mm threshold, 15 mm
inside the stance's 65 mm inradius, so the explored states straddle the threshold. The survey
runs through the CLI (``--json --states-out --plot``) for one single-arm and one dual-arm
configuration (``run_survey`` is wrapped to pass ``hands``, the two configurations whose key
poses exist here, which keeps the test fast, and the task it would build, kept for its handover
poses; everything else is the CLI's own path).

Every check works on what the CLI wrote: the recount, an independent reclassification
(pinocchio on the URDF, shapely; tests/survey/independent.py), the properties through the
project's StateEvaluator, collisions, the handover, the table and the plots.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest
import yaml
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rich.console import Console

from planner.stability.evaluator import HoldSpec, StateEvaluator
from service.cli.main import cli

from .independent import Independent
from .tables import table_rows

DATA = Path(__file__).parent.parent / "data"
SCENARIO = DATA / "one-legged-box.yaml"
HANDS = ["left-left", "right-left"]
STATES = 300
#: Two seeds of STATES states each (until: states).
SEEDS = 2
#: Flags are compared away from the threshold: two correct CoM computations differ by ~1e-12 m.
NEAR = 1e-9


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    import planner.api.jobs
    import planner.survey.runner as survey_module

    out = tmp_path_factory.mktemp("one-legged-survey")
    real = survey_module.run_survey
    captured = {}

    def two_configurations(scenario, **kwargs):
        from planner.regrasp.search_data import SearchData
        from planner.regrasp.task import Task
        captured["task"] = Task(scenario)  # what run_survey would build; kept for its handover poses
        captured["data"] = SearchData(captured["task"])
        doc, outcomes = real(scenario, hands=HANDS, task=captured["task"], data=captured["data"], **kwargs)
        captured["outcomes"] = outcomes
        return doc, outcomes

    with pytest.MonkeyPatch.context() as mp:
        patched = two_configurations
        # The CLI calls it through the planner's public interface, which binds it when first imported.
        mp.setattr(survey_module, "run_survey", patched)
        mp.setattr(planner.api.jobs, "run_survey", patched)
        res = CliRunner().invoke(cli, ["survey", str(SCENARIO), "--states", str(STATES), "--seeds-min", str(SEEDS),
                                       "--seeds-max", str(SEEDS), "--workers", "1", "--json",
                                       "--states-out", str(out / "states.npz"), "--plot", str(out / "plots")])
    assert res.exit_code == 0, res.output
    with np.load(out / "states.npz", allow_pickle=False) as npz:
        states = {k: npz[k] for k in npz.files}
    return SimpleNamespace(doc=json.loads(res.stdout), states=states, plots=out / "plots", stderr=res.stderr,
                           outcomes=captured["outcomes"], task=captured["task"], data=captured["data"])


@pytest.fixture(scope="module")
def indep(run):
    return Independent(run.doc["robot"]["name"], [str(n) for n in run.states["joint_names"]])


@pytest.fixture(scope="module")
def robot_com(run, indep):
    """pinocchio's robot CoM of every stored state."""
    return indep.robot_com(run.states["base_pose"], run.states["q"])


@pytest.fixture(scope="module")
def margins(run, indep, robot_com):
    """Independent margins of every stored state: equation 1, the polygon of the soles on the ground."""
    s = run.states
    com = indep.system_com(robot_com, indep.object_com(s["object_pose"], s["com_local"]), float(s["mass_kg"]))
    return indep.margins(indep.support_polygon(s["base_pose"], s["q"][0]), com[:, :2])


@pytest.fixture(scope="module")
def groups(run, indep):
    """The stored states by (hands, holding hand, seed), each with its grasp: the holding TCP in the object frame.

    Each seed explores one key path of its row's pool, so one grasp per leg and seed. The grasp is read off each
    state (pinocchio's TCP, the stored object pose); ``spread`` is how much it varies within the group (m, rad).
    """
    s = run.states
    out = []
    for hands in HANDS:
        for side in ("left", "right"):
            for seed in np.unique(s["seed"]):
                idx = np.flatnonzero((s["hands"] == hands) & (s["holding"] == side) & (s["seed"] == seed))
                if not len(idx):
                    continue
                grasps = [pin.XYZQUATToSE3(s["object_pose"][i]).actInv(
                    indep.frame(s["base_pose"], s["q"][i], f"{side[0]}_tcp")) for i in idx]
                spread = max(max(np.linalg.norm(pin.log6(grasps[0].actInv(g)).linear),
                                 np.linalg.norm(pin.log6(grasps[0].actInv(g)).angular)) for g in grasps)
                out.append(SimpleNamespace(hands=hands, side=side, seed=int(seed), idx=idx,
                                           T_obj_tcp=grasps[0].homogeneous, spread=spread))
    return out


@pytest.fixture(scope="module")
def evaluator_args(run):
    """What the project's StateEvaluator needs for this scenario, built from the project's own loaders."""
    from planner.robot.model import load_robot
    from planner.scene.scenarios import load_scenario
    from planner.stability.stances import solve_stance

    scenario = load_scenario(SCENARIO)
    robot = load_robot(scenario.robot)
    stance = solve_stance(robot, scenario.stance)
    return robot, stance, np.asarray(run.states["com_local"], float)


def _project_eval(run, groups, evaluator: StateEvaluator, threshold_m: float | None = None):
    """StateEvaluator on every stored state, group by group: (com (N, 3), margin (N,), stable (N,), object pose (N, 4, 4))."""
    n = len(run.states["q"])
    com, margin, stable, pose = np.zeros((n, 3)), np.zeros(n), np.zeros(n, bool), np.zeros((n, 4, 4))
    for g in groups:
        b = evaluator.evaluate(run.states["q"][g.idx], HoldSpec(g.side, g.T_obj_tcp), threshold_m=threshold_m)
        com[g.idx], margin[g.idx], stable[g.idx], pose[g.idx] = b.com, b.margin, b.stable, b.object_pose
    return com, margin, stable, pose


# -- counts ---------------------------------------------------------------------------------------

def test_the_survey_counts_unstable_states_as_well_as_stable_ones(run):
    rows = {r["hands"]: r for r in run.doc["rows"]}
    assert list(rows) == HANDS
    for row in rows.values():
        assert row["reason"] is None, row
        assert row["stable"] + row["unstable"] == SEEDS * STATES
        assert [p["stable"] + p["unstable"] for p in row["per_seed"]] == [STATES] * SEEDS
        assert row["ratio"] == pytest.approx(row["stable"] / (SEEDS * STATES))
    # A real share of unstable states, not a stray one.
    single = rows["left-left"]
    assert 0.1 <= single["unstable"] / (SEEDS * STATES) <= 0.9, single
    assert run.doc["threshold_m"] == 0.05 and run.doc["stance"]["name"] == "one-legged"


def test_counts_equal_the_recount_from_states_out(run):
    s = run.states
    assert len(s["q"]) == sum(r["stable"] + r["unstable"] for r in run.doc["rows"])
    for row in run.doc["rows"]:
        mine = s["hands"] == row["hands"]
        assert int(s["stable"][mine].sum()) == row["stable"]
        assert int((~s["stable"][mine]).sum()) == row["unstable"]
    assert set(np.unique(s["hands"])) == set(HANDS)
    assert s["q"].shape == (len(s["hands"]), len(s["joint_names"])) and s["object_pose"].shape == (len(s["hands"]), 7)
    assert float(s["threshold_m"]) == run.doc["threshold_m"] and float(s["mass_kg"]) == run.doc["object"]["mass_kg"]
    assert np.allclose(s["com_local"], run.doc["object"]["com_local"])
    assert np.allclose(s["base_pose"], run.doc["stance"]["base_pose"])


def test_an_independent_recomputation_agrees_with_the_flags_on_both_sides(run, indep, margins):
    """Every stored state reclassified from the URDF alone (pinocchio, equation 1, shapely)."""
    from shapely.geometry import Polygon

    s = run.states
    # The support polygon: soles on the ground (one-legged: the right one alone), from the URDF.
    polygon = indep.support_polygon(s["base_pose"], s["q"][0])
    assert polygon.symmetric_difference(Polygon(s["support_polygon"])).area < 1e-6
    assert polygon.area == pytest.approx(0.23 * 0.13, rel=1e-6)  # one sole
    thr = float(s["threshold_m"])
    assert (~s["stable"]).sum() >= 20 and s["stable"].sum() >= 20
    far = np.abs(margins - thr) > NEAR
    assert far.mean() > 0.95
    assert np.array_equal((margins >= thr)[far], s["stable"][far])
    assert not (margins[s["stable"]] < thr - NEAR).any() and not (margins[~s["stable"]] >= thr + NEAR).any()


# -- properties through the project's StateEvaluator ----------------------------------------------

def test_the_object_moves_rigidly_with_the_holding_hand(groups):
    """Per leg and seed one grasp: the stored object pose follows the holding TCP (so the grasp can be read off)."""
    assert {(g.hands, g.side) for g in groups} == {("left-left", "left"), ("right-left", "right"), ("right-left", "left")}
    for g in groups:
        assert g.spread < 1e-6, (g.hands, g.side, g.spread)


def test_the_state_evaluator_reproduces_the_stored_states(run, groups, evaluator_args, robot_com, indep):
    robot, stance, com_local = evaluator_args
    ev = StateEvaluator(robot, stance, float(run.states["threshold_m"]), float(run.states["mass_kg"]), com_local)
    com, _, stable, pose = _project_eval(run, groups, ev)
    assert np.array_equal(stable, run.states["stable"])
    obj = indep.object_com(run.states["object_pose"], com_local)
    assert np.allclose(com, indep.system_com(robot_com, obj, float(run.states["mass_kg"])), atol=1e-9)
    stored = np.array([pin.XYZQUATToSE3(p).homogeneous for p in run.states["object_pose"]])
    assert np.allclose(pose, stored, atol=1e-9)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(lo=st.floats(0.0, 0.07), raise_by=st.floats(0.0, 0.03))
def test_raising_the_threshold_never_turns_an_unstable_state_stable(run, groups, evaluator_args, margins, lo, raise_by):
    """Reclassified at two thresholds by the project's evaluator: stable at the higher one implies stable at the
    lower one; each classification equals the independent margin's, so the property is not vacuous."""
    robot, stance, com_local = evaluator_args
    hi = lo + raise_by
    ev = StateEvaluator(robot, stance, lo, float(run.states["mass_kg"]), com_local)
    _, margin, stable_lo, _ = _project_eval(run, groups, ev)
    _, _, stable_hi, _ = _project_eval(run, groups, ev.with_threshold(hi))
    assert not (stable_hi & ~stable_lo).any()
    # The states unstable at the survey's threshold stay unstable above it.
    if hi >= float(run.states["threshold_m"]):
        assert not (stable_hi & ~run.states["stable"]).any()
    assert np.allclose(margin, margins, atol=1e-9)
    for thr, flags in ((lo, stable_lo), (hi, stable_hi)):
        far = np.abs(margins - thr) > NEAR
        assert np.array_equal(flags[far], (margins >= thr)[far])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(light=st.floats(0.0, 30.0), extra=st.floats(0.5, 30.0))
def test_a_heavier_object_moves_each_com_towards_the_object_as_equation_1(run, groups, evaluator_args, robot_com, indep,
                                                                        light, extra):
    """The project's system CoM at two masses, on the stored q and grasps, against equation 1 written out:
    Gamma_S(m) - Gamma_obj = M / (M + m) (Gamma_robot - Gamma_obj), so the heavier one is the lighter one's
    offset from the object's CoM scaled by (M + m_light) / (M + m_heavy)."""
    robot, stance, com_local = evaluator_args
    heavy = light + extra
    thr = float(run.states["threshold_m"])
    com_l, _, _, pose = _project_eval(run, groups, StateEvaluator(robot, stance, thr, light, com_local))
    com_h, _, _, _ = _project_eval(run, groups, StateEvaluator(robot, stance, thr, heavy, com_local))
    obj = pose[:, :3, :3] @ com_local + pose[:, :3, 3]
    assert np.allclose(obj, indep.object_com(run.states["object_pose"], com_local), atol=1e-9)
    M = indep.total_mass
    assert M == pytest.approx(robot.total_mass, rel=1e-12)
    assert np.allclose(com_l, indep.system_com(robot_com, obj, light), atol=1e-9)
    assert np.allclose(com_h, indep.system_com(robot_com, obj, heavy), atol=1e-9)
    assert np.allclose(com_h - obj, (M + light) / (M + heavy) * (com_l - obj), atol=1e-9)
    d_l, d_h = np.linalg.norm(com_l - obj, axis=1), np.linalg.norm(com_h - obj, axis=1)
    assert np.all(d_h < d_l)


def test_no_counted_state_collides(run, groups, evaluator_args):
    """Every stored state, rechecked with its grasp in a collision world built afresh from the scenario;
    the exploration did meet colliding states (rejected, not counted), and the check does see a collision."""
    from planner.scene.collision import CollisionWorld
    from planner.scene.objects import build_object
    from planner.scene.scenarios import load_scenario

    robot, stance, _ = evaluator_args
    scenario = load_scenario(SCENARIO)
    world = CollisionWorld.from_scenario(robot, scenario, build_object(scenario.object),
                                         reference_postures=[(stance.base_pose, stance.q)])
    base = run.states["base_pose"]
    for g in groups:
        held = [(g.side, g.T_obj_tcp)]
        for i in g.idx:
            hit = world.check(base, run.states["q"][i], held=held)
            assert hit is None, (g.hands, int(i), hit)
    rejected = {h: c["rejected"]["collision"] for h, c in run.doc["stats"]["configurations"].items()}
    assert sum(rejected.values()) > 0, rejected
    # The same check on a counted state with the object held 0.3 m lower (its frame is upright: the
    # TCP 0.3 m higher in it) finds a collision (the table, or the other hand the object then meets).
    g = groups[0]
    sunk = g.T_obj_tcp.copy()
    sunk[2, 3] += 0.30
    q0 = run.states["q"][g.idx[0]]
    assert world.check(base, q0, held=[(g.side, g.T_obj_tcp)]) is None
    hit = world.check(base, q0, held=[(g.side, sunk)])
    assert hit is not None and hit.kind in ("object", "environment", "table") or "table" in f"{hit}", hit


# -- the dual-arm configuration -----------------------------------------------------------------------

def test_the_dual_arm_survey_goes_through_the_handover_pose(run, groups, indep):
    """right-left: right-held states grow from the pick's lift pose, left-held states grow from the key
    path's handover pose towards the place. Only sampled poses are counted (not the legs' ends), so the
    first poses of each tree lie within one extension of where it starts; the handover pose is off the
    table; each hand holds the box at its grasp (its TCP inside the box) in every state."""
    s = run.states
    by = {(g.hands, g.side): g for g in groups}
    giver, taker = by[("right-left", "right")], by[("right-left", "left")]
    label = next(p for p in run.doc["stats"]["configurations"]["right-left"]["path"] if p.startswith("handover pose"))
    T_handover = pin.SE3(run.data.handover_poses(run.task)[int(label.split()[2])].T_world_obj)
    start, goal = np.array(run.doc["object"]["start_pose"][:3]), np.array(run.doc["object"]["goal_pose"][:3])
    # One extension (0.3 rad over waist and arm) moves the object by well under 0.25 m.
    near_handover = np.linalg.norm(s["object_pose"][taker.idx][:, :3] - T_handover.translation, axis=1)
    assert near_handover.min() < 0.25, near_handover.min()
    near_pick = np.linalg.norm(s["object_pose"][giver.idx][:, :2] - start[:2], axis=1)
    assert near_pick.min() < 0.25, near_pick.min()
    assert min(np.linalg.norm(T_handover.translation - start), np.linalg.norm(T_handover.translation - goal)) > 0.05
    half = np.array([0.05, 0.12, 0.10]) / 2 + 1e-3
    for g, tcp in ((giver, "r_tcp"), (taker, "l_tcp")):
        for k in g.idx[:: max(1, len(g.idx) // 15)]:
            T = pin.XYZQUATToSE3(s["object_pose"][k])
            local = T.actInv(indep.frame(s["base_pose"], s["q"][k], tcp).translation)
            assert np.all(np.abs(local) <= half), (tcp, local)


# -- what the CLI wrote besides the states --------------------------------------------------------

def test_the_table_shows_each_configuration_with_c_u_r_and_the_recommended_marked(run):
    from service.cli.survey import LABELS, survey_table

    console = Console(width=200, record=True, color_system=None)
    console.print(survey_table(run.doc, "one-legged"))
    text = console.export_text()
    rows = {r["hands"]: r for r in run.doc["rows"]}
    seen = {}
    for cells in table_rows(text):
        for hands, label in LABELS.items():
            if cells[0].removesuffix(" *") == label:
                seen[hands] = cells
    assert set(seen) == set(rows)
    for hands, cells in seen.items():
        row = rows[hands]
        lo, hi = row["ratio_ci95"]
        assert cells[1:] == [str(row["stable"]), str(row["unstable"]), f"{row['ratio']:.4f}", f"[{lo:.4f}, {hi:.4f}]",
                             f"{row['seeds']}{'' if row['converged'] else ' (not converged)'}"]
        assert cells[0].endswith(" *") == (hands == run.doc["recommended"])
    # R decides: the dual-arm configuration here has the higher ratio.
    assert run.doc["recommended"] == max(rows.values(), key=lambda r: r["ratio"])["hands"]
    assert sum(c[0].endswith(" *") for c in seen.values()) == 1


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", path
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def test_the_convergence_plot_is_r_seed_by_seed_ending_at_the_row(run):
    """``--plot`` draws R against the states counted so far with its interval (docs/survey.md): the series is
    recomputed seed by seed from ``per_seed`` with the estimator's own seeded bootstrap, so its states grow seed
    by seed and its last point is the row's pooled ratio and 95 % interval (unstable states included here, so
    the interval is the bootstrap's, not the rule of three)."""
    from experiments.convergence_plot import convergence_series

    png = run.plots / "survey-one-legged-convergence.png"
    w, h = _png_size(png)
    assert w >= 400 and h >= 300 and png.stat().st_size > 10_000
    for row in run.doc["rows"]:
        assert row["unstable"] > 0
        series = convergence_series(row, int(run.doc["seed"]))
        assert np.array_equal(series["states"], np.cumsum([p["stable"] + p["unstable"] for p in row["per_seed"]]))
        assert series["ratio"][-1] == pytest.approx(row["ratio"])
        assert [series["lo"][-1], series["hi"][-1]] == pytest.approx(row["ratio_ci95"])
        assert np.all(series["lo"] <= series["ratio"] + 1e-12) and np.all(series["ratio"] <= series["hi"] + 1e-12)


def test_the_plots_are_real_pictures(run, tmp_path):
    import matplotlib.image as mpimg

    from service.cli.survey import bars_figure

    bars = run.plots / "survey-one-legged-bars.png"
    scatter = run.plots / "survey-one-legged-scatter.png"
    # One line per file, the path unbroken whatever the console's width.
    lines = run.stderr.splitlines()
    assert f"plot: {bars}" in lines and f"plot: {scatter}" in lines and f"plot: {scatter.with_suffix('.csv')}" in lines
    assert f"{len(run.states['q'])} evaluated states written to {run.plots.parent / 'states.npz'}" in lines
    for path in (bars, scatter):
        w, h = _png_size(path)
        assert w >= 400 and h >= 300 and path.stat().st_size > 10_000
        img = mpimg.imread(path)
        assert img.std() > 0.05  # not a blank canvas
    # The bar chart is the survey's rows: redrawn from the document it is the same picture, and with
    # another ratio it is not.
    scenario = yaml.safe_load(SCENARIO.read_text())["name"]
    same = bars_figure(run.doc, tmp_path / "same.png", scenario)
    assert np.array_equal(mpimg.imread(same), mpimg.imread(bars))
    other_rows = [dict(r, ratio=r["ratio"] / 2) for r in run.doc["rows"]]
    other = bars_figure({**run.doc, "rows": other_rows}, tmp_path / "other.png", scenario)
    assert not np.array_equal(mpimg.imread(other), mpimg.imread(bars))


def test_the_scatter_draws_its_csv_data_with_the_unstable_states_marked(run, tmp_path):
    """Redrawn from its CSV, the scatter is the same picture, pixel for pixel; drawn with every state
    stable it differs over many pixels: the unstable states' crosses are visible."""
    import matplotlib.image as mpimg

    from service.cli.survey import plot_title
    from experiments.plots import plot_survey_scatter

    with open(run.plots / "survey-one-legged-scatter.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    xy = np.array([[float(r["x_m"]), float(r["y_m"])] for r in rows])
    stable = np.array([r["stable"] == "1" for r in rows])
    hands = np.array([r["hands"] for r in rows])
    scenario = yaml.safe_load(SCENARIO.read_text())["name"]
    kwargs = dict(title=f"explored CoM projections\n{plot_title(run.doc, scenario)}", threshold_m=run.doc["threshold_m"],
                  polygon=np.array(run.doc["stats"]["support_polygon"]), xy=xy, hands=hands)
    again = plot_survey_scatter(tmp_path / "again.png", stable=stable, **kwargs)
    assert np.array_equal(mpimg.imread(again), mpimg.imread(run.plots / "survey-one-legged-scatter.png"))
    all_stable = plot_survey_scatter(tmp_path / "all-stable.png", stable=np.ones(len(xy), bool), **kwargs)
    changed = (np.abs(mpimg.imread(again)[:, :, :3] - mpimg.imread(all_stable)[:, :, :3]).sum(axis=2) > 0.3).sum()
    assert (~stable).sum() > 0 and changed > 20 * (~stable).sum()


def test_the_scatter_data_are_the_states_com_projections(run, indep, robot_com):
    """The CSV next to the scatter holds the points drawn: one per stored state, in the same order, at the
    independently recomputed CoM ground projection, coloured by the stored flag."""
    with open(run.plots / "survey-one-legged-scatter.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    s = run.states
    assert len(rows) == len(s["q"])
    assert [r["hands"] for r in rows] == list(s["hands"])
    assert [r["stable"] == "1" for r in rows] == list(s["stable"])
    xy = np.array([[float(r["x_m"]), float(r["y_m"])] for r in rows])
    com = indep.system_com(robot_com, indep.object_com(s["object_pose"], s["com_local"]), float(s["mass_kg"]))
    assert np.allclose(xy, com[:, :2], atol=1e-9)
    # The same arrays go to the picture.
    from service.cli.survey import scatter_data

    hands, xy2, stable = scatter_data(run.outcomes)
    assert np.array_equal(xy2, xy) and np.array_equal(stable, s["stable"]) and list(hands) == list(s["hands"])
