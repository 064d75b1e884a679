"""Fingerprints of the planner's behaviour, for checking that a change which should not alter
behaviour does not: the SHA-256 of each built-in scenario's plan document (with `stats` left
out and mesh paths reduced to their file names) and the crouched survey's counts.

Runs the installed `regrasp` command, so the same script compares any two checkouts:

    python scripts/behaviour_fingerprint.py --out before.json   # in one checkout
    python scripts/behaviour_fingerprint.py --out after.json    # in the other
    diff before.json after.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

SCENARIOS = ("upright", "staggered", "crouched", "one-legged", "drill-handover", "drill-upright")


def _normalised(value):
    """The document with every absolute path (a string ending in a file name) cut to its name."""
    if isinstance(value, dict):
        return {k: _normalised(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_normalised(v) for v in value]
    if isinstance(value, str) and value.startswith("/"):
        return Path(value).name
    return value


def plan_fingerprint(name: str, workdir: Path) -> dict:
    out = workdir / f"{name}.json"
    done = subprocess.run(["regrasp", "plan", "--scenario", name, "--out", str(out), "--quiet"],
                          stdout=subprocess.DEVNULL, timeout=600)
    if done.returncode not in (0, 1):  # 1: the plan is infeasible, a result like any other (it is fingerprinted)
        raise RuntimeError(f"regrasp plan --scenario {name} failed with exit code {done.returncode}")
    doc = json.loads(out.read_text())
    doc.pop("stats", None)
    canonical = json.dumps(_normalised(doc), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return {"status": doc["status"], "hands": doc.get("hands"), "points": len(doc.get("trajectory", [])),
            "sha256": hashlib.sha256(canonical.encode()).hexdigest()}


def survey_counts(states: int) -> dict:
    out = subprocess.run(["regrasp", "survey", "--scenario", "crouched", "--states", str(states), "--workers", "1",
                          "--json"], check=True, capture_output=True, text=True, timeout=900).stdout
    doc = json.loads(out)
    return {row["hands"]: [row.get("stable"), row.get("unstable")] for row in doc["rows"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--survey-states", type=int, default=2000, help="states per configuration; 0 skips the survey")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        result = {"plans": {name: plan_fingerprint(name, Path(tmp)) for name in SCENARIOS},
                  "crouched_survey": survey_counts(args.survey_states) if args.survey_states else None}
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(json.dumps(result, indent=2, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
