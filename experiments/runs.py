"""The report's runs: a survey and a plan of a (possibly changed) built-in scenario, with the report's
sample sizes, and the summaries the report keeps of them."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from experiments.tables import PAPER_TABLES
from planner.api.catalogue import resolve_scenario, with_overrides
from planner.api.jobs import CountingSettings, PlannerSettings, PlanOptions, plan_scenario, run_survey

#: The quick run's plan timing: no replans, vias, ranking or easing (a large share of a plan's time); each motion
#: is still shortcut, blended and timed by TOPP-RA, every sample checked.
QUICK_PLAN_TIMING: Mapping[str, Any] = MappingProxyType({
    "replans": 0, "alternatives": 1, "shortened_paths": 1, "rank_by_timing": False, "corner_easing_sweeps": 0})


@dataclass(frozen=True)
class PaperSettings:
    """Sample sizes: the survey estimator of the tables, the plans' iteration cap; the planner the paper's runs use."""

    estimator: dict[str, Any]
    plan_iterations: int
    workers: int | None = None
    #: the tables and plans without effort and grip limits, as the paper had none (always so for the reproduction)
    no_limits: bool = True
    quick: bool = False
    #: beside the reproduction, the tables' surveys and the stances' plans again with the limits on
    limits_section: bool = True
    #: beside the reproduction, the tables' surveys and plans again with the stable key postures on
    extensions_section: bool = True
    #: the reproduction's key postures as the paper's planner has them: a key pose that fails the margin is removed,
    #: never replaced by a stable posture (the section *extensions* shows what the stable postures change)
    stable_postures: bool = False
    #: where the surveys' seeds run (a planner.survey.seed_map.SeedMap, e.g. a Ray cluster's); None: on this machine
    seed_map: Any = field(default=None, compare=False, repr=False)
    #: the plans' timing settings changed from the planner's (``plan_timing``; the quick run searches no quicker
    #: paths: the motions are timed as the search left them, so its durations are longer than a product plan's)
    plan_timing: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def full(cls) -> "PaperSettings":
        # The survey's own default estimator (docs/contract.md section 4), as `regrasp survey` and `hands: auto` run it.
        return cls(estimator={"until": "solved", "ci_half_width": 0.02, "seeds_min": 10, "seeds_max": 256,
                              "leg_cap_states": 20000}, plan_iterations=600)

    @classmethod
    def quick_run(cls) -> "PaperSettings":
        return cls(estimator={"until": "states", "states_per_seed": 150, "seeds_min": 4, "seeds_max": 4,
                              "leg_cap_states": 150, "key_path_pool": 1}, plan_iterations=300, quick=True,
                   plan_timing=QUICK_PLAN_TIMING)

    def document(self) -> dict[str, Any]:
        return {"estimator": dict(self.estimator), "plan_iterations": self.plan_iterations, "workers": self.workers,
                "no_limits": self.no_limits, "quick": self.quick,
                "limits_section": self.limits_section, "extensions_section": self.extensions_section,
                "stable_postures": self.stable_postures, "plan_timing": dict(self.plan_timing)}

    def planner(self, stable_postures: bool | None = None) -> PlannerSettings:
        """The planner the report's plans run: its stable key postures (the report's unless given) and timing."""
        base = PlannerSettings()
        return base.model_copy(update={
            "stable_postures": self.stable_postures if stable_postures is None else stable_postures,
            "plan_timing": base.plan_timing.model_copy(update=dict(self.plan_timing))})

    def paper_planner(self) -> dict[str, bool]:
        """What the reproduction's planner has of the product's extensions (report.json ``paper_planner``)."""
        return {"limits": not self.no_limits, "stable_postures": self.stable_postures}


@dataclass
class Results:
    """Everything one report run computed, in the order it ran."""

    settings: PaperSettings
    tables: dict[str, Any] = field(default_factory=dict)
    comparison: dict[str, Any] = field(default_factory=dict)
    plans: dict[str, Any] = field(default_factory=dict)
    drills: dict[str, Any] = field(default_factory=dict)
    claims: list[dict[str, Any]] = field(default_factory=list)
    cause_runs: dict[str, Any] = field(default_factory=dict)
    handovers: dict[str, Any] = field(default_factory=dict)
    limits: dict[str, Any] = field(default_factory=dict)
    #: what the stable key postures change: the tables' surveys and plans again with them on
    extensions: dict[str, Any] = field(default_factory=dict)
    #: the exploration's sampler: the upright table again with the whole-box sampler
    sampler_ablation: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    figures: dict[str, str] = field(default_factory=dict)


def scenario(name: str, stance: Any = None, **changes: Any):
    sc = resolve_scenario(name, stance=stance)
    if changes.get("object"):
        sc = sc.model_copy(update={"object": sc.object.model_copy(update=changes.pop("object"))})
    return sc.model_copy(update=changes) if changes else sc


def survey(sc, settings: PaperSettings, no_limits: bool | None = None, stable_postures: bool | None = None,
           sampler: str | None = None) -> dict[str, Any]:
    """A survey with the report's estimator: its rows (docs/contract.md section 4) and what it ran with. On the
    paper's planner (without the limits and the stable key postures) unless ``no_limits`` is False or
    ``stable_postures`` True; ``sampler`` changes the exploration's sampler (the ablation)."""
    t0 = time.perf_counter()
    sc = with_overrides(sc, survey=settings.estimator)
    planner = settings.planner(stable_postures)
    doc, _ = run_survey(sc, workers=settings.workers, keep_states=False, seed_map=settings.seed_map, settings=planner,
                        no_limits=settings.no_limits if no_limits is None else no_limits,
                        counting=None if sampler is None else CountingSettings(sampler=sampler))
    return {"rows": doc["rows"], "recommended": doc["recommended"], "indistinguishable": doc["indistinguishable"],
            "estimator": doc["estimator"], "seed": doc["seed"], "threshold_m": doc["threshold_m"], "object": doc["object"],
            "stance": doc["stance"]["name"], "time_s": time.perf_counter() - t0, "doc": doc}


def table(stance: str, settings: PaperSettings) -> dict[str, Any]:
    t = survey(scenario(stance), settings)
    t["paper"] = [{"hands": h, "stable": c, "unstable": u, "ratio": r} for h, (c, u, r) in PAPER_TABLES[stance].items()]
    return t


def plan(scenario: Any, hands: str | None, threshold_m: float | None, settings: PaperSettings,
         stance: str | None = None, estimator: dict[str, Any] | None = None, limits: bool = False,
         stable_postures: bool | None = None) -> dict[str, Any]:
    """A plan of a scenario (a name or a Scenario) with the report's iteration cap and planner
    (:meth:`PaperSettings.planner`); ``hands: auto`` surveys with ``estimator`` (the report's). Without effort and
    grip limits unless ``limits``; with the report's stable key postures unless ``stable_postures`` says."""
    sc = scenario if not isinstance(scenario, str) else resolve_scenario(scenario, stance=stance)
    if estimator:
        sc = with_overrides(sc, survey=estimator)
    sc = sc.model_copy(update={"limits": sc.limits.model_copy(update={"max_iterations": settings.plan_iterations})})
    t0 = time.perf_counter()
    doc = plan_scenario(sc, PlanOptions(hands=hands, threshold_m=threshold_m, limits=limits),
                        settings=settings.planner(stable_postures))
    doc.setdefault("stats", {})["wall_s"] = time.perf_counter() - t0
    return doc


def com_trace(doc: dict) -> np.ndarray:
    return np.array([p["com"][:2] for p in doc.get("trajectory", [])]).reshape(-1, 2)


def plan_summary(doc: dict) -> dict[str, Any]:
    traj = doc.get("trajectory", [])
    st = doc.get("stats", {})
    return {"status": doc["status"], "hands": doc.get("hands"), "threshold_m": doc["threshold_m"],
            "min_margin_m": doc.get("min_margin_m"), "duration_s": traj[-1]["t"] if traj else None,
            "planning_time_s": st.get("time_s"), "failure": (doc.get("failure") or {}).get("code"), "points": len(traj),
            "failures": st.get("failures") if doc["status"] == "solved" else (doc.get("failure") or {}).get("counts")}


def plan_pair(scenario: Any, hands: str, settings: PaperSettings, threshold_m: float | None = None) -> tuple[dict, dict, dict]:
    constrained = plan(scenario, hands, threshold_m, settings)
    free = plan(scenario, hands, 0.0, settings)
    differ = (constrained["status"] == "solved" and free["status"] == "solved"
              and [p["q"] for p in constrained["trajectory"]] != [p["q"] for p in free["trajectory"]])
    thr = constrained["threshold_m"]
    breaks = free["status"] == "solved" and free["min_margin_m"] < thr - 1e-4
    return ({"constrained": plan_summary(constrained), "unconstrained": plan_summary(free), "plans_differ": differ,
             "unconstrained_breaks_threshold": breaks}, constrained, free)
