"""Graph search: the compiled CSR Dijkstra against networkx's Dijkstra on the same regrasp graphs.

Run: python benchmarks/bench_graph.py [--scenarios upright,drill-handover] [--repeats 20]
For each scenario and hand configuration: graph size, build time, and the median time of one
search (what the lazy search repeats after every removal) with scipy on the flat arrays and with
networkx on the exported DiGraph. Both must find the same cost (asserted).
"""

from __future__ import annotations

import argparse
import statistics
import time

import networkx as nx

from planner.blas_threads import one_blas_thread
from planner.regrasp.graph import SINK, SOURCE, RegraspGraph
from planner.regrasp.hand_config_planner import HandConfigPlanner
from planner.regrasp.search_data import SearchData
from planner.regrasp.task import Task
from planner.scene.scenarios import load_builtin


def median_s(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


@one_blas_thread  # as the CLI's plans run (planner/blas_threads.py)
def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenarios", default="upright,drill-handover")
    ap.add_argument("--hands", default="right-right,right-left")
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    print(f"{'scenario':<15} {'hands':<11} {'nodes':>6} {'edges':>7} {'build ms':>9} {'scipy ms':>9} {'networkx ms':>12} {'ratio':>6}")
    for name in args.scenarios.split(","):
        sc = load_builtin(name)
        task = Task(sc, None, threshold_m=sc.threshold_m)
        data = SearchData(task)
        for hands in args.hands.split(","):
            planner = HandConfigPlanner(task, hands, data=data)
            spec = planner.graph_spec()
            t0 = time.perf_counter()
            graph = RegraspGraph(spec, task.settings.weights)
            build = time.perf_counter() - t0
            exported = graph.to_networkx()
            found = graph.shortest()
            reference = nx.dijkstra_path_length(exported, SOURCE, SINK, weight="weight")
            assert found is not None and abs(found[1] - reference) < 1e-9, (found, reference)
            t_scipy = median_s(graph.shortest, args.repeats)
            t_nx = median_s(lambda: nx.dijkstra_path(exported, SOURCE, SINK, weight="weight"), max(3, args.repeats // 4))
            n, e = graph.size
            print(f"{name:<15} {hands:<11} {n:>6} {e:>7} {build * 1e3:>9.1f} {t_scipy * 1e3:>9.2f} {t_nx * 1e3:>12.1f} "
                  f"{t_nx / t_scipy:>6.0f}")


if __name__ == "__main__":
    main()
