"""``regrasp paper``: run the paper's section IV with our model and write the experiments report.

Everything in the report comes from the run that writes it: surveys per stance (C, U, R per
hand configuration with its 95 % interval over seeds, as ``regrasp survey`` computes them), the
stance comparison, CoM traces of the planned motions at the scenario's threshold and at 0 mm,
the real-robot drill tasks, planning times with and without the constraint, and a strict verdict
on each of the paper's claims (:mod:`experiments.claims`). Every claim not reproduced names a
cause and shows a run that changes that one thing (the pelvis placement, the object's CoM side,
its mass, the threshold), with the claim judged again on it. The numbers are also written to
``report.json`` (docs/contract.md section 4b). The tables and claims run on the paper's planner:
without effort and grip limits and without stable key postures, as the paper had neither
(``paper_planner`` in report.json). Beside them, the section *extensions* runs the same surveys
and plans with the stable key postures on, and the limits section with the limits on (left out
with ``--no-limits``); a sampler ablation runs the upright table with the exploration's samples
uniform over the joint box instead of near each leg's start and goal.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from experiments import runs
from experiments.causes import run_causes
from experiments.claims import NO_REMOVAL_HANDS, evaluate_claims
from experiments.convergence_plot import plot_convergence
from experiments.plots import plot_com_trace
from experiments.render import render
from experiments.runs import PaperSettings, Results
from experiments.tables import DRILL_TASKS, STANCES
from planner.api.jobs import handover_diagnosis

__all__ = ["PaperSettings", "Results", "run", "run_extensions", "run_limits", "run_sampler_ablation"]


def run(out: Path, settings: PaperSettings, progress: Callable[[str], None] = print) -> Results:
    out.mkdir(parents=True, exist_ok=True)
    res = Results(settings)
    t_all = time.perf_counter()
    # 1. Tables I-IV: each stance with its own object, CoM offset and threshold.
    for stance in STANCES:
        progress(f"survey: {stance} stance")
        res.tables[stance] = runs.table(stance, settings)
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
        res.comparison[stance] = runs.survey(runs.scenario("upright", stance=stance), settings)
    # 3. Figures: CoM traces of the planned motion at the threshold and at 0 mm.
    for stance in STANCES:
        hands = res.tables[stance]["recommended"] or "right-right"
        progress(f"plans: {stance} stance, {hands}, threshold and 0 mm")
        res.plans[stance], constrained, free = runs.plan_pair(stance, hands, settings)
        thr = constrained["threshold_m"]
        polygon = np.array(constrained.get("support_polygon") or free.get("support_polygon") or [[0, 0], [1, 0], [0, 1]])
        traces = []
        if free["status"] == "solved":
            traces.append(("0 mm (unconstrained)", runs.com_trace(free), "tab:red"))
        if constrained["status"] == "solved":
            traces.append((f"{thr * 1000:.0f} mm", runs.com_trace(constrained), "tab:blue"))
        fig = out / f"com-trace-{stance}.png"
        plot_com_trace(fig, title=f"{stance} stance, {hands}: CoM at {thr * 1000:.0f} mm vs 0 mm", polygon=polygon,
                       threshold_m=thr, traces=traces)
        res.figures[stance] = fig.name
    for hands in NO_REMOVAL_HANDS:
        progress(f"plan: upright, {hands} (node removals)")
        res.plans[f"upright-{hands}"] = {"constrained": runs.plan_summary(
            runs.plan("upright", hands, None, settings))}
    # 4. The real-robot tasks at 55 mm.
    for name in DRILL_TASKS:
        progress(f"real-robot task: {name}")
        doc = runs.plan(name, None, None, settings, estimator=settings.estimator)
        res.drills[name] = runs.plan_summary(doc)
        if doc["status"] == "solved":
            fig = out / f"com-trace-{name}.png"
            plot_com_trace(fig, title=f"{name} ({doc['hands']}), 55 mm", polygon=np.array(doc["support_polygon"]),
                           threshold_m=doc["threshold_m"], traces=[("55 mm", runs.com_trace(doc), "tab:blue")])
            res.figures[name] = fig.name
    progress("crouched handovers: why the dual-arm configurations fail or plan")
    res.handovers = {"crouched": handover_diagnosis(runs.scenario("crouched")),
                     "crouched-8kg": handover_diagnosis(runs.scenario("crouched", object={"mass_kg": 8.0})),
                     "upright": handover_diagnosis(runs.scenario("upright"))}
    res.claims = evaluate_claims(res)
    run_causes(res, settings, progress)
    run_sampler_ablation(res, settings, progress)
    if settings.extensions_section:
        run_extensions(res, settings, progress)
    if settings.limits_section:
        run_limits(res, settings, progress)
    res.timings["total_s"] = time.perf_counter() - t_all
    (out / "report.json").write_text(json.dumps(_to_json(res), indent=2, allow_nan=False))
    (out / "report.md").write_text(render(res))
    return res


def run_sampler_ablation(res: Results, settings: PaperSettings, progress: Callable[[str], None]) -> None:
    """What the exploration's sampler changes: the upright table again with samples uniform over the whole joint
    box (the exploration's former sampler) instead of near each leg's start and goal (the paper's reading)."""
    t0 = time.perf_counter()
    progress("sampler ablation: the upright survey with whole-box sampling")
    box = runs.survey(runs.scenario("upright"), settings, sampler="box")
    ends = {r["hands"]: r for r in res.tables["upright"]["rows"]}
    res.sampler_ablation = {
        "stance": "upright",
        "rows": [{"hands": r["hands"], "ratio_ends": ends[r["hands"]]["ratio"],
                  "ratio_ci95_ends": ends[r["hands"]].get("ratio_ci95"), "ratio_box": r["ratio"],
                  "ratio_ci95_box": r.get("ratio_ci95"), "reason": r.get("reason")} for r in box["rows"]],
        "recommended_ends": res.tables["upright"]["recommended"], "recommended_box": box["recommended"]}
    res.timings["sampler_ablation_s"] = time.perf_counter() - t0


def run_extensions(res: Results, settings: PaperSettings, progress: Callable[[str], None]) -> None:
    """What the product's stable key postures change: each table's survey and plan, and the node-removal plans,
    again with them on (a key pose that fails the margin is replaced by the nearest stable one before it is
    removed)."""
    t0 = time.perf_counter()
    for stance in STANCES:
        progress(f"extensions: {stance} stance survey and plan with stable key postures")
        with_sp = runs.survey(runs.scenario(stance), settings, stable_postures=True)
        hands = res.tables[stance]["recommended"] or "right-right"
        plan = runs.plan(stance, hands, None, settings, stable_postures=True)
        rows = {r["hands"]: r for r in res.tables[stance]["rows"]}
        res.extensions[stance] = {
            "rows": [{"hands": r["hands"], "ratio_without": rows.get(r["hands"], {}).get("ratio"),
                      "ratio_ci95_without": rows.get(r["hands"], {}).get("ratio_ci95"),
                      "ratio_with": r["ratio"], "ratio_ci95_with": r.get("ratio_ci95"), "reason_with": r.get("reason")}
                     for r in with_sp["rows"]],
            "recommended_without": res.tables[stance]["recommended"], "recommended_with": with_sp["recommended"],
            "plan": {"hands": hands, "without": res.plans[stance]["constrained"], "with": runs.plan_summary(plan)}}
    res.extensions["node_removals"] = {
        hands: {"without": res.plans[f"upright-{hands}"]["constrained"],
                "with": runs.plan_summary(runs.plan("upright", hands, None, settings, stable_postures=True))}
        for hands in NO_REMOVAL_HANDS}
    res.timings["extensions_s"] = time.perf_counter() - t0


def run_limits(res: Results, settings: PaperSettings, progress: Callable[[str], None]) -> None:
    """What the effort and grip limits change: each table's survey and each stance's plan again with them on."""
    t0 = time.perf_counter()
    for stance in STANCES:
        progress(f"limits: {stance} stance survey and plan with effort and grip checked")
        with_limits = runs.survey(runs.scenario(stance), settings, no_limits=False)
        hands = res.tables[stance]["recommended"] or "right-right"
        plan = runs.plan(stance, hands, None, settings, limits=True)
        rows = {r["hands"]: r for r in res.tables[stance]["rows"]}
        res.limits[stance] = {
            "rows": [{"hands": r["hands"], "ratio_without": rows.get(r["hands"], {}).get("ratio"),
                      "ratio_with": r["ratio"], "ratio_ci95_with": r.get("ratio_ci95"), "over_limits": r.get("over_limits"),
                      "reason_with": r.get("reason")} for r in with_limits["rows"]],
            "recommended_without": res.tables[stance]["recommended"], "recommended_with": with_limits["recommended"],
            "plan": {"hands": hands, **runs.plan_summary(plan),
                     "max_effort_ratio": max((p.get("effort_ratio") or 0.0 for p in plan.get("trajectory") or []),
                                             default=None)},
        }
    res.timings["limits_s"] = time.perf_counter() - t0


def _table_json(t: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in t.items() if k != "doc"}


def _to_json(res: Results) -> dict[str, Any]:
    return {"settings": res.settings.document(), "paper_planner": res.settings.paper_planner(), "tables": {s: _table_json(t) for s, t in res.tables.items()},
            "comparison": {s: _table_json(t) for s, t in res.comparison.items()}, "plans": res.plans,
            "drills": res.drills, "handovers": res.handovers, "claims": res.claims,
            "limits": {"reproduction": "off (--no-limits): the paper had none", "with_limits": res.limits},
            "extensions": {"stable_postures": res.extensions, "limits": res.limits},
            "sampler_ablation": res.sampler_ablation,
            "timings": res.timings, "figures": res.figures}
