"""The task stability survey: the paper's stability ratio R per hand configuration, with its interval.

For each hand configuration the regrasp graph gives the task's key poses (its nodes are
validated: IK, collision, CoM margin; motions are not planned, which the exploration itself
does). Every stretch where the object is carried becomes an exploration leg: from the pick
(lift pose) towards the place (lift pose), or to and from the handover pose for ``left-right``
and ``right-left``. Each seed explores the legs with the paper's goal-biased, constrained
T-RRT and counts each sampled pose once (:mod:`planner.survey.counting`); seeds repeat until
every row's interval is tight (:mod:`planner.survey.estimator`). R = C / (C + U), the paper's
equation 2, pooled over the seeds.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import wait
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from threadpoolctl import ThreadpoolController

from planner.blas_threads import one_blas_thread, one_thread
from planner.errors import Canceled
from planner.forking import pool_may_fork
from planner.motion.trrt import TrrtSettings
from planner.regrasp.graph import HandoverNode, PlacementNode, RegraspGraph, Validation
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.path_assembly import carried
from planner.regrasp.settings import HANDS_OF, PlannerSettings
from planner.regrasp.search_data import SearchData
from planner.regrasp.seed_free import SeedFreeResults
from planner.regrasp.task import Task
from planner.stability.evaluator import HoldSpec
from planner.survey import limits as survey_limits
from planner.survey.counting import CountingSettings, ExploreLeg
from planner.survey.estimator import Estimator, RowWork, SeedCount, run_rows
from planner.survey.key_paths import KeyPathDraw, node_id, pool_seeds, task_for_seed
from planner.survey.seed_map import ForkedSeeds, SeedMap
from planner.survey.shared_checks import HeldCollisions
from planner.termination import Termination, never
from schemas.common import HAND_CONFIGS
from schemas.scenario import Scenario
from schemas.survey import SURVEY_SCHEMA, SurveyRow, indistinguishable, recommend

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
    #: counted poses over an effort or grip limit, summed over the judged seeds (None: limits off)
    over_limits: int | None = None
    seed: np.ndarray | None = None
    interval: list[float] | None = None
    converged: bool = False
    per_seed: list = field(default_factory=list)

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


def key_pose_termination(task: Task, should_stop: Callable[[], bool]) -> Termination:
    """The key-pose search's termination: its own iteration cap, the scenario's time budget (if any), the cancel."""
    return Termination.of_limits(task.scenario.limits, should_stop).with_iterations(KEY_POSE_ITERATIONS)


def key_path(planner: HandConfigPlanner) -> tuple[list | None, str | None]:
    """The cheapest path whose nodes are valid (motions not planned), or the reason there is none; the
    search stops on the planner's termination (:func:`key_pose_termination`)."""
    graph = RegraspGraph(planner.screen(planner.graph_spec(), want=1), planner.task.settings.weights)
    planner.prepare_search(graph)
    res = graph.search(planner.validate_node, lambda a, b, k: Validation(True), planner.termination)
    if res.status != "solved":
        return None, f"{res.code}: {res.message}"
    return res.path, None


def _node_label(n) -> str:
    if isinstance(n, PlacementNode):
        return f"placement {n.placement} grasp {n.grasp} {n.hand}"
    return f"handover pose {n.pose} grasps {n.giver_grasp}->{n.taker_grasp}"


def _node_label_of(ids: dict) -> str:
    """:func:`_node_label` of a node given by its ids (:func:`planner.survey.key_paths.node_id`)."""
    if "placement" in ids:
        return f"placement {ids['placement']} grasp {ids['grasp']} {ids['hand']}"
    return f"handover pose {ids['handover_pose']} grasps {ids['giver_grasp']}->{ids['taker_grasp']}"


#: The configurations that pick and place with the same hand.
SINGLE_ARM = tuple(h for h, (pick, place) in HANDS_OF.items() if pick == place)


def estimator_of(scenario: Scenario, states: int | None = None) -> Estimator:
    """The scenario's estimator (its ``survey:`` field); ``states`` asks for ``until: states`` instead."""
    sv = scenario.survey
    est = Estimator(until=sv.until, ci_half_width=sv.ci_half_width, seeds_min=sv.seeds_min, seeds_max=sv.seeds_max,
                    states_per_seed=sv.states_per_seed, leg_cap_states=sv.leg_cap_states, key_paths=sv.key_paths,
                    key_path_pool=sv.key_path_pool)
    if states is not None:
        if states < 1:
            raise ValueError(f"states per seed must be >= 1, got {states}")
        est = est.model_copy(update={"until": "states", "states_per_seed": states})
    return est


def _leg_collisions(task: Task, leg: ExploreLeg) -> ExploreLeg:
    """The leg with this task's collision check for what it holds (the held object differs per leg)."""
    return ExploreLeg(leg.start, leg.goal, leg.hold, leg.active,
                      HeldCollisions(task.world, np.asarray(task.stance.base_pose, dtype=float), leg.hold))


class RemoteSeeds:
    """The survey's per-seed function for a seed map on other machines: picklable, it carries the
    scenario and the legs (not the built task) and builds the task once per worker process that runs it."""

    def __init__(self, task: Task, rows: list[RowWork], estimator: Estimator, counting: CountingSettings | None,
                 trrt: TrrtSettings, threshold_m: float, base_seed: int) -> None:
        self.scenario, self.settings = task.scenario, task.settings
        self.task_threshold_m, self.threshold_m, self.seed = task.threshold_m, threshold_m, task.seed
        self.base_seed = base_seed
        self.rows = {r.hands: RowWork(r.hands, [[ExploreLeg(g.start, g.goal, g.hold, g.active) for g in member]
                                                for member in r.legs], key_paths=list(r.key_paths))
                     for r in rows if r.legs}
        self.estimator, self.counting, self.trrt = estimator, counting, trrt
        self._built: tuple[ThreadpoolController, Any, dict[str, RowWork]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        return dict(self.__dict__, _built=None)

    def __call__(self, hands: str, seed: int, keep_states: bool) -> SeedCount:
        if self._built is None:
            blas = ThreadpoolController()  # the BLAS libraries found once per worker process, not once per seed
            with one_thread(blas):
                task = Task(self.scenario, self.settings, threshold_m=self.task_threshold_m, seed=self.seed)
                evaluator = survey_limits.limited(task, task.evaluator.with_threshold(self.threshold_m))
                rows = {h: RowWork(h, [[_leg_collisions(task, g) for g in member] for member in r.legs],
                                   key_paths=r.key_paths) for h, r in self.rows.items()}
            self._built = blas, evaluator, rows
        blas, evaluator, rows = self._built
        with one_thread(blas):
            return rows[hands].explore(evaluator, seed, self.base_seed, self.estimator, settings=self.counting,
                                       trrt=self.trrt, keep_states=keep_states)


def draw_key_path(task: Task, data: SearchData, hands: str, kp_seed: int,
                  should_stop: Callable[[], bool] = never) -> KeyPathDraw:
    """The planner's key path for ``hands`` with ``task`` (seeded ``kp_seed``: :func:`task_for_seed`) and its
    search's scratch ``data``, and the legs it carries the object on."""
    t0 = time.perf_counter()
    planner = HandConfigPlanner(task, hands, key_pose_termination(task, should_stop), data=data)
    path, reason = key_path(planner)
    if path is None:
        return KeyPathDraw(hands, kp_seed, None, reason=f"no feasible grasp or key poses: {reason}",
                           time_s=time.perf_counter() - t0)
    legs = [ExploreLeg(g.start, g.goal, g.hold, g.active) for g in _legs(planner, path)]
    return KeyPathDraw(hands, kp_seed, [node_id(n) for n in path], legs,
                       None if legs else "the key-pose path carries the object nowhere", time.perf_counter() - t0)


def draw_seed(task: Task, configs: list[str], kp_seed: int, should_stop: Callable[[], bool] = never,
              data: SearchData | None = None, seed_free: SeedFreeResults | None = None) -> dict[str, KeyPathDraw]:
    """The planner's key path of each configuration at one key-path seed: a pure function of (task, configurations,
    key-path seed). As a plan's search does, the configurations share one search scratch (``data``, the run's
    own at the task's seed, else a fresh one), single-arm ones first (a dual-arm one then finds both hands'
    grasps probed). ``seed_free`` shares the seed-free steps' results with the pool's other key-path seeds
    (:mod:`planner.regrasp.seed_free`: the same draws, computed once)."""
    t = task_for_seed(task, kp_seed)
    d = data if data is not None and t is task else SearchData(t, seed_free)
    order = sorted(configs, key=lambda h: (h not in SINGLE_ARM, configs.index(h)))
    own = d.seed_free
    if own is None:
        d.seed_free = seed_free
    try:
        return {h: draw_key_path(t, d, h, kp_seed, should_stop) for h in order}
    finally:
        d.seed_free = own


def draw_pools(task: Task, configs: list[str], estimator: Estimator, *, workers: int, can_fork: bool,
               should_stop: Callable[[], bool], data: SearchData | None = None) -> dict[str, list[KeyPathDraw]]:
    """Every row's pool of key paths (:mod:`planner.survey.key_paths`), one key-path seed per job, in forked
    workers where forking is safe; the draws are the same either way."""
    seeds = pool_seeds(estimator.key_path_pool)
    by_seed: dict[int, dict[str, KeyPathDraw]] = {}
    # The draws' seed-free steps are computed once per process (planner.regrasp.seed_free). The first draw
    # runs here and fills them; forked workers, started after it, inherit them for the other seeds. The
    # task's own seed is drawn here when it is in the pool, so its validations stay with the task (a plan
    # after the survey reuses them).
    seed_free = SeedFreeResults()
    first = task.seed if task.seed in seeds else seeds[0]
    if should_stop():
        raise Canceled()
    by_seed[first] = draw_seed(task, configs, first, should_stop, data, seed_free)
    rest = [k for k in seeds if k != first]
    if workers > 1 and can_fork and len(rest) > 1:
        session = ForkedSeeds(min(workers, len(rest))).open(
            lambda _hands, kp_seed, _keep: draw_seed(task, configs, kp_seed, seed_free=seed_free))
        canceled = True
        try:
            futures = {session.submit("", k, False): k for k in rest}
            for f, k in futures.items():
                while not f.done():
                    if should_stop():
                        raise Canceled()
                    wait([f], timeout=0.2)
                by_seed[k] = f.result()
            canceled = False
        finally:
            session.close(cancel=canceled)
    else:
        for k in rest:
            if should_stop():
                raise Canceled()
            by_seed[k] = draw_seed(task, configs, k, should_stop, data, seed_free)
    return {h: [by_seed[k][h] for k in seeds] for h in configs}


def _row_work(task: Task, hands: str, pool: list[KeyPathDraw]) -> RowWork:
    """A configuration's pool of legs (the draws that found a key path), with this task's collision checks."""
    found = [d for d in pool if d.ok]
    stats = {"key_poses_s": sum(d.time_s for d in pool), "key_path_seeds": [d.seed for d in pool],
             "key_paths_found": len(found), "distinct_key_paths": len({repr(d.nodes) for d in found})}
    if not found:
        return RowWork(hands, None, pool[0].reason if pool else "no key path drawn", stats)
    stats["path"] = [_node_label_of(n) for n in found[0].nodes]
    legs = [[_leg_collisions(task, g) for g in d.legs] for d in found]
    return RowWork(hands, legs, None, stats, key_paths=[d.label() for d in found])


def _outcome(r: RowWork, estimator: Estimator, keep_states: bool) -> ConfigOutcome:
    v = r.verdict
    counts = r.counts[: v.seeds] if v is not None else []
    stats = dict(r.stats, seeds=len(counts), exploration_s=sum(c.time_s for c in counts),
                 states_per_s=sum(c.stable + c.unstable for c in counts) / max(sum(c.time_s for c in counts), 1e-9),
                 evaluated=sum(c.stable + c.unstable for c in counts),
                 solved_seeds=sum(c.solved for c in counts), statuses=sorted({c.status for c in counts}),
                 rejected={"collision": sum(leg["collisions"] for c in counts for leg in c.legs), "joint_limits": 0},
                 legs_per_seed=[[{k: leg[k] for k in ("counted", "stable", "unstable", "solved", "nodes", "repeats")}
                                 for leg in c.legs] for c in counts])
    out = ConfigOutcome(r.hands, v.stable if v else 0, v.unstable if v else 0, r.reason, stats,
                        interval=list(v.interval) if v and v.interval else None, converged=bool(v and v.converged),
                        per_seed=[c.entry() for c in counts],
                        over_limits=(None if not counts or any(c.over_limits is None for c in counts)
                                     else sum(c.over_limits for c in counts)))
    if r.reason is None and v is not None and v.stable + v.unstable == 0:
        out.reason = "no state was counted (every sampled pose collided)"
    if keep_states and counts and all(c.states is not None for c in counts):
        parts = [c.states for c in counts]
        out.q = np.vstack([p.q for p in parts])
        out.holding = np.concatenate([p.holding for p in parts])
        out.object_pose = np.vstack([p.object_pose for p in parts])
        out.stable_flags = np.concatenate([p.stable for p in parts])
        out.com = np.vstack([p.com for p in parts])
        out.seed = np.concatenate([np.full(len(p.stable), c.seed) for p, c in zip(parts, counts)])
    return out


@one_blas_thread
def run_survey(
    scenario: Scenario,
    *,
    estimator: Estimator | None = None,
    states: int | None = None,
    seed: int | None = None,
    threshold_m: float | None = None,
    hands: list[str] | None = None,
    workers: int | None = None,
    settings: PlannerSettings | None = None,
    should_stop: Callable[[], bool] = never,
    progress: Callable[[float, str], None] = lambda f, m: None,
    task: Task | None = None,
    data: SearchData | None = None,
    keep_states: bool = True,
    no_limits: bool = False,
    counting: CountingSettings | None = None,
    seed_map: SeedMap | None = None,
) -> tuple[dict[str, Any], list[ConfigOutcome]]:
    """The survey document (docs/contract.md section 4) and the per-configuration outcomes (with states).

    ``estimator`` defaults to the scenario's ``survey:`` field; ``states`` switches it to a fixed
    number of states per seed. Seeds start at ``seed`` (default: the scenario's). ``seed_map`` runs
    the seeds elsewhere (a Ray cluster: :class:`RemoteSeeds` is what it runs); by default they run in
    ``workers`` forked processes where forking is safe, else in this process. ``data`` is the search's
    scratch over ``task`` (shared with a plan that surveys first; a fresh one when not given)."""
    t0 = time.perf_counter()
    est = estimator or estimator_of(scenario, states)
    if estimator is not None and states is not None:
        est = est.model_copy(update={"until": "states", "states_per_seed": states})
    first_seed = scenario.seed if seed is None else seed
    threshold = scenario.threshold_m if threshold_m is None else threshold_m
    configs = hands or list(HAND_CONFIGS)
    for h in configs:
        if h not in HAND_CONFIGS:
            raise ValueError(f"unknown hands {h!r}; valid: {', '.join(HAND_CONFIGS)}")
    if no_limits and task is None:
        settings = (settings or PlannerSettings()).model_copy(update={"limits": False})
    task = task or Task(scenario, settings, threshold_m=threshold)
    data = SearchData(task) if data is None else data
    no_limits = task.limits is None
    inradius = task.stance.polygon.inradius
    if threshold > inradius:
        reason = (f"threshold {threshold * 1000:.1f} mm is larger than the support polygon's inradius "
                  f"{inradius * 1000:.1f} mm in stance {task.stance.name!r}: no state can be stable")
        rows = [RowWork(h, None, reason) for h in configs]
        for r in rows:
            r.verdict = None
    else:
        n_workers = max(1, workers if workers is not None else (os.cpu_count() or 1))
        progress(0.02, f"key paths of {len(configs)} hand configurations ({est.key_path_pool} key-path seeds each)")
        pools = draw_pools(task, configs, est, workers=n_workers, can_fork=pool_may_fork(), should_stop=should_stop,
                           data=data)
        rows = [_row_work(task, h, pools[h]) for h in configs]
        progress(0.05, f"exploring {len(configs)} hand configurations ({est.until})")
        # A pose over an effort or grip limit counts as unstable (planner.survey.limits).
        trrt = TrrtSettings(margin_cost=task.constrained)
        run_rows(rows, survey_limits.limited(task, task.evaluator.with_threshold(threshold)), est, first_seed, workers=n_workers,
                 settings=counting, trrt=trrt, should_stop=should_stop,
                 progress=lambda f, m: progress(0.05 + 0.9 * f, m), keep_states=keep_states,
                 can_fork=pool_may_fork(), seed_map=seed_map,
                 seed_fn=None if seed_map is None else RemoteSeeds(task, rows, est, counting, trrt, threshold, first_seed))
    outcomes = [_outcome(r, est, keep_states) for r in rows]
    survey_rows = [SurveyRow(hands=o.hands, stable=o.stable, unstable=o.unstable, ratio=o.ratio, reason=o.reason,
                             ratio_ci95=o.interval, seeds=len(o.per_seed), converged=o.converged, per_seed=o.per_seed,
                             over_limits=o.over_limits)
                   for o in outcomes]
    best = recommend(survey_rows)
    doc = {
        "schema": SURVEY_SCHEMA,
        "robot": {"name": task.robot.name, "urdf_sha256": task.robot.urdf_sha256},
        "stance": task.stance.result().model_dump(),
        "threshold_m": threshold,
        "seed": first_seed,
        "object": {"name": task.obj.name, "mass_kg": task.obj.mass_kg, "com_local": task.obj.com_local.tolist(),
                   "start_pose": list(scenario.start_pose), "goal_pose": list(scenario.goal_pose)},
        "estimator": est.document(),
        "limits": "off" if no_limits else "effort and grip",
        "rows": [r.model_dump(exclude_none=False) for r in survey_rows],
        "recommended": best,
        "indistinguishable": indistinguishable(survey_rows, best),
        "stats": {"time_s": time.perf_counter() - t0, "no_limits": no_limits,
                  "states_per_configuration": est.states_per_seed if est.until == "states" else None,
                  "support_polygon": task.stance.polygon.vertices.tolist(),
                  "configurations": {o.hands: o.stats for o in outcomes}},
    }
    return doc, outcomes


def write_states(path: str, doc: dict, outcomes: list[ConfigOutcome], task_info: dict) -> int:
    """Every evaluated state as an .npz (no pickled objects): docs/contract.md section 4."""
    parts = [o for o in outcomes if o.q is not None and len(o.q)]
    nq = len(task_info["joint_names"])
    if parts:
        hands = np.concatenate([np.full(len(o.q), o.hands) for o in parts]).astype("U11")
        q = np.vstack([o.q for o in parts])
        holding = np.concatenate([o.holding for o in parts]).astype("U5")
        pose = np.vstack([o.object_pose for o in parts])
        stable = np.concatenate([o.stable_flags for o in parts]).astype(bool)
        seeds = np.concatenate([o.seed if o.seed is not None else np.full(len(o.q), doc["seed"]) for o in parts]).astype(np.int64)
    else:
        seeds = np.zeros(0, np.int64)
        hands, q, holding, pose, stable = np.zeros(0, "U11"), np.zeros((0, nq)), np.zeros(0, "U5"), np.zeros((0, 7)), np.zeros(0, bool)
    np.savez_compressed(
        path, hands=hands, q=q, holding=holding, object_pose=pose, stable=stable, seed=seeds,
        base_pose=np.asarray(doc["stance"]["base_pose"]), joint_names=np.asarray(task_info["joint_names"], dtype="U16"),
        threshold_m=np.float64(doc["threshold_m"]), mass_kg=np.float64(doc["object"]["mass_kg"]),
        com_local=np.asarray(doc["object"]["com_local"]), support_polygon=np.asarray(doc["stats"]["support_polygon"]),
    )
    return len(q)
