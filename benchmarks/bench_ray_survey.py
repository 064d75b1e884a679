"""Benchmark: a survey on a one-node and on a two-node Ray cluster, and Ray's cost per task (prints its figures).

Starts Ray clusters on this machine on 127.0.0.1 only (tests/service/ray_two_nodes.py; token auth, Ray's files
in a temporary directory), one CPU per node, and runs the same survey (small-box, fixed states per seed, fixed
seeds) on each as `regrasp survey --ray-address` would, then in this process alone. Ray's cost per task is
measured with empty tasks (submit to result, one CPU) and as the survey's extra time over the seeds' own.

    python benchmarks/bench_ray_survey.py [--states 300] [--seeds 4] [--empty 200]
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HELPER = ROOT / "tests" / "service" / "ray_two_nodes.py"


def start_cluster(temp_dir: str, nodes: int) -> tuple[subprocess.Popen, dict, dict]:
    env = dict(os.environ, RAY_TMPDIR=temp_dir, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(16),
               RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_USAGE_STATS_ENABLED="0", PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, str(HELPER), temp_dir, "1", str(nodes)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, text=True)
    return proc, json.loads(proc.stdout.readline()), env


def on_cluster(nodes: int, states: int, seeds: int, empty: int) -> dict:
    """In a driver process of its own (one Ray connection per process): the survey and the empty tasks."""
    with tempfile.TemporaryDirectory(prefix="rb", dir="/tmp") as temp_dir:
        proc, info, env = start_cluster(temp_dir, nodes)
        try:
            out = subprocess.run([sys.executable, __file__, "--driver", info["address"], "--states", str(states),
                                  "--seeds", str(seeds), "--empty", str(empty)], env=env, capture_output=True,
                                 text=True, timeout=1800)
            if out.returncode != 0:
                raise RuntimeError(out.stderr[-2000:])
            return json.loads(out.stdout.strip().splitlines()[-1])
        finally:
            proc.stdin.close()
            proc.wait(60)


def survey_args(states: int, seeds: int):  # type: ignore[no-untyped-def]
    from planner.scene.scenarios import load_scenario
    from planner.survey.estimator import Estimator

    return (load_scenario(ROOT / "tests" / "data" / "small-box.yaml"),
            Estimator(until="states", states_per_seed=states, seeds_min=seeds, seeds_max=seeds))


def driver(address: str, states: int, seeds: int, empty: int) -> None:
    import ray

    from planner.survey.runner import run_survey
    from service.executors.ray_seeds import RaySeeds, connect

    connect(address)
    noop = ray.remote(num_cpus=1)(lambda: None)
    ray.get(noop.remote())  # a warm worker
    t0 = time.perf_counter()
    for _ in range(empty):
        ray.get(noop.remote())
    per_task_s = (time.perf_counter() - t0) / empty
    scenario, est = survey_args(states, seeds)
    seed_map = RaySeeds()
    t0 = time.perf_counter()
    doc, _ = run_survey(scenario, estimator=est, keep_states=False, seed_map=seed_map)
    wall = time.perf_counter() - t0
    seed_s = sum(c["exploration_s"] for c in doc["stats"]["configurations"].values())
    key_s = sum(c.get("key_poses_s", 0.0) for c in doc["stats"]["configurations"].values())
    print(json.dumps({"wall_s": wall, "seeds": len(seed_map.placements), "nodes": len(seed_map.nodes()),
                      "empty_task_s": per_task_s, "seed_s": seed_s, "key_poses_s": key_s,
                      "ratios": [r["ratio"] for r in doc["rows"]]}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=300)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--empty", type=int, default=200)
    ap.add_argument("--driver", help=argparse.SUPPRESS)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    if args.driver:
        driver(args.driver, args.states, args.seeds, args.empty)
        return
    from planner.survey.runner import run_survey

    scenario, est = survey_args(args.states, args.seeds)
    t0 = time.perf_counter()
    local, _ = run_survey(scenario, estimator=est, workers=1, keep_states=False)
    local_s = time.perf_counter() - t0
    print(f"survey small-box, {args.states} states x {args.seeds} seeds x 4 configurations, one CPU per node")
    print(f"  this process alone (local executor, 1 worker): {local_s:.1f} s")
    for nodes in (1, 2):
        r = on_cluster(nodes, args.states, args.seeds, args.empty)
        same = r["ratios"] == [row["ratio"] for row in local["rows"]]
        overhead = max(r["wall_s"] - r["key_poses_s"] - r["seed_s"] / nodes, 0.0) / max(r["seeds"], 1)
        print(f"  Ray, {nodes} node(s): {r['wall_s']:.1f} s ({r['seeds']} seeds on {r['nodes']} node(s); "
              f"same ratios as local: {same}); empty task round trip {r['empty_task_s'] * 1000:.2f} ms; "
              f"survey time beyond key poses and seeds/nodes: {overhead * 1000:.0f} ms per seed task")


if __name__ == "__main__":
    main()
