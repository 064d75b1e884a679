"""The survey's estimator of R per hand configuration: seeds repeated until the interval is tight.

One seed is one counted exploration of the task (:func:`planner.survey.counting.explore_counted`):
C stable and U unstable poses. R = C / (C + U) pooled over seeds. Seeds ``seed``, ``seed`` + 1,
... are judged in that order, at each look (:func:`is_look`: from ``seeds_min`` on, after every whole
round of the row's key-path pool): a row whose 95 % interval lies within ``ci_half_width`` of its R on
both sides is converged and takes no more seeds; at ``seeds_max`` it stops unconverged. The interval
is the percentile bootstrap over seeds (2,000 resamples from a generator seeded by the survey's seed
and the row): resampling whole seeds keeps the strong correlation between the poses of one tree. A
row that explores several key paths in fixed shares is resampled within each key path's seeds (the
stratified bootstrap, :func:`ratio_interval`), and needs :data:`MIN_SEEDS_PER_KEY_PATH` seeds of each
distinct key path and :data:`MIN_UNSTABLE_POSES` unstable poses before it converges. A row with no
unstable pose at all has [1 - 3/(C + U), 1] (the "rule of three": a bootstrap cannot show an interval
there) and needs neither.

Seeds may run in parallel (on a seed map: forked workers or a Ray cluster, one seed per job) and still give the same answer as
in one process: every seed draws from its own generator, and a row is judged on its seeds in
order, so seeds that ran beyond its convergence are dropped.
"""

from __future__ import annotations

import time
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field
from typing import Any, Callable, Literal, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from planner.errors import Canceled
from planner.motion.trrt import TrrtSettings
from planner.survey.limits import over_limits
from planner.survey.counting import (
    CountedExploration,
    CountingSettings,
    ExploreLeg,
    explore_counted,
)
from planner.survey.seed_map import ForkedSeeds, SeedFn, SeedMap
from planner.termination import never
from schemas.common import HAND_CONFIGS

#: Bootstrap resamples of the seeds per interval.
BOOTSTRAP_RESAMPLES = 2000
#: Seeds handed to the workers ahead of the judgement, per worker.
LOOKAHEAD_PER_WORKER = 2
#: Seeds of each distinct key path a row with several needs before its stratified interval may call it converged.
MIN_SEEDS_PER_KEY_PATH = 6
#: Unstable poses a row needs before its bootstrap interval may call it converged (a row with none at all has the
#: rule of three's interval instead): a resample of seeds sees a handful of rare unstable poses as far less
#: variable than they are, so a row near R = 1 stopped on a narrow interval too early.
MIN_UNSTABLE_POSES = 20


class Estimator(BaseModel):
    """When a survey has seen enough (docs/contract.md section 4; the scenario's ``survey:`` field)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    until: Literal["solved", "states"] = Field("solved", description="solved: each seed explores until its tree reaches "
                                               "the goal (or the leg cap); states: each seed counts states_per_seed poses")
    ci_half_width: float = Field(0.02, gt=0, le=0.5, description="largest distance of the 95 % bounds from R")
    seeds_min: int = Field(10, ge=1, le=10_000)
    seeds_max: int = Field(256, ge=1, le=10_000)
    states_per_seed: int | None = Field(None, ge=1, le=1_000_000, description="until: states only")
    leg_cap_states: int = Field(20_000, ge=1, le=1_000_000, description="a leg that counted this many poses ends unsolved")
    key_paths: Literal["stratified"] = Field("stratified", description="stratified: each row explores the planner's "
                                             "key paths for the key-path seeds 1..key_path_pool, an equal share of seeds "
                                             "each (planner.survey.key_paths)")
    key_path_pool: int = Field(8, ge=1, le=64, description="key-path seeds per row")

    @model_validator(mode="after")
    def _check(self) -> "Estimator":
        if self.seeds_max < self.seeds_min:
            raise ValueError(f"seeds_max {self.seeds_max} is below seeds_min {self.seeds_min}")
        if self.until == "states" and self.states_per_seed is None:
            raise ValueError("until: states needs states_per_seed")
        return self

    def document(self) -> dict[str, Any]:
        """The survey document's ``estimator`` field."""
        doc = {"until": self.until, "ci_half_width": self.ci_half_width, "seeds_min": self.seeds_min,
               "seeds_max": self.seeds_max, "leg_cap_states": self.leg_cap_states, "key_paths": self.key_paths,
               "key_path_pool": self.key_path_pool}
        if self.until == "states":
            doc["states_per_seed"] = self.states_per_seed
        return doc


def ratio_interval(stable: np.ndarray, unstable: np.ndarray, rng: np.random.Generator,
                   resamples: int = BOOTSTRAP_RESAMPLES, strata: Sequence | None = None) -> tuple[float, float] | None:
    """The 95 % percentile-bootstrap interval of the pooled C / (C + U) over seeds (one entry per seed).

    ``strata`` (one label per seed: its key path, planner.survey.key_paths) makes it the stratified
    bootstrap: each stratum's seeds are resampled among themselves, so every resample keeps the
    stratification's fixed shares, and the interval covers the exploration's noise on each key path,
    not a spread between the key paths that the fixed shares do not have. It is the rescaling bootstrap
    of Rao and Wu (1988): n_h - 1 draws from a stratum of n_h seeds, scaled by n_h / (n_h - 1), so that
    its variance is the unbiased stratified one even with few seeds per stratum (a plain resample of n_h
    would shrink it by (n_h - 1) / n_h). With one stratum, or a stratum of one seed, it is the plain
    bootstrap over all seeds.

    With no unstable pose at all: [1 - 3/(C + U), 1]. None when nothing was counted.
    """
    c = np.asarray(stable, dtype=float)
    u = np.asarray(unstable, dtype=float)
    n = c + u
    total = float(n.sum())
    if total <= 0:
        return None
    if float(u.sum()) == 0.0:
        return max(0.0, 1.0 - 3.0 / total), 1.0
    groups = _strata_rows(strata, len(c))
    if groups is None:
        k = len(c)
        idx = rng.integers(0, k, size=(resamples, k))
        cs, ns = c[idx].sum(axis=1), n[idx].sum(axis=1)
    else:
        cs, ns = np.zeros(resamples), np.zeros(resamples)
        for rows in groups:
            m = len(rows)
            idx = rows[rng.integers(0, m, size=(resamples, m - 1))]
            cs += m / (m - 1) * c[idx].sum(axis=1)
            ns += m / (m - 1) * n[idx].sum(axis=1)
    ok = ns > 0
    r = cs[ok] / ns[ok]
    lo, hi = np.percentile(r, [2.5, 97.5])
    return float(lo), float(hi)


def _strata_rows(strata: Sequence | None, k: int) -> list[np.ndarray] | None:
    """The seeds of each stratum (in order of first appearance), or None for the plain bootstrap: no strata,
    one stratum, or a stratum with a single seed (whose noise the stratified resample could not see)."""
    if strata is None:
        return None
    labels = list(strata)
    if len(labels) != k:
        raise ValueError(f"{len(labels)} strata labels for {k} seeds")
    rows: dict = {}
    for i, s in enumerate(labels):
        rows.setdefault(s, []).append(i)
    if len(rows) < 2 or min(len(r) for r in rows.values()) < 2:
        return None
    return [np.array(r) for r in rows.values()]


def strata_sizes(strata: Sequence) -> list[int]:
    """How many seeds each stratum (label) holds."""
    sizes: dict = {}
    for s in strata:
        sizes[s] = sizes.get(s, 0) + 1
    return list(sizes.values())


def within(ratio: float, interval: tuple[float, float], half_width: float) -> bool:
    """Whether both bounds lie within ``half_width`` of ``ratio`` (a float tolerance of 1e-12)."""
    lo, hi = interval
    return ratio - lo <= half_width + 1e-12 and hi - ratio <= half_width + 1e-12


def bootstrap_rng(seed: int, hands: str, n_seeds: int) -> np.random.Generator:
    """The generator of one row's interval after ``n_seeds`` seeds (the same on any layout)."""
    return np.random.default_rng([int(seed), HAND_CONFIGS.index(hands), int(n_seeds), 4019])


@dataclass
class SeedCount:
    """One seed's counts, and its counted poses when they are kept."""

    seed: int
    stable: int
    unstable: int
    solved: bool
    status: str
    time_s: float
    legs: list[dict] = field(default_factory=list)
    states: CountedExploration | None = None
    #: counted poses over an effort or grip limit (None: the limits are off)
    over_limits: int | None = None
    #: the key path this seed explored (its key-path seed and nodes: planner.survey.key_paths)
    key_path: dict | None = None

    def entry(self) -> dict[str, Any]:
        out = {"seed": self.seed, "stable": self.stable, "unstable": self.unstable, "solved": self.solved}
        if self.key_path is not None:
            out["key_path"] = self.key_path
        return out


@dataclass
class Judgement:
    """A row's verdict on its first ``seeds`` seeds."""

    seeds: int
    stable: int
    unstable: int
    ratio: float | None
    interval: tuple[float, float] | None
    converged: bool


def strata_of(counts: list[SeedCount]) -> list:
    """Each seed's stratum: the key-path seed it explored (None when it names none)."""
    return [None if s.key_path is None else s.key_path.get("seed") for s in counts]


def paths_of(counts: list[SeedCount]) -> list:
    """Each seed's key path by its nodes (pool members with the same key path share one; None when it names none)."""
    return [None if s.key_path is None else repr(s.key_path.get("nodes")) for s in counts]


def judge(counts: list[SeedCount], estimator: Estimator, seed: int, hands: str) -> Judgement:
    """R and its interval over ``counts`` (seeds in order), and whether the row may stop there."""
    c = np.array([s.stable for s in counts])
    u = np.array([s.unstable for s in counts])
    C, U = int(c.sum()), int(u.sum())
    ratio = C / (C + U) if C + U else None
    strata = strata_of(counts)
    interval = ratio_interval(c, u, bootstrap_rng(seed, hands, len(counts)), strata=strata) if counts else None
    # The stratified interval needs each distinct key path's own noise (pool members the planner gave the same
    # key path share it) and enough unstable poses to see their spread; the rule of three (no unstable pose) needs
    # neither.
    sizes = strata_sizes(paths_of(counts))
    enough = U == 0 or ((len(sizes) < 2 or min(sizes) >= MIN_SEEDS_PER_KEY_PATH) and U >= MIN_UNSTABLE_POSES)
    converged = (ratio is not None and interval is not None and len(counts) >= estimator.seeds_min and enough
                 and within(ratio, interval, estimator.ci_half_width))
    return Judgement(len(counts), C, U, ratio, interval, converged)


def is_look(k: int, estimator: Estimator, round_size: int = 1) -> bool:
    """Whether a row may stop after ``k`` seeds: from ``seeds_min`` on, after whole rounds of its key-path pool
    (``round_size`` members, seed ``base + j`` exploring member ``j mod round_size``), and at ``seeds_max``.

    Whole rounds keep every key path's share of the seeds equal, the weights the stratification states (after
    a partial round the first members would weigh more). Judging once a round rather than after every seed
    also keeps the stopping rule's own error small: a row that may stop at the first narrow interval among many
    looks stops early on intervals that happen to be narrow (docs/survey.md, *The estimator*)."""
    if k < estimator.seeds_min:
        return False
    return k >= estimator.seeds_max or k % max(1, round_size) == 0


def first_converged(counts: list[SeedCount], estimator: Estimator, seed: int, hands: str,
                    start: int = 1, round_size: int = 1) -> Judgement | None:
    """The judgement at the first look (:func:`is_look`, from ``start`` seeds) at which the row converged, else None."""
    for k in range(max(start, estimator.seeds_min), len(counts) + 1):
        if not is_look(k, estimator, round_size):
            continue
        j = judge(counts[:k], estimator, seed, hands)
        if j.converged:
            return j
    return None


def seed_rng(seed: int, hands: str) -> np.random.Generator:
    """One seed's exploration generator: independent of the layout and of the other rows."""
    return np.random.default_rng([int(seed), HAND_CONFIGS.index(hands), 19])


def explore_seed(legs: list[ExploreLeg], evaluator, hands: str, seed: int, estimator: Estimator, *,
                 settings: CountingSettings | None = None, trrt: TrrtSettings | None = None,
                 should_stop: Callable[[], bool] | None = None, keep_states: bool = False) -> SeedCount:
    """One seed's counted exploration of a configuration's legs."""
    t0 = time.perf_counter()
    budget = estimator.states_per_seed if estimator.until == "states" else None
    ex = explore_counted(legs, evaluator, seed_rng(seed, hands), leg_cap_states=estimator.leg_cap_states, budget=budget,
                         settings=settings, trrt=trrt, should_stop=should_stop)
    limits = getattr(evaluator, "limits", None)  # a planner.survey.limits.LimitedEvaluator checks them
    over = (None if limits is None or ex.status == "canceled"
            else over_limits(limits, ex.q, ex.holding, ex.object_pose, should_stop or never))
    return SeedCount(seed=seed, stable=ex.n_stable, unstable=ex.n_unstable, solved=ex.solved, status=ex.status,
                     time_s=time.perf_counter() - t0, legs=ex.stats["legs"], states=ex if keep_states else None,
                     over_limits=over)


# -- running rows ---------------------------------------------------------------------------------

@dataclass
class RowWork:
    """What one configuration's seeds need: its pool of key paths' legs (None with the reason when it has
    none); seed ``base + j`` explores pool member ``j mod len(legs)`` (planner.survey.key_paths)."""

    hands: str
    legs: list[list[ExploreLeg]] | None
    reason: str | None = None
    stats: dict = field(default_factory=dict)
    counts: list[SeedCount] = field(default_factory=list)
    verdict: Judgement | None = None
    #: what each pool member's per-seed entry names (its key-path seed and nodes), in pool order
    key_paths: list[dict] = field(default_factory=list)

    def member(self, seed: int, base: int) -> int:
        """The pool member survey seed ``seed`` explores (seeds counted from ``base``)."""
        return (int(seed) - int(base)) % len(self.legs)

    def explore(self, evaluator, seed: int, base: int, estimator: "Estimator", **kw: Any) -> SeedCount:
        """Survey seed ``seed`` on its pool member's legs: a pure function of (row, seed)."""
        k = self.member(seed, base)
        count = explore_seed(self.legs[k], evaluator, self.hands, seed, estimator, **kw)
        count.key_path = self.key_paths[k] if k < len(self.key_paths) else None
        return count


def run_rows(rows: list[RowWork], evaluator, estimator: Estimator, seed: int, *, workers: int = 1,
             settings: CountingSettings | None = None, trrt: TrrtSettings | None = None,
             should_stop: Callable[[], bool] = never, progress: Callable[[float, str], None] = lambda f, m: None,
             keep_states: bool = False, can_fork: bool = False, seed_map: SeedMap | None = None,
             seed_fn: SeedFn | None = None) -> None:
    """Run each row's seeds until it converged or reached ``seeds_max``; fills ``counts`` and ``verdict``.

    On ``seed_map`` when given (``seed_fn``, a pure per-seed function, is what it runs; by default
    :func:`explore_seed` on the rows' legs), else in forked workers when ``can_fork`` and ``workers`` > 1,
    else in this process; the verdicts are the same.
    """
    live = [r for r in rows if r.legs]
    for r in rows:
        if not r.legs:
            r.verdict = Judgement(0, 0, 0, None, None, False)

    def settle(r: RowWork) -> bool:
        """Judge the row on its seeds so far, when they make a look; True when it needs no more."""
        if not is_look(len(r.counts), estimator, len(r.legs)):
            return False
        j = judge(r.counts, estimator, seed, r.hands)
        if j.converged or len(r.counts) >= estimator.seeds_max:
            r.verdict = j
            return True
        return False

    total = max(1, len(live))
    if seed_map is None and (workers <= 1 or not can_fork) or not live:
        for i, r in enumerate(live):
            done = False
            while not done:
                if should_stop():
                    raise Canceled()
                sd = seed + len(r.counts)
                r.counts.append(r.explore(evaluator, sd, seed, estimator, settings=settings, trrt=trrt,
                                          should_stop=should_stop, keep_states=keep_states))
                if r.counts[-1].status == "canceled":
                    raise Canceled()
                done = settle(r)
                progress((i + min(len(r.counts) / max(estimator.seeds_min, 1), 0.99)) / total,
                         f"{r.hands}: {len(r.counts)} seeds")
        return
    by_hands = {r.hands: r for r in live}

    def in_process(hands: str, sd: int, keep: bool) -> SeedCount:
        return by_hands[hands].explore(evaluator, sd, seed, estimator, settings=settings, trrt=trrt, keep_states=keep)

    seed_map = seed_map or ForkedSeeds(workers)
    session = seed_map.open(seed_fn or in_process)
    canceled = True
    try:
        results: dict[str, dict[int, SeedCount]] = {r.hands: {} for r in live}
        issued: dict[str, int] = {r.hands: 0 for r in live}
        open_rows = list(live)
        pending: dict[Future, tuple[str, int]] = {}

        def top_up() -> None:
            # Round-robin over the open rows, seeds in order, a few jobs ahead per slot.
            while len(pending) < seed_map.slots * LOOKAHEAD_PER_WORKER:
                candidates = [r for r in open_rows if issued[r.hands] < estimator.seeds_max]
                if not candidates:
                    return
                r = min(candidates, key=lambda r: (issued[r.hands], rows.index(r)))
                sd = seed + issued[r.hands]
                issued[r.hands] += 1
                pending[session.submit(r.hands, sd, keep_states)] = (r.hands, sd)

        top_up()
        while open_rows:
            finished, _ = wait(list(pending), timeout=0.2, return_when=FIRST_COMPLETED)
            if should_stop():
                raise Canceled()
            for f in finished:
                hands, sd = pending.pop(f)
                results[hands][sd] = f.result()
            for r in list(open_rows):
                got = results[r.hands]
                while seed + len(r.counts) in got:
                    r.counts.append(got.pop(seed + len(r.counts)))
                    if settle(r):
                        open_rows.remove(r)
                        break
                progress(sum(min(len(x.counts) / max(estimator.seeds_min, 1), 1.0) for x in live) / total * 0.99,
                         f"{sum(len(x.counts) for x in live)} seeds judged")
            for f, (hands, _) in list(pending.items()):
                if all(r.hands != hands for r in open_rows):
                    session.cancel(f)
                    del pending[f]
            top_up()
        canceled = False
    finally:
        session.close(cancel=canceled)
