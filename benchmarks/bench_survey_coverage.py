"""How often does a survey row's 95 % interval cover its R? A resampling simulation on real seeds.

Run:  python benchmarks/bench_survey_seeds.py --out DIR        (keeps each survey document)
      python benchmarks/bench_survey_coverage.py DIR [--rows crouched:right-left,upright:left-left] [--reps 100]
          [--fixed 24,64,256]

For each row, the population is the row's seeds from every document of its stance in DIR (all base seeds),
each under its key-path seed (the stratum). The truth is the pool's equal-share mix over that population,
sum over key paths of the mean C over sum of the mean N. A repeat draws 256 seeds with replacement, seed j
from pool member j mod 8 (as the survey hands them out), and judges them with the survey's own stopping rule
(``planner.survey.estimator.first_converged``: from seeds_min on, after whole rounds of the pool, at least
``MIN_SEEDS_PER_KEY_PATH`` seeds of each distinct key path, until the interval is within +-0.02, else at 256
seeds); it covers when the truth lies in the
interval it stops with. ``--fixed`` also gives the coverage of the interval of a fixed number of seeds (no
stopping rule). Prints, per row: the population's seeds and their sizes (median and largest), the
stopping rule's coverage and median seeds, and each fixed count's coverage.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from planner.survey.estimator import Estimator, SeedCount, first_converged, judge


def population(out: Path, stance: str, hands: str) -> list[dict]:
    """Every per-seed entry of the row in the stance's survey documents."""
    seeds = []
    for f in sorted(out.glob(f"survey-{stance}-*.json")):
        row = next(r for r in json.loads(f.read_text())["rows"] if r["hands"] == hands)
        seeds.extend(row["per_seed"])
    if not seeds:
        raise SystemExit(f"no seeds of {stance} {hands} in {out}")
    return seeds


def coverage(seeds: list[dict], hands: str, reps: int, fixed: list[int], seeds_max: int = 256) -> dict:
    est = Estimator(seeds_max=seeds_max)
    pool = sorted({s["key_path"]["seed"] for s in seeds})
    by = {k: [s for s in seeds if s["key_path"]["seed"] == k] for k in pool}
    truth = (sum(np.mean([s["stable"] for s in by[k]]) for k in pool)
             / sum(np.mean([s["stable"] + s["unstable"] for s in by[k]]) for k in pool))
    rng = np.random.default_rng(2026)
    covered, stops = 0, []
    fixed_cover = {k: 0 for k in fixed}
    for rep in range(reps):
        draw = [by[pool[j % len(pool)]][int(rng.integers(len(by[pool[j % len(pool)]])))] for j in range(seeds_max)]
        counts = [SeedCount(seed=1 + j, stable=s["stable"], unstable=s["unstable"], solved=True, status="done",
                            time_s=0.0, key_path=s["key_path"]) for j, s in enumerate(draw)]
        v = first_converged(counts, est, 1, hands, round_size=len(pool)) or judge(counts, est, 1, hands)
        stops.append(v.seeds)
        covered += v.interval[0] <= truth <= v.interval[1]
        for k in fixed:
            lo, hi = judge(counts[:k], est, 1, hands).interval
            fixed_cover[k] += lo <= truth <= hi
    n = np.array([s["stable"] + s["unstable"] for s in seeds])
    return {"truth": truth, "seeds": len(seeds), "size_median": int(np.median(n)), "size_max": int(n.max()),
            "coverage": covered / reps, "stop_median": float(np.median(stops)),
            "converged": float(np.mean([s < seeds_max for s in stops])),
            "fixed": {k: c / reps for k, c in fixed_cover.items()}}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path, help="the folder bench_survey_seeds.py --out wrote")
    ap.add_argument("--rows", default="upright:left-left,upright:left-right,crouched:left-right,crouched:right-left")
    ap.add_argument("--reps", type=int, default=100)
    ap.add_argument("--fixed", default="", help="also the coverage at these fixed seed counts (comma-separated)")
    args = ap.parse_args()
    fixed = [int(k) for k in args.fixed.split(",") if k]
    for item in args.rows.split(","):
        stance, hands = item.split(":")
        r = coverage(population(args.out, stance, hands), hands, args.reps, fixed)
        extra = "".join(f"; {k} seeds {c:.0%}" for k, c in r["fixed"].items())
        print(f"{stance:10s} {hands:11s} population {r['seeds']} seeds (poses median {r['size_median']}, largest "
              f"{r['size_max']}), R {r['truth']:.3f}: stopping rule covers {r['coverage']:.0%} of {args.reps} "
              f"(median {r['stop_median']:.0f} seeds, {r['converged']:.0%} converged){extra}", flush=True)


if __name__ == "__main__":
    main()
