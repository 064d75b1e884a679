"""Do independent surveys agree? Each paper stance surveyed from three base seeds whose seed ranges never
meet (1, 10001, 20001), with the survey's default estimator, and how long each converged survey took.

Targets: at least 95 % of same-row pairs of 95 % intervals overlap; whenever one run separates its best
row (no tie), the others recommend the same row; a converged survey of one stance in <= 60 s on 2 cores.
Run: python benchmarks/bench_survey_seeds.py [--stances upright,staggered,crouched,one-legged] [--workers 2] [--out DIR]
Each survey's line ends with the machine's load average (1 min) when it ended; ``--out`` keeps each survey
document (``survey-STANCE-SEED.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from itertools import combinations
from pathlib import Path

from planner.scene.scenarios import resolve_scenario
from planner.survey.runner import run_survey

BASE_SEEDS = (1, 10001, 20001)


def overlap(a: list[float] | None, b: list[float] | None) -> bool | None:
    if not a or not b:
        return None
    return a[0] <= b[1] and b[0] <= a[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--stances", default="upright,staggered,crouched,one-legged")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="write each survey document here")
    args = ap.parse_args()
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
    pairs = overlapping = 0
    disagreements = []
    for stance in args.stances.split(","):
        docs = {}
        for seed in BASE_SEEDS:
            t0 = time.perf_counter()
            doc, _ = run_survey(resolve_scenario(stance), seed=seed, workers=args.workers, keep_states=False)
            docs[seed] = doc
            if args.out is not None:
                (args.out / f"survey-{stance}-{seed}.json").write_text(json.dumps(doc))
            rows = "  ".join(f"{r['hands']} " + ("n/a" if r["ratio"] is None else
                                                 f"{r['ratio']:.3f} [{r['ratio_ci95'][0]:.3f}, {r['ratio_ci95'][1]:.3f}] "
                                                 f"{r['seeds']}s") for r in doc["rows"])
            tie = f" (tie: {', '.join(doc['indistinguishable'])})" if doc["indistinguishable"] else ""
            print(f"{stance:10s} seed {seed:5d}: {time.perf_counter() - t0:6.1f} s  best {doc['recommended']}{tie}  {rows}  (load {os.getloadavg()[0]:.1f})",
                  flush=True)
        for a, b in combinations(BASE_SEEDS, 2):
            for ra, rb in zip(docs[a]["rows"], docs[b]["rows"]):
                o = overlap(ra["ratio_ci95"], rb["ratio_ci95"])
                if o is not None:
                    pairs += 1
                    overlapping += o
        separated = [s for s in BASE_SEEDS if docs[s]["recommended"] and not docs[s]["indistinguishable"]]
        for s in separated:
            others = {docs[t]["recommended"] for t in BASE_SEEDS if t != s}
            if others != {docs[s]["recommended"]}:
                disagreements.append(f"{stance}: seed {s} separates {docs[s]['recommended']}, others {sorted(others)}")
    print(f"same-row interval pairs overlapping: {overlapping} of {pairs} ({100 * overlapping / max(pairs, 1):.1f} %)")
    print("separated best rows agree" if not disagreements else "disagreements: " + "; ".join(disagreements))


if __name__ == "__main__":
    main()
