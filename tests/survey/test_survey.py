"""The stability survey on the upright small-box task: counts, recounts, determinism, bad input.

The unstable side, the properties on stored states, the handover and the outputs are in
test_survey_states.py (one-legged task) and test_survey_cli.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from planner.regrasp.node_validation import validate_placement
from planner.regrasp.probes import probe_givers, probe_grasps
from planner.regrasp.search_data import SearchData
from planner.scene.collision import CollisionWorld
from planner.scene.scenarios import load_scenario
from planner.survey.estimator import Estimator
from planner.survey.runner import run_survey, write_states
from service.cli.main import cli

from .independent import Independent

DATA = Path(__file__).parent.parent / "data"
HANDS = ["right-right", "left-left"]
STATES = 300
#: One seed of STATES states: the fixed-budget mode (until: states).
ONE_SEED = Estimator(until="states", states_per_seed=STATES, seeds_min=1, seeds_max=1)


def seeds_of(n: int, states: int = STATES) -> Estimator:
    return Estimator(until="states", states_per_seed=states, seeds_min=n, seeds_max=n)


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(DATA / "small-box.yaml")


@pytest.fixture(scope="module")
def surveyed(scenario, tmp_path_factory):
    doc, outcomes = run_survey(scenario, estimator=seeds_of(2), hands=HANDS, workers=1)
    path = tmp_path_factory.mktemp("survey") / "states.npz"
    from planner.robot.model import load_robot

    write_states(str(path), doc, outcomes, {"joint_names": list(load_robot("hrp5p").joint_names)})
    return doc, outcomes, dict(np.load(path, allow_pickle=False))


def test_rows_count_exactly_the_requested_states(surveyed):
    doc, _, _ = surveyed
    assert [r["hands"] for r in doc["rows"]] == HANDS
    for row in doc["rows"]:
        assert row["reason"] is None, row
        assert row["seeds"] == 2 and [p["seed"] for p in row["per_seed"]] == [1, 2]
        assert all(p["stable"] + p["unstable"] == STATES for p in row["per_seed"])
        assert row["stable"] + row["unstable"] == 2 * STATES
        assert row["stable"] == sum(p["stable"] for p in row["per_seed"])
        assert row["ratio"] == pytest.approx(row["stable"] / (2 * STATES))
        assert row["ratio_ci95"][0] <= row["ratio"] <= row["ratio_ci95"][1]
    assert doc["recommended"] in HANDS


def test_counts_equal_the_recount_from_states_out(surveyed):
    doc, _, states = surveyed
    for row in doc["rows"]:
        mine = states["hands"] == row["hands"]
        assert int(states["stable"][mine].sum()) == row["stable"]
        assert int((~states["stable"][mine]).sum()) == row["unstable"]
        for p in row["per_seed"]:
            assert int(states["stable"][mine & (states["seed"] == p["seed"])].sum()) == p["stable"]
    assert states["q"].shape == (len(states["hands"]), len(states["joint_names"]))
    assert states["object_pose"].shape == (len(states["hands"]), 7)


def test_an_independent_recomputation_agrees_with_the_stable_flags(surveyed):
    """A sample of the upright states reclassified from the URDF alone (all stable here: the states
    that are not are in test_survey_states.py's one-legged task)."""
    from shapely.geometry import Polygon

    _, _, states = surveyed
    indep = Independent("hrp5p", [str(n) for n in states["joint_names"]])
    pick = np.linspace(0, len(states["q"]) - 1, 60).astype(int)
    robot = indep.robot_com(states["base_pose"], states["q"][pick])
    com = indep.system_com(robot, indep.object_com(states["object_pose"][pick], states["com_local"]), float(states["mass_kg"]))
    polygon = indep.support_polygon(states["base_pose"], states["q"][0])
    assert polygon.symmetric_difference(Polygon(states["support_polygon"])).area < 1e-6
    margins = indep.margins(polygon, com[:, :2])
    thr = float(states["threshold_m"])
    near = np.abs(margins - thr) < 1e-9
    assert np.array_equal((margins >= thr)[~near], states["stable"][pick][~near])


def test_a_colliding_state_is_never_counted(scenario, surveyed):
    _, outcomes, _ = surveyed
    from planner.robot.model import load_robot
    from planner.scene.objects import build_object
    from planner.stability.stances import solve_stance

    robot = load_robot("hrp5p")
    stance = solve_stance(robot, scenario.stance)
    # The stance posture's touching pairs (thighs of bent knees) are disabled, as in the planner.
    world = CollisionWorld.from_scenario(robot, scenario, build_object(scenario.object),
                                         reference_postures=[(stance.base_pose, stance.q)])
    for o in outcomes:
        side = o.hands.split("-")[0]
        # Every counted state of a single-arm leg holds the object in one hand: recheck it with that grasp.
        import planner.transforms as tf

        for q, pose in zip(o.q[::15], o.object_pose[::15]):
            T_tcp = world.kin.frame(*world.kin.forward(stance.base_pose, q[None]), robot.spec.arms[side].tcp)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = T_tcp[0][0], T_tcp[1][0]
            T_obj_tcp = tf.inverse(tf.pose7_to_matrix(pose)) @ T
            assert world.check(stance.base_pose, q, held=[(side, T_obj_tcp)]) is None


def test_same_seed_same_counts_in_any_process_layout(scenario, surveyed):
    doc, _, _ = surveyed
    again, _ = run_survey(scenario, estimator=seeds_of(2), hands=HANDS, workers=2, keep_states=False)
    assert [(r["stable"], r["unstable"]) for r in again["rows"]] == [(r["stable"], r["unstable"]) for r in doc["rows"]]


def test_threshold_beyond_the_polygon_gives_reasons_not_counts(scenario):
    doc, _ = run_survey(scenario, estimator=seeds_of(1, 10), hands=HANDS, threshold_m=0.2, workers=1)
    for row in doc["rows"]:
        assert row["ratio"] is None and "inradius" in row["reason"]
    assert doc["recommended"] is None


@pytest.mark.parametrize("args,message", [
    (["--stance", "kneeling"], "built-in stances"),
    (["--states", "0"], "--states must be at least 1"),
    (["--threshold-mm", "-5"], "between 0 and 500"),
])
def test_bad_input_is_a_clear_usage_error(args, message):
    res = CliRunner().invoke(cli, ["survey", str(DATA / "small-box.yaml"), *args])
    assert res.exit_code == 2
    assert message in res.output


def test_json_output_is_one_document_even_with_files_written(tmp_path):
    import json

    res = CliRunner().invoke(cli, ["survey", str(DATA / "small-box.yaml"), "--states", "40", "--workers", "1",
                                    "--json", "--states-out", str(tmp_path / "s.npz")])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert {r["hands"] for r in doc["rows"]} == {"left-left", "right-right", "left-right", "right-left"}
    assert "evaluated states written" in res.stderr and (tmp_path / "s.npz").is_file()


def test_cli_threshold_beyond_the_polygon_is_an_error():
    res = CliRunner().invoke(cli, ["survey", str(DATA / "small-box.yaml"), "--threshold-mm", "200", "--states", "10"])
    assert res.exit_code == 2 and "inradius" in res.output


def test_states_out_with_all_stances_is_refused(tmp_path):
    res = CliRunner().invoke(cli, ["survey", str(DATA / "small-box.yaml"), "--all-stances", "--states-out", str(tmp_path / "s.npz")])
    assert res.exit_code == 2 and "one stance" in res.output
    assert not (tmp_path / "s.npz").exists()


def test_unknown_hands_are_rejected(scenario):
    with pytest.raises(ValueError, match="unknown hands 'both'"):
        run_survey(scenario, estimator=seeds_of(1, 10), hands=["both"], workers=1)


def test_key_poses_do_not_depend_on_which_configuration_ran_first(scenario):
    """Node validations are shared by a task's hand configurations and each node draws from its own
    generator, so a configuration finds the same key path whatever was validated before it."""
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.task import Task
    from planner.survey.runner import key_path, key_pose_termination

    def path_of(task, data, hands):
        path, reason = key_path(HandConfigPlanner(task, hands, key_pose_termination(task, lambda: False), data=data))
        assert path is not None, reason
        return path

    alone_task = Task(scenario)
    alone = path_of(alone_task, SearchData(alone_task), "left-left")
    shared = Task(scenario)
    shared_data = SearchData(shared)
    path_of(shared, shared_data, "right-right")
    path_of(shared, shared_data, "left-right")
    assert len(shared_data.node_cache) > 0
    assert path_of(shared, shared_data, "left-left") == alone


def test_a_parallel_survey_hands_its_node_validations_to_the_callers_task(scenario, monkeypatch):
    """Key poses are found in the caller's task (the workers only explore), so the plan after a
    `hands: auto` survey finds its key path without validating a node again."""
    import planner.regrasp.hand_config_planner as hcp
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.task import Task
    from planner.survey.runner import key_path, key_pose_termination

    task = Task(scenario)
    data = SearchData(task)
    run_survey(scenario, estimator=seeds_of(2, 50), hands=["right-right", "left-left"], workers=2, task=task,
               data=data)
    assert data.node_cache, "the workers' validations did not reach the caller"
    before = dict(data.node_cache)
    fresh_calls = []
    planner = HandConfigPlanner(task, "left-left", key_pose_termination(task, lambda: False), data=data)
    validate = hcp.validate_placement
    monkeypatch.setattr(hcp, "validate_placement",
                        lambda t, d, node, rng: fresh_calls.append(node) or validate(t, d, node, rng))
    path, reason = key_path(planner)
    assert path is not None, reason
    assert fresh_calls == [] and data.node_cache == before
    monkeypatch.undo()
    # and they are the validations a one-process run makes (each node has its own generator)
    alone = Task(scenario)
    alone_data = SearchData(alone)
    assert key_path(HandConfigPlanner(alone, "left-left", key_pose_termination(alone, lambda: False),
                                      data=alone_data))[0] == path


def test_the_cli_progress_bar_leaves_the_process_single_threaded():
    """The survey forks its workers only from a single-threaded process (see planner.forking)."""
    import threading

    from service.cli.plan import run_with_progress

    before = threading.active_count()
    during = run_with_progress("test", lambda progress: (progress(0.5, "half"), threading.active_count())[1])
    assert during == before


def test_the_estimator_defaults_to_the_scenario_s_and_the_old_count_reads_as_until_states(scenario):
    """docs/contract.md section 4: the scenario's survey field (until solved, +-0.02, 10 to 256 seeds, legs capped at
    20,000 states by default); `states_per_configuration` (survey/1) reads as until: states; 0 is refused.
    (A threshold beyond the polygon skips the exploration itself.)"""
    from planner.jobs.plan_job import build_task
    from planner.scene.scenarios import with_overrides

    task = build_task(scenario)
    doc, _ = run_survey(scenario, threshold_m=1.0, workers=1, task=task)
    assert doc["schema"] == "regrasp.survey/2"
    assert doc["estimator"] == {"until": "solved", "ci_half_width": 0.02, "seeds_min": 10, "seeds_max": 256,
                                "leg_cap_states": 20000, "key_paths": "stratified", "key_path_pool": 8}
    assert all(row["ratio"] is None and "inradius" in row["reason"] for row in doc["rows"])
    own = with_overrides(scenario, states_per_configuration=1234)
    doc, _ = run_survey(own, threshold_m=1.0, workers=1, task=task)
    assert doc["estimator"]["until"] == "states" and doc["estimator"]["states_per_seed"] == 1234
    with pytest.raises(ValueError, match="states per seed must be >= 1, got 0"):
        run_survey(scenario, states=0, workers=1, task=task)


@pytest.mark.parametrize("stable_postures", [False, True], ids=["ik-postures", "stable-postures"])
def test_grasp_probes_bound_the_validated_margin_and_prefill_only_certain_failures(scenario, stable_postures):
    """The search weighs placement nodes by a batched probe (IK at the grasp pose, margin holding the
    object there) before validating any. The probe must be optimistic (the node's validated margin is
    never larger: its lift starts from that very state), and a node it marks as failing on the margin
    must be one its own validation rejects for that reason. With stable postures, a probe that finds the
    held object unstable looks for the posture with the hand in place that keeps the margin: every probe
    left with a posture then keeps the planning threshold, and the ones that found none are marked."""
    from planner.regrasp.graph import PlacementNode
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.settings import PlannerSettings
    from planner.regrasp.task import Task
    settings = PlannerSettings(stable_postures=stable_postures)
    probe_task = Task(scenario, settings)
    probe_data = SearchData(probe_task)
    planner = HandConfigPlanner(probe_task, "right-right", data=probe_data)
    nodes = [n for n in planner.graph_spec().placement_nodes if isinstance(n, PlacementNode)][:40]
    margins = np.array([m for m in (p.margin_m for p in probe_grasps(probe_task, probe_data, nodes).values()) if m is not None])
    assert len(margins) >= 10  # many grasps of a spec are beyond the arm alone (from below, behind)
    # A threshold between the probed margins: some nodes are stable at their grasp, some are not.
    threshold = float(np.median(margins)) - probe_task.settings.planning_buffer_m
    task = Task(scenario, settings, threshold_m=threshold)
    data = SearchData(task)
    probes = probe_grasps(task, data, nodes)
    prefilled = {n: data.node_cache[n] for n in nodes if n in data.node_cache}
    if stable_postures:
        assert data.counters["stable_postures_found"] > 0
        for n in nodes:
            if probes[n].q is not None and n not in prefilled:
                assert probes[n].margin_m >= task.evaluator.threshold_m - 1e-9
    else:
        assert any(v.cause == "com_margin" for v in prefilled.values()), "no node was marked as failing on the margin"
    planner = HandConfigPlanner(task, "right-right", data=data)
    validated_ok = 0
    for node in nodes[:24]:
        data.node_cache.pop(node, None)
        v = validate_placement(task, data, node, np.random.default_rng(task.node_seed(node)))
        if node in prefilled:
            assert not v.ok and (v.cause, v.detail) == (prefilled[node].cause, prefilled[node].detail)
        elif v.ok and probes[node].margin_m is not None:
            validated_ok += 1
            assert v.margin_m <= probes[node].margin_m + 1e-12
    assert validated_ok > 0


def test_batched_giver_probes_classify_as_the_one_state_check_does(scenario):
    """The givers at the handover poses are solved and checked in batches; each entry's cause and margin
    must be what the planner's one-state check (pinocchio CoM, per-state collision) finds for it."""
    from planner.regrasp.graph import HandoverNode
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.task import Task
    task = Task(scenario, threshold_m=0.05)
    data = SearchData(task)
    planner = HandConfigPlanner(task, "right-left", data=data)
    nodes = [n for n in planner.graph_spec().handover_nodes if isinstance(n, HandoverNode)]
    probe_givers(task, data, nodes)
    entries = [v for v in data.giver_at.values() if v is not None]
    assert len(entries) >= 20
    causes = set()
    for q, hold, cause, margin in entries[:60]:
        assert np.linalg.norm(hold.T_obj_tcp[:3, 3]) < 0.5  # the object really is in that hand
        want_cause, want_margin = data.checker.classify(q, hold, None)
        assert cause == want_cause
        assert margin == pytest.approx(want_margin, abs=1e-9)
        causes.add(cause)
    assert len(causes) >= 2, causes  # both outcomes occur, so the comparison means something


def test_the_jaw_closing_probe_caches_the_verdict_the_validation_reaches(scenario):
    """The probes also close the jaw on the resting object from the probed posture, for all probed
    nodes at once. A node found failing there is cached with the verdict its own validation (from the
    same posture) reaches, margin included; a probed node not cached gets past that check."""
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.task import Task
    task = Task(scenario)
    data = SearchData(task)
    planner = HandConfigPlanner(task, "right-right", data=data)
    nodes = planner.graph_spec().placement_nodes
    probes = probe_grasps(task, data, nodes)
    closing = [n for n in nodes if n in data.node_cache and data.node_cache[n].detail == "closing the jaw"]
    passed = [n for n in nodes if probes[n].q is not None and n not in data.node_cache]
    assert len(closing) >= 10 and len(passed) >= 10
    for node in closing[:12]:
        cached = data.node_cache.pop(node)
        v = validate_placement(task, data, node, np.random.default_rng(task.node_seed(node)))
        assert (v.ok, v.cause, v.detail) == (False, cached.cause, "closing the jaw")
        assert v.margin_m == pytest.approx(cached.margin_m, abs=1e-9)
    for node in passed[:12]:
        v = validate_placement(task, data, node, np.random.default_rng(task.node_seed(node)))
        assert v.ok or v.detail != "closing the jaw", node


def test_a_search_reaching_a_node_the_arm_alone_missed_probes_all_such_nodes_with_the_waist(scenario):
    """Nodes whose batched arm-only probe missed come last in the search. When a validation first
    reaches one, every such node of that hand is probed at once with the waist helping: a posture
    found reaches the grasp within the IK tolerance and the joint limits, its margin is the one of
    holding the object there (recomputed through pinocchio), a margin failure is cached with the
    verdict the node's own validation reaches, and the validation starts from that posture."""
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.task import Task
    task = Task(scenario)
    data = SearchData(task)
    planner = HandConfigPlanner(task, "right-right", data=data)
    nodes = planner.graph_spec().placement_nodes
    probes = probe_grasps(task, data, nodes)
    missed = [n for n in nodes if probes[n].q is None and n not in data.node_cache]
    assert len(missed) >= 10
    planner.validate_node(missed[0])
    assert set(missed) <= data.waist_probed
    reached = [n for n in missed if data.grasp_probes[n].q is not None]
    assert len(reached) >= 5, "the waist reached none of the grasps the arm alone missed"
    waist = task.robot.waist_indices()
    moved = 0
    for node in reached:
        q, margin = data.grasp_probes[node].q, data.grasp_probes[node].margin_m
        assert np.all(q >= task.robot.lower - 1e-9) and np.all(q <= task.robot.upper + 1e-9)
        moved += bool(np.any(np.abs(q[waist] - task.home[waist]) > 1e-6))
        grasp = task.grasps["right"][node.grasp]
        T_obj = task.placements[node.placement]
        T = task.tcp(q, "right")
        assert np.linalg.norm(T[:3, 3] - (T_obj @ grasp.T_obj_tcp)[:3, 3]) <= task.settings.ik.pos_tol_m + 1e-9
        closed = q.copy()
        closed[task.jaw["right"]] = grasp.jaw_value
        robot_com = task.evaluator.evaluate_one(closed).robot_com
        assert margin == pytest.approx(float(task.evaluator.with_object(robot_com[None], T_obj[None]).margin[0]), abs=1e-9)
    assert moved >= 1  # the waist did help
    cached = [n for n in reached if n in data.node_cache and data.node_cache[n].cause == "com_margin"]
    fresh = [n for n in reached if n not in data.node_cache]
    assert cached and fresh
    for node in cached[:8]:
        verdict = data.node_cache.pop(node)
        v = validate_placement(task, data, node, np.random.default_rng(task.node_seed(node)))
        assert (v.ok, v.cause, v.detail) == (False, verdict.cause, verdict.detail)
    started = 0
    for node in fresh[:8]:
        v = validate_placement(task, data, node, np.random.default_rng(task.node_seed(node)))
        if v.ok:  # the key poses start from the probed posture
            assert np.array_equal(v.payload.q_grasp_open[waist], data.grasp_probes[node].q[waist])
            started += 1
    assert started >= 1
    # A survey worker hands this over: another copy of the task, whose arm-only probes missed the same
    # nodes, takes the waist's postures and does not probe them again.
    other = Task(scenario)
    other_data = SearchData(other)
    probe_grasps(other, other_data, nodes)
    other_data.adopt(data.validations())
    assert set(missed) <= other_data.waist_probed
    assert all(np.array_equal(other_data.grasp_probes[n].q, data.grasp_probes[n].q) for n in reached)


def test_nodes_known_to_fail_leave_the_graph_before_the_search_and_are_counted(scenario):
    """What the probes (or another hand configuration) already proved invalid is removed up front, so
    the search spends no iteration on it; the removals are counted by cause like the screening's."""
    from planner.regrasp.graph import RegraspGraph
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.task import Task
    task = Task(scenario)
    data = SearchData(task)
    planner = HandConfigPlanner(task, "right-left", data=data)
    graph = RegraspGraph(planner.graph_spec(), task.settings.weights)
    planner._weigh_nodes(graph)
    known = {n for n in graph.nodes() if n in data.node_cache and not data.node_cache[n].ok}
    givers = {n for n in graph.nodes() if getattr(n, "pose", None) is not None
              and (data.giver_at.get((n.pose, n.giver_grasp, n.giver)) or (None, None, None))[2] is not None}
    assert len(known) >= 10 and len(givers) >= 10
    before = sum(planner.screen_failures.values())
    planner._drop_known_failures(graph)
    alive = set(graph.nodes())
    assert not (known | givers) & alive
    assert sum(planner.screen_failures.values()) - before == len(known | givers)
    # everything else is still there for the search
    assert all(n in alive for n in planner.graph_spec().placement_nodes if n not in data.node_cache)
