"""The ablations: for each claim not reproduced, runs that each change one thing (the pelvis placement,
the object's CoM side, its mass, the threshold, the estimator's precision), the claim judged again on each."""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable

from experiments import runs
from experiments.claims import (
    NO_REMOVAL_HANDS,
    ORDERINGS,
    judge_all_stable,
    judge_best_stance,
    judge_no_removal,
    judge_ordering,
    judge_threshold_motion,
)
from experiments.runs import PaperSettings, Results
from experiments.tables import STANCES
from planner.api.catalogue import builtin_stance
from planner.api.robots import load_robot



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
    "upright-left-no-removal": (("the threshold", "the left-left and left-right plans at 40 mm instead of 60 mm", None),),
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

    if name == "mirrored-com":
        up = runs.scenario("upright")
        return up.model_copy(update={"object": runs.scenario("staggered").object.model_copy(
            update={"mass_kg": up.object.mass_kg})}), settings
    if name == "upright-30mm":
        return runs.scenario("upright", threshold_m=0.03), settings
    if name == "staggered-centred":
        sdef = builtin_stance(load_robot("hrp5p"), "staggered").model_copy(update={"com_over": "support-centre",
                                                                                  "name": "staggered-centred"})
        return runs.scenario("staggered", stance=sdef), settings
    if name == "crouched-8kg":
        return runs.scenario("crouched", object={"mass_kg": 8.0}), settings
    if name == "one-legged-20mm":
        return runs.scenario("one-legged", threshold_m=0.02), settings
    if name == "one-legged-precise":
        est = dict(settings.estimator)
        if est["until"] == "solved":
            est["ci_half_width"] = est["ci_half_width"] * PRECISION_SHARE
        else:
            est["seeds_min"] = est["seeds_max"] = int(round(est["seeds_max"] / PRECISION_SHARE))
        return runs.scenario("one-legged"), dataclasses.replace(settings, estimator=est)
    raise KeyError(name)


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
    run: dict[str, Any] = {}
    if variant is not None:
        if variant not in surveys:
            sc, variant_settings = _variant(variant, settings)
            surveys[variant] = runs.survey(sc, variant_settings)
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
                lighter = runs.survey(runs.scenario("crouched", object={"mass_kg": mass}), settings)
                held, why = judge_all_stable(lighter["rows"])
                run["sweep"].append({"mass_kg": mass, "verdict": "reproduced" if held else "not reproduced", "evidence": why})
    elif cid == "upright-left-no-removal":
        run["plans"] = {h: runs.plan_summary(runs.plan("upright", h, 0.04, settings))
                        for h in NO_REMOVAL_HANDS}
        ok, ev = judge_no_removal(run["plans"])
    elif cid == "threshold-changes-motion":
        crouched = runs.scenario("crouched", object={"mass_kg": 8.0})
        pair, _, _ = runs.plan_pair(crouched, res.plans["crouched"]["constrained"]["hands"] or "right-right", settings)
        run["plans"] = {"crouched-8kg": pair}
        ok, ev = judge_threshold_motion({**{s: res.plans[s] for s in STANCES if s != "crouched"}, "crouched-8kg": pair})
    else:
        by = {}
        for stance in STANCES:  # every stance, as the claim compares them all
            by[stance] = runs.survey(runs.scenario("upright", stance=stance, threshold_m=0.03), settings)["rows"]
        run["tables"] = by
        ok, ev = judge_best_stance(by)
    run.update(verdict="reproduced" if ok else "not reproduced", evidence=ev)
    return run
