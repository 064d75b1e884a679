"""``regrasp paper``: run the paper's section IV with our model and write the experiments report.

Everything in the report comes from the run that writes it: surveys per stance (C, U, R per
hand configuration with its 95 % interval over seeds, as ``regrasp survey`` computes them), the
stance comparison, CoM traces of the planned motions at the scenario's threshold and at 0 mm,
the real-robot drill tasks, planning times with and without the constraint, and a strict verdict
on each of the paper's claims (:mod:`service.paper_claims`). Every claim not reproduced names a
cause and shows a run that changes that one thing (the pelvis placement, the object's CoM side,
its mass, the threshold), with the claim judged again on it. The numbers are also written to
``report.json`` (docs/contract.md section 4b). The tables are reproduced without effort and grip
limits, as the paper had none; beside them, the same surveys and plans with the limits on show what the
limits change (left out with ``--no-limits``).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from planner.stability.stances import BUILTIN_STANCES as STANCES
from schemas.common import HAND_CONFIGS

#: The paper's Tables I-IV: (C, U, R) per hand configuration.
PAPER_TABLES: dict[str, dict[str, tuple[int, int, float]]] = {
    "upright": {"left-left": (10529, 15, 0.9986), "right-right": (15991, 1801, 0.8998),
                "left-right": (11189, 41, 0.9963), "right-left": (5391, 7351, 0.4231)},
    "staggered": {"left-left": (6447, 135, 0.9795), "right-right": (250, 90, 0.64),
                  "left-right": (2135, 6482, 0.2478), "right-left": (1370, 390, 0.7784)},
    "crouched": {"left-left": (12242, 0, 1.0), "right-right": (654, 0, 1.0),
                 "left-right": (6901, 0, 1.0), "right-left": (14754, 0, 1.0)},
    "one-legged": {"left-left": (2628, 0, 1.0), "right-right": (4299, 2401, 0.6416),
                   "left-right": (2558, 2444, 0.5113), "right-left": (1306, 88, 0.9368)},
}
DRILL_TASKS = ("drill-handover", "drill-upright")



@dataclass(frozen=True)
class PaperSettings:
    """Sample sizes: the survey estimator of the tables, the plans' iteration cap."""

    estimator: dict[str, Any]
    plan_iterations: int
    workers: int | None = None
    #: the tables and plans without effort and grip limits, as the paper had none (always so for the reproduction)
    no_limits: bool = True
    quick: bool = False
    #: beside the reproduction, the tables' surveys and the stances' plans again with the limits on
    limits_section: bool = True

    @classmethod
    def full(cls) -> "PaperSettings":
        # The survey's own default estimator (docs/contract.md section 4), as `regrasp survey` and `hands: auto` run it.
        return cls(estimator={"until": "solved", "ci_half_width": 0.02, "seeds_min": 10, "seeds_max": 256,
                              "leg_cap_states": 20000}, plan_iterations=600)

    @classmethod
    def quick_run(cls) -> "PaperSettings":
        return cls(estimator={"until": "states", "states_per_seed": 150, "seeds_min": 3, "seeds_max": 3,
                              "leg_cap_states": 150}, plan_iterations=300, quick=True)

    def document(self) -> dict[str, Any]:
        return {"estimator": dict(self.estimator), "plan_iterations": self.plan_iterations, "workers": self.workers,
                "no_limits": self.no_limits, "quick": self.quick,
                "limits_section": self.limits_section}


@dataclass
class Results:
    settings: PaperSettings
    tables: dict[str, Any] = field(default_factory=dict)
    comparison: dict[str, Any] = field(default_factory=dict)
    plans: dict[str, Any] = field(default_factory=dict)
    drills: dict[str, Any] = field(default_factory=dict)
    claims: list[dict[str, Any]] = field(default_factory=list)
    cause_runs: dict[str, Any] = field(default_factory=dict)
    handovers: dict[str, Any] = field(default_factory=dict)
    limits: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    figures: dict[str, str] = field(default_factory=dict)


def _scenario(name: str, stance: Any = None, **changes: Any):
    from planner.scene.scenarios import resolve_scenario

    sc = resolve_scenario(name, stance=stance)
    if changes.get("object"):
        sc = sc.model_copy(update={"object": sc.object.model_copy(update=changes.pop("object"))})
    return sc.model_copy(update=changes) if changes else sc


def _survey(sc, settings: PaperSettings, no_limits: bool | None = None) -> dict[str, Any]:
    """A survey with the report's estimator: its rows (docs/contract.md section 4) and what it ran with
    (without the limits unless ``no_limits`` is False)."""
    from planner.scene.scenarios import with_overrides
    from planner.survey.runner import run_survey

    t0 = time.perf_counter()
    sc = with_overrides(sc, survey=settings.estimator)
    doc, _ = run_survey(sc, workers=settings.workers, keep_states=False,
                        no_limits=settings.no_limits if no_limits is None else no_limits)
    return {"rows": doc["rows"], "recommended": doc["recommended"], "indistinguishable": doc["indistinguishable"],
            "estimator": doc["estimator"], "seed": doc["seed"], "threshold_m": doc["threshold_m"], "object": doc["object"],
            "stance": doc["stance"]["name"], "time_s": time.perf_counter() - t0, "doc": doc}


def _table(stance: str, settings: PaperSettings) -> dict[str, Any]:
    t = _survey(_scenario(stance), settings)
    t["paper"] = [{"hands": h, "stable": c, "unstable": u, "ratio": r} for h, (c, u, r) in PAPER_TABLES[stance].items()]
    return t


def _plan(scenario: Any, hands: str | None, threshold_m: float | None, iterations: int, stance: str | None = None,
          estimator: dict[str, Any] | None = None, limits: bool = False) -> dict[str, Any]:
    """A plan of a scenario (a name or a Scenario); ``hands: auto`` surveys with ``estimator`` (the report's).
    Without effort and grip limits, as the paper, unless ``limits``."""
    from planner.jobs.plan_job import PlanOptions, plan_scenario
    from planner.scene.scenarios import resolve_scenario, with_overrides

    sc = scenario if not isinstance(scenario, str) else resolve_scenario(scenario, stance=stance)
    if estimator:
        sc = with_overrides(sc, survey=estimator)
    sc = sc.model_copy(update={"limits": sc.limits.model_copy(update={"max_iterations": iterations})})
    t0 = time.perf_counter()
    doc = plan_scenario(sc, PlanOptions(hands=hands, threshold_m=threshold_m, limits=limits))
    doc.setdefault("stats", {})["wall_s"] = time.perf_counter() - t0
    return doc


def _trace(doc: dict) -> np.ndarray:
    return np.array([p["com"][:2] for p in doc.get("trajectory", [])]).reshape(-1, 2)


def _plan_summary(doc: dict) -> dict[str, Any]:
    traj = doc.get("trajectory", [])
    st = doc.get("stats", {})
    return {"status": doc["status"], "hands": doc.get("hands"), "threshold_m": doc["threshold_m"],
            "min_margin_m": doc.get("min_margin_m"), "duration_s": traj[-1]["t"] if traj else None,
            "planning_time_s": st.get("time_s"), "failure": (doc.get("failure") or {}).get("code"), "points": len(traj),
            "failures": st.get("failures") if doc["status"] == "solved" else (doc.get("failure") or {}).get("counts")}


def _plan_pair(scenario: Any, hands: str, settings: PaperSettings, threshold_m: float | None = None) -> tuple[dict, dict, dict]:
    constrained = _plan(scenario, hands, threshold_m, settings.plan_iterations)
    free = _plan(scenario, hands, 0.0, settings.plan_iterations)
    differ = (constrained["status"] == "solved" and free["status"] == "solved"
              and [p["q"] for p in constrained["trajectory"]] != [p["q"] for p in free["trajectory"]])
    thr = constrained["threshold_m"]
    breaks = free["status"] == "solved" and free["min_margin_m"] < thr - 1e-4
    return ({"constrained": _plan_summary(constrained), "unconstrained": _plan_summary(free), "plans_differ": differ,
             "unconstrained_breaks_threshold": breaks}, constrained, free)


#: What each claim's cause runs change: (cause, what the run changes, the survey variant it runs or None), in the
#: order tried. The first whose run reproduces the claim is the claim's cause; the others are shown as tried.
CAUSES: dict[str, tuple[tuple[str, str, str | None], ...]] = {
    "upright-left-hand-most-stable": (
        ("the object's CoM side", "the upright task with the object's CoM mirrored front to back (CoM (-150, 80, 150) mm, "
         "the staggered task's carrier)", "mirrored-com"),
        ("the threshold", "the upright task at 30 mm instead of 60 mm", "upright-30mm")),
    "upright-right-left-least-stable": (
        ("the object's CoM side", "the upright task with the object's CoM mirrored front to back", "mirrored-com"),
        ("the threshold", "the upright task at 30 mm instead of 60 mm", "upright-30mm")),
    "upright-left-no-removal": (("the threshold", "the left-left plan at 40 mm instead of 60 mm", None),),
    "staggered-left-left-most-stable": (
        ("the pelvis placement", "the staggered stance with the pelvis moved so the CoM stands over the centre of the new "
         "polygon (com_over: support-centre)", "staggered-centred"),),
    "staggered-right-hand-endings-least-stable": (
        ("the pelvis placement", "the staggered stance with the CoM re-centred (com_over: support-centre)",
         "staggered-centred"),),
    "crouched-all-stable": (
        ("the object's mass", "the crouched task with 8 kg (the paper's analysis) instead of 15 kg, then lighter still "
         "(a mass sweep)", "crouched-8kg"),),
    "one-legged-left-left-most-stable": (
        ("the estimator's precision", "the one-legged survey run until every interval is within +-0.005 instead of +-0.02 "
         "(a tie at +-0.02 may be an interval too wide to tell)", "one-legged-precise"),
        ("the threshold", "the one-legged task at 20 mm instead of 30 mm", "one-legged-20mm")),
    "one-legged-right-hand-endings-less-stable": (
        ("the estimator's precision", "the one-legged survey run until every interval is within +-0.005 instead of +-0.02",
         "one-legged-precise"),
        ("the threshold", "the one-legged task at 20 mm instead of 30 mm", "one-legged-20mm")),
    "threshold-changes-motion": (
        ("the object's mass", "the crouched task's plans with 8 kg (the paper's analysis) instead of 15 kg, the other "
         "stances as they are", None),),
    "crouched-most-stable-stance": (("the threshold", "the upright task in each stance at 30 mm instead of 60 mm", None),),
}

#: The crouched task's lighter objects after the 8 kg cause run: where R = 1 everywhere would hold, if anywhere.
SWEEP_MASSES_KG = (4.0, 1.0)
#: The precision variant's interval: this share of the estimator's half-width (more seeds; with a fixed budget
#: per seed, this many times the seeds).
PRECISION_SHARE = 0.25


def _variant(name: str, settings: PaperSettings) -> tuple[Any, PaperSettings]:
    """The scenario and the report settings of a survey cause run."""
    import dataclasses

    from planner.robot.model import load_robot
    from planner.stability.stances import builtin_stance

    if name == "mirrored-com":
        up = _scenario("upright")
        return up.model_copy(update={"object": _scenario("staggered").object.model_copy(
            update={"mass_kg": up.object.mass_kg})}), settings
    if name == "upright-30mm":
        return _scenario("upright", threshold_m=0.03), settings
    if name == "staggered-centred":
        sdef = builtin_stance(load_robot("hrp5p"), "staggered").model_copy(update={"com_over": "support-centre",
                                                                                  "name": "staggered-centred"})
        return _scenario("staggered", stance=sdef), settings
    if name == "crouched-8kg":
        return _scenario("crouched", object={"mass_kg": 8.0}), settings
    if name == "one-legged-20mm":
        return _scenario("one-legged", threshold_m=0.02), settings
    if name == "one-legged-precise":
        est = dict(settings.estimator)
        if est["until"] == "solved":
            est["ci_half_width"] = est["ci_half_width"] * PRECISION_SHARE
        else:
            est["seeds_min"] = est["seeds_max"] = int(round(est["seeds_max"] / PRECISION_SHARE))
        return _scenario("one-legged"), dataclasses.replace(settings, estimator=est)
    raise KeyError(name)


def handover_failures(sc) -> dict[str, Any]:
    """Why the dual-arm configurations of a task find a key path or not: its handover poses' height, and the
    handover node validations by cause (the giver at the pose, the taker's approach, ...)."""
    from collections import Counter

    from planner.regrasp.graph import HandoverNode
    from planner.regrasp.hand_config_planner import HandConfigPlanner
    from planner.regrasp.task import Task
    from planner.survey.runner import key_path

    task = Task(sc)
    out: dict[str, Any] = {"object_mass_kg": sc.object.mass_kg, "pelvis_height_m": float(task.stance.base_pose[2]),
                           "handover_com_heights_m": sorted({round(float(h.T_world_obj[2, 3]
                                                                         + (h.T_world_obj[:3, :3] @ task.obj.com_local)[2]), 3)
                                                             for h in task.handover_poses})}
    for hands in ("left-right", "right-left"):
        path, reason = key_path(HandConfigPlanner(task, hands), lambda: False)
        out[hands] = "key path found" if path is not None else reason
    causes = Counter(f"{v.cause or 'valid'}: {v.detail}" if v.detail else (v.cause or "valid")
                     for k, v in task.node_cache.items() if isinstance(k, HandoverNode))
    out["handover_validations"] = dict(causes.most_common())
    # Key postures that failed the margin and were replaced by a stable one with the hands in place.
    out["stable_postures"] = {"asked": int(task.counters["stable_postures"]),
                              "found": int(task.counters["stable_postures_found"])}
    return out


def evaluate_claims(res: Results) -> list[dict[str, Any]]:
    """Each claim's strict verdict on this run's tables, plans and comparison (no cause runs yet)."""
    from .paper_claims import (
        CLAIM_TEXT,
        ORDERINGS,
        judge_all_stable,
        judge_best_stance,
        judge_no_removal,
        judge_ordering,
        judge_threshold_motion,
    )

    out = []
    for cid, text in CLAIM_TEXT.items():
        if cid in ORDERINGS:
            stance, hi, lo = ORDERINGS[cid]
            ok, ev = judge_ordering(res.tables[stance]["rows"], hi, lo)
        elif cid == "crouched-all-stable":
            ok, ev = judge_all_stable(res.tables["crouched"]["rows"])
        elif cid == "upright-left-no-removal":
            ok, ev = judge_no_removal(res.plans["upright-left-left"]["constrained"])
        elif cid == "threshold-changes-motion":
            ok, ev = judge_threshold_motion({s: res.plans[s] for s in STANCES})
        else:
            ok, ev = judge_best_stance({s: c["rows"] for s, c in res.comparison.items()})
        out.append({"id": cid, "text": text, "verdict": "reproduced" if ok else "not reproduced", "evidence": ev,
                    "cause": None, "cause_run": None, "other_cause_runs": []})
    return out


def run_causes(res: Results, settings: PaperSettings, progress: Callable[[str], None]) -> None:
    """For each claim not reproduced: the runs that each change one thing, judged again; the claim's cause is
    the first whose run reproduces it (else the first tried), the others are kept as tried."""
    surveys: dict[str, dict] = {}
    for claim in res.claims:
        if claim["verdict"] == "reproduced":
            continue
        cid = claim["id"]
        runs = []
        for cause, change, variant in CAUSES[cid]:
            progress(f"cause run for {cid}: {change}")
            t0 = time.perf_counter()
            run = {"cause": cause, "change": change, **_cause_run(res, settings, cid, variant, surveys)}
            run["time_s"] = time.perf_counter() - t0
            runs.append(run)
        chosen = next((r for r in runs if r["verdict"] == "reproduced"), runs[0])
        claim["cause"] = chosen["cause"]
        claim["cause_run"] = chosen
        claim["other_cause_runs"] = [r for r in runs if r is not chosen]
        res.cause_runs[cid] = chosen


def _cause_run(res: Results, settings: PaperSettings, cid: str, variant: str | None, surveys: dict[str, dict]) -> dict:
    """One cause run of claim ``cid``: its table, plan or plans, and the claim's verdict on them."""
    from .paper_claims import (
        ORDERINGS,
        judge_all_stable,
        judge_best_stance,
        judge_no_removal,
        judge_ordering,
        judge_threshold_motion,
    )

    run: dict[str, Any] = {}
    if variant is not None:
        if variant not in surveys:
            sc, variant_settings = _variant(variant, settings)
            surveys[variant] = _survey(sc, variant_settings)
        t = surveys[variant]
        run["table"] = {k: t[k] for k in ("rows", "recommended", "indistinguishable", "threshold_m", "object", "stance",
                                          "estimator")}
        if cid in ORDERINGS:
            _, hi, lo = ORDERINGS[cid]
            ok, ev = judge_ordering(t["rows"], hi, lo)
        else:
            ok, ev = judge_all_stable(t["rows"])
            # Lighter still: the mass at which the claim would hold, if any (the same task otherwise).
            run["sweep"] = []
            for mass in SWEEP_MASSES_KG:
                lighter = _survey(_scenario("crouched", object={"mass_kg": mass}), settings)
                held, why = judge_all_stable(lighter["rows"])
                run["sweep"].append({"mass_kg": mass, "verdict": "reproduced" if held else "not reproduced", "evidence": why})
    elif cid == "upright-left-no-removal":
        run["plan"] = _plan_summary(_plan("upright", "left-left", 0.04, settings.plan_iterations))
        ok, ev = judge_no_removal(run["plan"])
    elif cid == "threshold-changes-motion":
        crouched = _scenario("crouched", object={"mass_kg": 8.0})
        pair, _, _ = _plan_pair(crouched, res.plans["crouched"]["constrained"]["hands"] or "right-right", settings)
        run["plans"] = {"crouched-8kg": pair}
        ok, ev = judge_threshold_motion({**{s: res.plans[s] for s in STANCES if s != "crouched"}, "crouched-8kg": pair})
    else:
        by = {}
        for stance in STANCES:  # every stance, as the claim compares them all
            by[stance] = _survey(_scenario("upright", stance=stance, threshold_m=0.03), settings)["rows"]
        run["tables"] = by
        ok, ev = judge_best_stance(by)
    run.update(verdict="reproduced" if ok else "not reproduced", evidence=ev)
    return run


def run(out: Path, settings: PaperSettings, progress: Callable[[str], None] = print) -> Results:
    from service.convergence_plot import plot_convergence
    from service.plots import plot_com_trace

    out.mkdir(parents=True, exist_ok=True)
    res = Results(settings)
    t_all = time.perf_counter()
    # 1. Tables I-IV: each stance with its own object, CoM offset and threshold.
    for stance in STANCES:
        progress(f"survey: {stance} stance")
        res.tables[stance] = _table(stance, settings)
        fig = out / f"convergence-{stance}.png"
        plot_convergence(fig, res.tables[stance]["doc"], title=f"{stance}: R against states counted (95 % interval)")
        res.figures[f"convergence-{stance}"] = fig.name
    res.timings["tables_s"] = time.perf_counter() - t_all
    # 2. Stance comparison: the upright task (its object and threshold) in the four stances.
    for stance in STANCES:
        if stance == "upright":
            res.comparison[stance] = res.tables["upright"]
            continue
        progress(f"stance comparison: upright task in the {stance} stance")
        res.comparison[stance] = _survey(_scenario("upright", stance=stance), settings)
    # 3. Figures: CoM traces of the planned motion at the threshold and at 0 mm.
    for stance in STANCES:
        hands = res.tables[stance]["recommended"] or "right-right"
        progress(f"plans: {stance} stance, {hands}, threshold and 0 mm")
        res.plans[stance], constrained, free = _plan_pair(stance, hands, settings)
        thr = constrained["threshold_m"]
        polygon = np.array(constrained.get("support_polygon") or free.get("support_polygon") or [[0, 0], [1, 0], [0, 1]])
        traces = []
        if free["status"] == "solved":
            traces.append(("0 mm (unconstrained)", _trace(free), "tab:red"))
        if constrained["status"] == "solved":
            traces.append((f"{thr * 1000:.0f} mm", _trace(constrained), "tab:blue"))
        fig = out / f"com-trace-{stance}.png"
        plot_com_trace(fig, title=f"{stance} stance, {hands}: CoM at {thr * 1000:.0f} mm vs 0 mm", polygon=polygon,
                       threshold_m=thr, traces=traces)
        res.figures[stance] = fig.name
    progress("plan: upright, left-left (node removals)")
    res.plans["upright-left-left"] = {"constrained": _plan_summary(_plan("upright", "left-left", None, settings.plan_iterations))}
    # 4. The real-robot tasks at 55 mm.
    for name in DRILL_TASKS:
        progress(f"real-robot task: {name}")
        doc = _plan(name, None, None, settings.plan_iterations, estimator=settings.estimator)
        res.drills[name] = _plan_summary(doc)
        if doc["status"] == "solved":
            fig = out / f"com-trace-{name}.png"
            plot_com_trace(fig, title=f"{name} ({doc['hands']}), 55 mm", polygon=np.array(doc["support_polygon"]),
                           threshold_m=doc["threshold_m"], traces=[("55 mm", _trace(doc), "tab:blue")])
            res.figures[name] = fig.name
    progress("crouched handovers: why the dual-arm configurations fail or plan")
    res.handovers = {"crouched": handover_failures(_scenario("crouched")),
                     "crouched-8kg": handover_failures(_scenario("crouched", object={"mass_kg": 8.0})),
                     "upright": handover_failures(_scenario("upright"))}
    res.claims = evaluate_claims(res)
    run_causes(res, settings, progress)
    if settings.limits_section:
        run_limits(res, settings, progress)
    res.timings["total_s"] = time.perf_counter() - t_all
    (out / "report.json").write_text(json.dumps(_to_json(res), indent=2, allow_nan=False))
    (out / "report.md").write_text(render(res))
    return res


def run_limits(res: Results, settings: PaperSettings, progress: Callable[[str], None]) -> None:
    """What the effort and grip limits change: each table's survey and each stance's plan again with them on."""
    t0 = time.perf_counter()
    for stance in STANCES:
        progress(f"limits: {stance} stance survey and plan with effort and grip checked")
        with_limits = _survey(_scenario(stance), settings, no_limits=False)
        hands = res.tables[stance]["recommended"] or "right-right"
        plan = _plan(stance, hands, None, settings.plan_iterations, limits=True)
        rows = {r["hands"]: r for r in res.tables[stance]["rows"]}
        res.limits[stance] = {
            "rows": [{"hands": r["hands"], "ratio_without": rows.get(r["hands"], {}).get("ratio"),
                      "ratio_with": r["ratio"], "ratio_ci95_with": r.get("ratio_ci95"), "over_limits": r.get("over_limits"),
                      "reason_with": r.get("reason")} for r in with_limits["rows"]],
            "recommended_without": res.tables[stance]["recommended"], "recommended_with": with_limits["recommended"],
            "plan": {"hands": hands, **_plan_summary(plan),
                     "max_effort_ratio": max((p.get("effort_ratio") or 0.0 for p in plan.get("trajectory") or []),
                                             default=None)},
        }
    res.timings["limits_s"] = time.perf_counter() - t0


def _table_json(t: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in t.items() if k != "doc"}


def _to_json(res: Results) -> dict[str, Any]:
    return {"settings": res.settings.document(), "tables": {s: _table_json(t) for s, t in res.tables.items()},
            "comparison": {s: _table_json(t) for s, t in res.comparison.items()}, "plans": res.plans,
            "drills": res.drills, "handovers": res.handovers, "claims": res.claims,
            "limits": {"reproduction": "off (--no-limits): the paper had none", "with_limits": res.limits},
            "timings": res.timings, "figures": res.figures}


def _fmt(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def _fmt_mm(v: float | None) -> str:
    return "n/a" if v is None else f"{v * 1000:.1f} mm"


def _ratio_cell(row: dict[str, Any]) -> str:
    if row.get("ratio") is None:
        return f"n/a ({_short_reason(row.get('reason'))})"
    ci = row.get("ratio_ci95")
    return f"{row['ratio']:.4f} [{ci[0]:.4f}, {ci[1]:.4f}]" if ci else f"{row['ratio']:.4f}"


INCONSISTENCIES = [
    ("The crouched object is 15 kg in the simulation set-up and 8 kg in the analysis.",
     "We follow 15 kg, the figure of the set-up paragraph that describes the run (planner/scene/scenario_data/crouched.yaml)."),
    ("The analysis paragraph headed 'staggered' (the second one) describes the one-legged results (Table IV, Fig. 5).",
     "We read it as the one-legged analysis and check its claim against our one-legged table."),
    ("'0 unstable poses recorded' stands beside U = 135 for the staggered left-hand configuration.",
     "We read '0 unstable poses' as the executed (planned) path, and U as the explored states; both are reported here separately."),
    ("'The constraints for the one-legged stance are softened' is never explained.",
     "We apply no softening: the one-legged stance uses the same rule (margin >= 30 mm) on the one-sole polygon."),
]


def render(res: Results) -> str:
    s = res.settings
    est = s.estimator
    budget = (f"{est['states_per_seed']} states per seed, {est['seeds_min']} seeds" if est["until"] == "states" else
              f"seeds until every interval is within +-{est['ci_half_width']} ({est['seeds_min']} to {est['seeds_max']} "
              f"seeds, legs capped at {est['leg_cap_states']} states)")
    lines = [
        "# Reproducing \"Regrasp Planning Considering Bipedal Stability Constraints\"", "",
        "Generated by `regrasp paper`; every number below comes from this run (also in `report.json`).", "",
        "- Model: the project's HRP-5P-like robot (1.82 m, 101 kg, 37 DoF).",
        f"- Survey estimator: {budget}; R is pooled over the seeds and its 95 % interval is the percentile bootstrap "
        "over seeds. A claim is reproduced only when the orderings it names hold between intervals that do not overlap.",
        "- Tables, comparison and plans without effort and grip limits, as the paper had none; the section "
        "*What the limits change* runs the same surveys and plans with them on"
        + ("." if res.limits else " (left out of this run: `--no-limits`)."),
        f"- Total run time: {res.timings.get('total_s', 0):.1f} s.", "",
        "## Tables I-IV: stability per hand configuration", "",
    ]
    for stance in STANCES:
        t = res.tables[stance]
        obj = t["object"]
        lines += [f"### {stance.capitalize()} stance", "",
                  f"Object {obj['mass_kg']:g} kg, CoM {[round(v * 1000) for v in obj['com_local']]} mm in the object frame, "
                  f"threshold {t['threshold_m'] * 1000:.0f} mm. Recommended: **{t['recommended']}**"
                  + (f" (a tie with {', '.join(t['indistinguishable'])})" if t["indistinguishable"] else "") + ".", "",
                  f"![convergence]({res.figures.get('convergence-' + stance, '')})", "",
                  "| hand configuration | C (ours) | U (ours) | R (ours) [95 %] | seeds | C (paper) | U (paper) | R (paper) |",
                  "|---|---|---|---|---|---|---|---|"]
        paper = {p["hands"]: p for p in t["paper"]}
        for row in t["rows"]:
            p = paper[row["hands"]]
            seeds = f"{row['seeds']}{'' if row['converged'] else ' (not converged)'}"
            lines.append(f"| {row['hands']} | {row['stable']} | {row['unstable']} | {_ratio_cell(row)} | {seeds} | "
                         f"{p['stable']} | {p['unstable']} | {p['ratio']:.4f} |")
        lines.append("")
    lines += ["## Stance comparison (the upright task in each stance)", "",
              "| stance | " + " | ".join(HAND_CONFIGS) + " |", "|---" * (len(HAND_CONFIGS) + 1) + "|"]
    for stance in STANCES:
        by = {r["hands"]: r for r in res.comparison[stance]["rows"]}
        lines.append(f"| {stance} | " + " | ".join(_ratio_cell(by[h]) for h in HAND_CONFIGS) + " |")
    lines += ["", "## CoM traces at the threshold and at 0 mm (Figs. 2-5)", ""]
    for stance in STANCES:
        p = res.plans[stance]
        c, u = p["constrained"], p["unconstrained"]
        lines += [f"### {stance.capitalize()} stance ({c['hands']})", "",
                  f"![CoM trace]({res.figures.get(stance, '')})", "",
                  "| threshold | status | min margin | duration | planning time |", "|---|---|---|---|---|",
                  f"| {c['threshold_m'] * 1000:.0f} mm | {c['status']} | {_fmt_mm(c['min_margin_m'])} | "
                  f"{_fmt_s(c['duration_s'])} | {_fmt_s(c['planning_time_s'])} |",
                  f"| 0 mm | {u['status']} | {_fmt_mm(u['min_margin_m'])} | {_fmt_s(u['duration_s'])} | {_fmt_s(u['planning_time_s'])} |",
                  "", ("The two plans differ" if p["plans_differ"] else "The two plans are the same")
                  + ("; the unconstrained plan comes closer to the edge than the threshold (the paper's Fig. 1 effect)."
                     if p["unconstrained_breaks_threshold"] else "; the unconstrained plan keeps the threshold anyway."), ""]
    lines += ["## The real-robot tasks (55 mm)", "", "| task | status | hands | min margin | duration | planning time |",
              "|---|---|---|---|---|---|"]
    for name, d in res.drills.items():
        lines.append(f"| {name} | {d['status']}{' (' + d['failure'] + ')' if d['failure'] else ''} | {d['hands']} | "
                     f"{_fmt_mm(d['min_margin_m'])} | {_fmt_s(d['duration_s'])} | {_fmt_s(d['planning_time_s'])} |")
    lines += ["", "## Crouched handovers", "",
              "Handover poses are offsets from the stance's pelvis, so the crouched robot hands over lower. Why the "
              "dual-arm configurations find a key path or not (handover node validations by cause):", "",
              "| task | pelvis height | handover CoM heights | left-right | right-left | stable postures found | "
              "handover validations |",
              "|---|---|---|---|---|---|---|"]
    for name, h in res.handovers.items():
        steadied = h.get("stable_postures") or {"asked": 0, "found": 0}
        lines.append(f"| {name} ({h['object_mass_kg']:g} kg) | {h['pelvis_height_m']:.2f} m | "
                     f"{', '.join(f'{z:.2f}' for z in h['handover_com_heights_m'])} m | {_short_reason(h['left-right'])} | "
                     f"{_short_reason(h['right-left'])} | {steadied['found']} of {steadied['asked']} | "
                     + "; ".join(f"{k}: {n}" for k, n in h["handover_validations"].items()) + " |")
    lines += ["", "A key posture that fails the margin is replaced by the nearest one with the hands in place that "
              "keeps it (the waist leaning back; docs/motion.md, *Stable key postures*); *stable postures found* counts "
              "those replacements for the two dual-arm configurations' key paths."]
    lines += ["", "## Planning time with and without the constraint", "",
              "| stance | with the threshold | at 0 mm | ratio |", "|---|---|---|---|"]
    for stance in STANCES:
        p = res.plans[stance]
        a, b = p["constrained"]["planning_time_s"], p["unconstrained"]["planning_time_s"]
        lines.append(f"| {stance} | {_fmt_s(a)} | {_fmt_s(b)} | {(a / b) if a and b else float('nan'):.2f} |")
    if res.limits:
        lines += ["", "## What the limits change", "",
                  "The same surveys and the stances' plans with static joint torques and grip checked (docs/robots.md): "
                  "a pose over a limit counts as unstable (and in `over_limits`).", "",
                  "| stance | hand configuration | R without | R with [95 %] | over limits | plan with limits |",
                  "|---|---|---|---|---|---|"]
        for stance, lim in res.limits.items():
            plan = lim["plan"]
            verdict = (f"{plan['hands']}: {plan['status']}" + (f" ({plan['failure']})" if plan.get("failure") else "")
                       + (f", max effort ratio {plan['max_effort_ratio']:.2f}" if plan.get("max_effort_ratio") else ""))
            for k, row in enumerate(lim["rows"]):
                with_cell = _ratio_cell({"ratio": row["ratio_with"], "ratio_ci95": row["ratio_ci95_with"],
                                         "reason": row["reason_with"]})
                lines.append(f"| {stance if k == 0 else ''} | {row['hands']} | {_fmt(row['ratio_without'])} | {with_cell} | "
                             f"{row['over_limits'] if row['over_limits'] is not None else 'n/a'} | {verdict if k == 0 else ''} |")
    lines += ["", "## Where we agree and where we differ", ""]
    for c in res.claims:
        lines.append(f"- **{c['verdict']}** (`{c['id']}`): {c['text']} Evidence: {c['evidence']}.")
        if c["cause_run"]:
            r = c["cause_run"]
            lines.append(f"  - Cause: {c['cause']}. Run: {r['change']}: the claim is then **{r['verdict']}** "
                         f"({r['evidence']}).")
            for step in r.get("sweep") or []:
                lines.append(f"    - {step['mass_kg']:g} kg: **{step['verdict']}** ({step['evidence']}).")
            for other in c.get("other_cause_runs") or []:
                lines.append(f"  - Also tried: {other['cause']}. Run: {other['change']}: the claim is then "
                             f"**{other['verdict']}** ({other['evidence']}).")
    lines += ["", "## The paper's own inconsistencies, and the reading we follow", ""]
    for issue, reading in INCONSISTENCIES:
        lines.append(f"- {issue} {reading}")
    lines.append("")
    return "\n".join(lines)


def _short_reason(reason: str | None) -> str:
    """The failure code of a reason ("... key poses: COM_MARGIN: ..." -> "COM_MARGIN"), else its first words."""
    if not reason:
        return "no plan"
    import re

    m = re.search(r"\b([A-Z][A-Z_]{3,})\b", reason)
    if m:
        return m.group(1)
    return "threshold cannot be met" if "inradius" in reason else reason.split(":")[0][:60]


def _fmt_s(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f} s"
