"""The task stability survey: the paper's RRT-inspired stability ratio per hand configuration.

For each hand configuration the regrasp graph gives the task's key poses (its nodes
are validated: IK, collision, CoM margin; motions are not planned, which the
exploration itself does). Every stretch where the object is carried becomes an
exploration leg: from the pick (lift pose) towards the place (lift pose), or to and
from the handover pose for ``left-right`` and ``right-left``. The goal-biased
energy-based exploration (:func:`planner.motion.trrt.explore`) then evaluates states until
N have been counted: C stable, U unstable, R = C / (C + U) (the paper's equation 2).

Configurations run in parallel in worker processes; each has its own seeded
generator, so the same seed gives the same counts however they are scheduled.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from planner.errors import Canceled as GraphCanceled
from planner.errors import Canceled as SurveyCanceled
from planner.forking import pool_context, pool_may_fork, spare_cores
from planner.motion.trrt import ExploreLeg, TrrtSettings, explore
from planner.regrasp.graph import HandoverNode, PlacementNode, Validation
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.path_assembly import carried
from planner.regrasp.settings import HANDS_OF, PlannerSettings
from planner.regrasp.task import Task
from planner.stability.evaluator import HoldSpec
from planner.survey import limits as survey_limits
from planner.termination import Termination
from schemas.common import HAND_CONFIGS
from schemas.scenario import Scenario
from schemas.survey import SURVEY_SCHEMA, TIE_ORDER, SurveyRow, recommend

#: Default states per configuration when neither the request nor the scenario says.
DEFAULT_STATES = 10_000
#: Node-search effort to find a configuration's key poses.
KEY_POSE_ITERATIONS = 400


@dataclass
class ConfigOutcome:
    hands: str
    stable: int
    unstable: int
    reason: str | None
    stats: dict
    q: np.ndarray | None = None
    holding: np.ndarray | None = None
    object_pose: np.ndarray | None = None
    stable_flags: np.ndarray | None = None
    com: np.ndarray | None = None
    #: counted poses over an effort or grip limit (None: limits off)
    over_limits: int | None = None

    @property
    def ratio(self) -> float | None:
        total = self.stable + self.unstable
        return self.stable / total if total else None


def _legs(planner: HandConfigPlanner, path: list) -> list[ExploreLeg]:
    """One exploration leg per carried stretch of the key-pose path."""
    t = planner.task
    legs: list[ExploreLeg] = []
    for a, b in zip(path[:-1], path[1:]):
        if not carried(a, b):
            continue
        if isinstance(a, PlacementNode) and isinstance(b, PlacementNode):
            ka, kb = planner.keyposes[a], planner.keyposes[b]
            goal = planner.motions.with_arm_of(kb.q_lift, ka.q_lift, a.hand)
            legs.append(ExploreLeg(ka.q_lift, goal, HoldSpec(a.hand, ka.T_obj_tcp), t.active[a.hand]))
        elif isinstance(b, HandoverNode):
            ka, hp = planner.keyposes[a], planner.handovers[b]
            legs.append(ExploreLeg(ka.q_lift, hp.q_giver_at, HoldSpec(a.hand, ka.T_obj_tcp), t.active[a.hand]))
        else:
            hp, kb = planner.handovers[a], planner.keyposes[b]
            goal = planner.motions.with_arm_of(kb.q_lift, hp.q_after, b.hand)
            legs.append(ExploreLeg(hp.q_after, goal, HoldSpec(b.hand, hp.T_taker_obj_tcp), t.active[b.hand]))
    return legs


def key_path(planner: HandConfigPlanner, should_stop: Callable[[], bool]) -> tuple[list | None, str | None]:
    """The cheapest path whose nodes are valid (motions not planned), or the reason there is none."""
    from planner.regrasp.graph import RegraspGraph

    termination = Termination(KEY_POSE_ITERATIONS, planner.task.scenario.limits.time_s, should_stop)
    graph = RegraspGraph(planner.screen(planner.graph_spec(), termination, want=1), planner.task.settings.weights)
    planner.prepare_search(graph)
    res = graph.search(planner.validate_node, lambda a, b, k: Validation(True), termination)
    if res.status != "solved":
        return None, f"{res.code}: {res.message}"
    return res.path, None


def survey_configuration(task: Task, hands: str, states: int, seed: int | list[int],
                         should_stop: Callable[[], bool] = lambda: False, keep_states: bool = True):
    """Explore one hand configuration and count its stable and unstable states.

    With a list of seeds, the key poses are found once (with the first seed) and the
    exploration runs once per seed; a list of outcomes is returned.
    """
    seeds = [seed] if isinstance(seed, int) else list(seed)
    t0 = time.perf_counter()
    planner = HandConfigPlanner(task, hands)
    try:
        path, reason = key_path(planner, should_stop)
    except GraphCanceled:
        raise SurveyCanceled() from None
    t1 = time.perf_counter()
    outcomes = []
    legs: list[ExploreLeg] = []
    if path is not None:
        legs = _legs(planner, path)
    for sd in seeds:
        if path is None:
            outcomes.append(ConfigOutcome(hands, 0, 0, f"no feasible grasp or key poses: {reason}", {"time_s": t1 - t0}))
            continue
        if not legs:
            outcomes.append(ConfigOutcome(hands, 0, 0, "the key-pose path carries the object nowhere", {"time_s": t1 - t0}))
            continue
        outcomes.append(_explore(task, hands, legs, states, sd, path, t1 - t0, should_stop, keep_states))
    return outcomes[0] if isinstance(seed, int) else outcomes


def _explore(task: Task, hands: str, legs: list[ExploreLeg], states: int, seed: int, path: list, key_poses_s: float,
             should_stop: Callable[[], bool], keep_states: bool) -> ConfigOutcome:
    evaluator = task.evaluator.with_threshold(task.threshold_m)
    # LIMITS HOOK (planner.survey.limits): a pose over an effort or grip limit counts as unstable, and the
    # recorded ones over a limit are the row's over_limits (below).
    evaluator = survey_limits.limited(task, evaluator)
    checked = []
    for leg in legs:
        held = [(leg.hold.tcp_side, leg.hold.T_obj_tcp)]

        def free(Q: np.ndarray, held=held) -> np.ndarray:
            return ~task.world.check_batch(task.stance.base_pose, Q, held=held).collides

        checked.append(ExploreLeg(leg.start, leg.goal, leg.hold, leg.active, free))
    rng = np.random.default_rng([seed, HAND_CONFIGS.index(hands), 11])
    t1 = time.perf_counter()
    ex = explore(checked, evaluator, None, states, rng, TrrtSettings(margin_cost=task.constrained), should_stop=should_stop)
    if ex.status == "canceled":
        raise SurveyCanceled()
    elapsed = time.perf_counter() - t1
    stats = dict(ex.stats, key_poses_s=key_poses_s, exploration_s=elapsed, seed=seed,
                 states_per_s=ex.stats["evaluated"] / max(elapsed, 1e-9),
                 path=[_node_label(n) for n in path], status=ex.status)
    out = ConfigOutcome(hands, ex.n_stable, ex.n_unstable, None, stats)
    out.over_limits = survey_limits.over_limits(task, ex.q, ex.holding, ex.object_pose)  # LIMITS HOOK
    if ex.status != "done":
        out.reason = f"exploration stopped early ({ex.status}) after {ex.stats['evaluated']} states"
    if keep_states:
        out.q, out.holding, out.object_pose, out.stable_flags, out.com = ex.q, ex.holding, ex.object_pose, ex.stable, ex.com
    return out


def _node_label(n) -> str:
    if isinstance(n, PlacementNode):
        return f"placement {n.placement} grasp {n.grasp} {n.hand}"
    return f"handover pose {n.pose} grasps {n.giver_grasp}->{n.taker_grasp}"


# -- worker processes ---------------------------------------------------------------------------
_WORKER_TASKS: dict[str, Task] = {}


def _task_key(scenario_json: str, threshold_m: float, settings_json: str) -> str:
    return f"{scenario_json}|{threshold_m}|{settings_json}"


#: The configurations that pick and place with the same hand.
SINGLE_ARM = tuple(h for h, (pick, place) in HANDS_OF.items() if pick == place)


def _rounds(configs: list[str], n_workers: int) -> list[list[int]]:
    """The configurations (indices) each round runs, one pool task each; a round starts when the one
    before it has ended, from everything the earlier rounds worked out (sent to its workers).

    With a worker per configuration, one round, dual-arm configurations (the longest: handover key
    poses) submitted first. With fewer, the single-arm configurations first, then the dual-arm ones:
    a dual-arm configuration probes the grasps of both hands, and after the first round both are
    known (with chains by picking hand, each worker probed the other hand's grasps again: measured
    0.3-0.6 s per worker). The one-process survey runs the same order, so each configuration starts
    from the same probes and key poses in any process layout.
    """
    if n_workers >= len(configs):
        return [sorted(range(len(configs)), key=lambda k: (configs[k] in SINGLE_ARM, k))]
    rounds = []
    for single in (True, False):
        mine = [k for k in range(len(configs)) if (configs[k] in SINGLE_ARM) == single]
        while mine:  # at most two of each kind: more only if a caller repeats a configuration
            rounds.append(mine[:n_workers])
            mine = mine[n_workers:]
    return rounds


def _skipped(hands: str, done: dict[int, list[ConfigOutcome]], states: int) -> list[ConfigOutcome] | None:
    """The outcome (one seed) of a configuration not surveyed because one already surveyed (``done``:
    outcomes by configuration index) outranks it (:func:`_outranked`), or None: survey it."""
    why = _outranked(hands, [o[0] for o in done.values()], states)
    return [ConfigOutcome(hands, 0, 0, why, {})] if why else None


def _outranked(hands: str, done: list[ConfigOutcome], states: int) -> str | None:
    """Why ``hands`` cannot be recommended over a configuration already surveyed, or None.

    A configuration whose every state was stable (R = 1, C = N) can at best be tied, and a tie
    goes to the one earlier in the contract's order (:func:`schemas.survey.recommend`): the
    configurations after it need no survey when only the recommendation is wanted."""
    for o in sorted(done, key=lambda o: TIE_ORDER.index(o.hands)):
        if (o.reason is None and o.unstable == 0 and o.stable == states
                and TIE_ORDER.index(o.hands) < TIE_ORDER.index(hands)):
            return (f"not surveyed: {o.hands} had all {states} states stable (R = 1), which {hands} "
                    f"could at best tie, and a tie goes to {o.hands}")
    return None


def _serial_order(configs: list[str]) -> list[int]:
    """The one-process survey's order: the order of :func:`_rounds`."""
    return [k for rnd in _rounds(configs, 1) for k in rnd]


def _worker(args: tuple) -> tuple[list[ConfigOutcome], dict]:
    """Run one configuration (see :func:`_rounds`) after adopting what earlier rounds found: one
    outcome per seed, and what the worker's task worked out (:meth:`Task.validations`), which the
    parent's adopts."""
    scenario_json, threshold_m, hands, states, seeds, settings_json, known, then_handover_poses = args
    key = _task_key(scenario_json, threshold_m, settings_json)
    task = _WORKER_TASKS.get(key)
    if task is None:
        scenario = Scenario.model_validate_json(scenario_json)
        settings = PlannerSettings.model_validate_json(settings_json) if settings_json else None
        task = Task(scenario, settings, threshold_m=threshold_m)
        _WORKER_TASKS.clear()
        _WORKER_TASKS[key] = task
    if known is not None:
        task.adopt(known)
    outcomes = survey_configuration(task, hands, states, list(seeds))
    if then_handover_poses:
        task.handover_poses  # noqa: B018 - computed here once for the next round's workers (0.3-0.8 s each)
    return outcomes, task.validations()


def run_survey(
    scenario: Scenario,
    *,
    states: int | None = None,
    seed: int | None = None,
    threshold_m: float | None = None,
    hands: list[str] | None = None,
    workers: int | None = None,
    settings: PlannerSettings | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    progress: Callable[[float, str], None] = lambda f, m: None,
    task: Task | None = None,
    recommendation_only: bool = False,
) -> tuple[dict[str, Any], list[ConfigOutcome]]:
    """The survey document (CONTRACT.md section 4) and the per-configuration outcomes (with states).

    With ``recommendation_only``, a configuration that cannot be recommended over one already
    surveyed (:func:`_outranked`) is not surveyed: its row has no ratio and says why."""
    docs = run_survey_seeds(scenario, [scenario.seed if seed is None else seed], states=states, threshold_m=threshold_m,
                            hands=hands, workers=workers, settings=settings, should_stop=should_stop, progress=progress,
                            task=task, recommendation_only=recommendation_only)
    return docs[0]


def run_survey_seeds(
    scenario: Scenario,
    seeds: list[int],
    *,
    states: int | None = None,
    threshold_m: float | None = None,
    hands: list[str] | None = None,
    workers: int | None = None,
    settings: PlannerSettings | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    progress: Callable[[float, str], None] = lambda f, m: None,
    task: Task | None = None,
    recommendation_only: bool = False,
) -> list[tuple[dict[str, Any], list[ConfigOutcome]]]:
    """One survey per seed; key poses are found once per configuration and shared by the seeds."""
    t0 = time.perf_counter()
    if recommendation_only and len(seeds) != 1:
        raise ValueError("recommendation_only needs exactly one seed: the seeds could recommend differently")
    if states is None:
        states = scenario.survey.states_per_configuration or DEFAULT_STATES
    if states < 1:
        raise ValueError(f"states per configuration must be >= 1, got {states}")
    threshold = scenario.threshold_m if threshold_m is None else threshold_m
    configs = hands or list(HAND_CONFIGS)
    for h in configs:
        if h not in HAND_CONFIGS:
            raise ValueError(f"unknown hands {h!r}; valid: {', '.join(HAND_CONFIGS)}")
    task = task or Task(scenario, settings, threshold_m=threshold)
    inradius = task.stance.polygon.inradius
    outcomes: list[ConfigOutcome]
    if threshold > inradius:
        reason = (f"threshold {threshold * 1000:.1f} mm is larger than the support polygon's inradius "
                  f"{inradius * 1000:.1f} mm in stance {task.stance.name!r}: no state can be stable")
        per_config = [[ConfigOutcome(h, 0, 0, reason, {}) for _ in seeds] for h in configs]
    else:
        n_workers = min(len(configs), workers if workers is not None else (os.cpu_count() or 1))
        progress(0.05, f"exploring {len(configs)} hand configurations, {states} states each")
        if n_workers <= 1:
            by_index: dict[int, list[ConfigOutcome]] = {}
            for k in _serial_order(configs):
                skip = _skipped(configs[k], by_index, states) if recommendation_only else None
                by_index[k] = skip or survey_configuration(task, configs[k], states, list(seeds), should_stop)
                progress(0.05 + 0.9 * len(by_index) / len(configs), f"{configs[k]} done")
            per_config = [by_index[k] for k in range(len(configs))]
        else:
            sc_json = scenario.model_dump_json(by_alias=True)
            st_json = settings.model_dump_json() if settings is not None else ""
            context = pool_context()
            if context.get_start_method() == "fork":
                # Forked workers inherit the imported modules and this task: no start-up cost.
                _WORKER_TASKS.clear()
                _WORKER_TASKS[_task_key(sc_json, threshold, st_json)] = task
            results: dict[int, list[ConfigOutcome]] = {}
            try:
                with ProcessPoolExecutor(max_workers=n_workers, mp_context=context) as pool:
                    rounds = _rounds(configs, n_workers)
                    for r, ks in enumerate(rounds):
                        if recommendation_only:
                            skipped = {k: _skipped(configs[k], results, states) for k in ks}
                            results.update({k: out for k, out in skipped.items() if out})
                            ks = [k for k in ks if k not in results]
                            if not ks:
                                continue  # nothing left to send this round's workers
                        # A later round starts from what the earlier ones found (sent along: the
                        # workers were forked before the parent adopted it). The first task of a
                        # round before a dual-arm one also works out the handover poses, which
                        # every dual-arm configuration needs.
                        known = task.validations() if r else None
                        poses_next = any(configs[k] not in SINGLE_ARM for later in rounds[r + 1:] for k in later)
                        futures = {k: pool.submit(_worker, (sc_json, threshold, configs[k], states, list(seeds), st_json,
                                                            known, poses_next and i == 0))
                                   for i, k in enumerate(ks)}
                        pending = set(futures.values())
                        while pending:
                            finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                            for k, f in futures.items():
                                if f in finished:
                                    results[k], validations = f.result()
                                    task.adopt(validations)
                                    progress(0.05 + 0.9 * len(results) / len(configs), f"{configs[k]} done")
                            if pending and should_stop():
                                for g in pending:
                                    g.cancel()
                                # The pool forgets its processes when shut down: take them first.
                                procs = list((getattr(pool, "_processes", None) or {}).values())
                                pool.shutdown(wait=False, cancel_futures=True)
                                for proc in procs:
                                    proc.kill()
                                raise SurveyCanceled() from None
                    per_config = [results[k] for k in range(len(configs))]
            finally:
                _WORKER_TASKS.clear()  # the parent keeps no task alive once its workers are gone
    docs = []
    for i, seed in enumerate(seeds):
        outcomes = [pc[i] for pc in per_config]
        rows = [SurveyRow(hands=o.hands, stable=o.stable, unstable=o.unstable, ratio=o.ratio, reason=o.reason,
                          over_limits=o.over_limits) for o in outcomes]
        doc = {
            "schema": SURVEY_SCHEMA,
            "robot": {"name": task.robot.name, "urdf_sha256": task.robot.urdf_sha256},
            "stance": task.stance.result().model_dump(),
            "threshold_m": threshold,
            "seed": seed,
            "object": {"name": task.obj.name, "mass_kg": task.obj.mass_kg, "com_local": task.obj.com_local.tolist(),
                       "start_pose": list(scenario.start_pose), "goal_pose": list(scenario.goal_pose)},
            "rows": [r.model_dump(exclude_none=False) for r in rows],
            "recommended": recommend(rows),
            "stats": {"states_per_configuration": states, "time_s": time.perf_counter() - t0,
                      "support_polygon": task.stance.polygon.vertices.tolist(),
                      "configurations": {o.hands: o.stats for o in outcomes}},
        }
        docs.append((doc, outcomes))
    return docs


def write_states(path: str, doc: dict, outcomes: list[ConfigOutcome], task_info: dict) -> int:
    """Every evaluated state as an .npz (no pickled objects): CONTRACT.md section 4."""
    parts = [o for o in outcomes if o.q is not None and len(o.q)]
    nq = len(task_info["joint_names"])
    if parts:
        hands = np.concatenate([np.full(len(o.q), o.hands) for o in parts]).astype("U11")
        q = np.vstack([o.q for o in parts])
        holding = np.concatenate([o.holding for o in parts]).astype("U5")
        pose = np.vstack([o.object_pose for o in parts])
        stable = np.concatenate([o.stable_flags for o in parts]).astype(bool)
    else:
        hands, q, holding, pose, stable = np.zeros(0, "U11"), np.zeros((0, nq)), np.zeros(0, "U5"), np.zeros((0, 7)), np.zeros(0, bool)
    np.savez_compressed(
        path, hands=hands, q=q, holding=holding, object_pose=pose, stable=stable,
        base_pose=np.asarray(doc["stance"]["base_pose"]), joint_names=np.asarray(task_info["joint_names"], dtype="U16"),
        threshold_m=np.float64(doc["threshold_m"]), mass_kg=np.float64(doc["object"]["mass_kg"]),
        com_local=np.asarray(doc["object"]["com_local"]), support_polygon=np.asarray(doc["stats"]["support_polygon"]),
    )
    return len(q)


def quick_survey(task: Task, should_stop: Callable[[], bool] = lambda: False, states: int = 1500) -> dict:
    """A small survey, for ``--hands auto``: in forked workers where forking is safe and there is
    more than one core (the task is inherited, and the workers' node validations come back for the
    plan that follows), in this process otherwise (a spawned worker's start-up costs more than it
    saves on this survey's size)."""
    parallel = spare_cores() > 0 and pool_may_fork()
    doc, _ = run_survey(task.scenario, states=states, threshold_m=task.threshold_m, workers=2 if parallel else 1,
                        task=task, should_stop=should_stop, recommendation_only=True)
    return doc


def run_survey_request(request: dict[str, Any], ctx) -> dict[str, Any]:
    """The service's survey job (CONTRACT.md section 5)."""
    from planner.scene.scenarios import resolve_scenario

    scenario = resolve_scenario(request["scenario"], stance=request.get("stance"), threshold_m=request.get("threshold_m"),
                                seed=request.get("seed"), states_per_configuration=request.get("states_per_configuration"),
                                time_limit_s=request.get("time_limit_s"))
    doc, _ = run_survey(scenario, workers=1, should_stop=lambda: bool(ctx.cancelled()), progress=ctx.progress)
    return doc
