"""Benchmark of the planning service's API (prints its figures; no pass/fail).

1. Submit and poll latency (p50/p95) with N concurrent clients while every worker
   is busy planning (CPU-bound jobs fill all workers; the API process never plans).
   Target: p95 <= 50 ms.
2. Throughput of trivial jobs per minute, embedded (local spawn workers) versus Ray.

    python benchmarks/bench_api.py [--clients 50] [--rounds 10] [--trivial 200] [--workers 2] [--no-ray]

Each scenario runs a real `regrasp serve` on 127.0.0.1 (SQLite store in a temp dir).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import psutil

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
TOKEN = "bench-token-planner"
#: Niceness of this benchmark process while it generates load (the server keeps its own priority).
CLIENT_NICE = 5
#: A client polls its job this many times after submitting it.
POLLS_PER_SUBMIT = 3
sys.path.insert(0, str(HERE))
from bench_api_handlers import HANDLERS  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(data_dir: Path, workers: int, executor: str = "local") -> tuple[subprocess.Popen, str]:
    port = free_port()
    env = dict(os.environ)
    env.update({
        "PYTHONPATH": os.pathsep.join([str(HERE), str(ROOT), env.get("PYTHONPATH", "")]),
        "REGRASP_TOKENS": json.dumps({TOKEN: {"user": "bench", "roles": ["planner", "approver", "operator"]}}),
        "REGRASP_HANDLERS": json.dumps(HANDLERS), "REGRASP_CHECK_SCENARIO_NAMES": "false",
        "REGRASP_PRELOAD_ROBOT": "false", "REGRASP_QUEUE_LIMIT": "100000", "REGRASP_AUDIT": "false",
        "REGRASP_BRIDGE_CONNECT": json.dumps([f"tcp/127.0.0.1:{free_port()}"]),
    })
    proc = subprocess.Popen([sys.executable, "-m", "service.cli.main", "serve", "--port", str(port), "--data-dir",
                             str(data_dir), "--workers", str(workers), "--executor", executor, "--log-level", "warning"],
                            cwd=ROOT, env=env, stdout=open(data_dir / "server.log", "ab"), stderr=subprocess.STDOUT,
                            start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 400  # a local Ray instance takes 5-30 s to start on a loaded machine
    while time.monotonic() < deadline:
        try:
            if httpx.get(url + "/healthz", timeout=1).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise RuntimeError("server did not start")


def stop_server(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(20)
    except subprocess.TimeoutExpired:
        proc.kill()
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def wait_done(c: httpx.Client, ids: list[str], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        jobs = c.get("/v1/jobs", params={"limit": 500, "state": "planned"}).json()["total"]
        if jobs >= len(ids):
            return
        time.sleep(0.2)
    raise RuntimeError("jobs did not finish in time")


def latency_buckets(url: str) -> dict[tuple[str, str], dict[float, float]]:
    """Cumulative bucket counts of the server's request-latency histogram, by (method, route)."""
    out: dict[tuple[str, str], dict[float, float]] = {}
    for line in httpx.get(url + "/metrics").text.splitlines():
        if not line.startswith("regrasp_http_request_duration_seconds_bucket{"):
            continue
        labels, value = line[line.index("{") + 1:line.rindex("}")], float(line.rsplit(" ", 1)[1])
        fields = dict(part.split("=", 1) for part in labels.split(","))
        fields = {k: v.strip('"') for k, v in fields.items()}
        if not fields["status"].startswith("2"):
            continue
        le = float("inf") if fields["le"] == "+Inf" else float(fields["le"])
        key = (fields["method"], fields["route"])
        out.setdefault(key, {})
        out[key][le] = out[key].get(le, 0.0) + value
    return out


def bucket_quantile(before: dict[float, float], after: dict[float, float], q: float) -> float:
    """Upper bound (s) of the bucket holding the q-quantile of the requests between two scrapes."""
    edges = sorted(after)
    counts = [after[e] - before.get(e, 0.0) for e in edges]
    total = counts[-1]
    for edge, cum in zip(edges, counts):
        if cum >= q * total:
            return edge
    return float("inf")


def pct(values: list[float], q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(round(q * (len(values) - 1))))]


async def latency_run(url: str, clients: int, rounds: int, think_s: float) -> dict[str, list[float]]:
    """Each client submits a job, then polls it; ``think_s`` between requests (0 = closed loop, saturation)."""
    submit_ms: list[float] = []
    poll_ms: list[float] = []
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, limits=limits,
                                 timeout=60) as c:
        async def one(i: int) -> None:
            await asyncio.sleep(think_s * i / clients)  # spread the clients over one think period
            for k in range(rounds):
                t = time.perf_counter()
                r = await c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "trivial", "seed": i * 1000 + k}})
                submit_ms.append((time.perf_counter() - t) * 1000)
                r.raise_for_status()
                for _ in range(POLLS_PER_SUBMIT):
                    await asyncio.sleep(think_s)
                    t = time.perf_counter()
                    (await c.get(r.headers["location"])).raise_for_status()
                    poll_ms.append((time.perf_counter() - t) * 1000)
                await asyncio.sleep(think_s)

        await asyncio.gather(*(one(i) for i in range(clients)))
    return {"submit": submit_ms, "poll": poll_ms}


def bench_latency(args: argparse.Namespace) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        proc, url = start_server(Path(tmp), args.workers)
        try:
            with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}) as c:
                busy = [c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "busy-600"}}).json()["id"]
                        for _ in range(args.workers)]
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline:
                    if all(c.get(f"/v1/jobs/{j}").json()["state"] == "planning" for j in busy):
                        break
                    time.sleep(0.2)
                os.nice(CLIENT_NICE)  # the load generator must not starve the server it measures
                api = psutil.Process(proc.pid)
                cpu0 = sum(api.cpu_times()[:2])
                hist0 = latency_buckets(url)
                t0 = time.perf_counter()
                res = asyncio.run(latency_run(url, args.clients, args.rounds, args.think_s))
                elapsed = time.perf_counter() - t0
                cpu = sum(api.cpu_times()[:2]) - cpu0
                hist1 = latency_buckets(url)
                n = sum(len(v) for v in res.values())
                print(f"load: {args.clients} clients, {args.think_s} s between a client's requests -> "
                      f"{n / elapsed:.0f} requests/s over {elapsed:.1f} s; machine load average "
                      f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
                print(f"API process CPU: {cpu / n * 1000:.2f} ms per request, {cpu / elapsed * 100:.0f}% of one core "
                      "(it never plans; workers run at nice 10)")
                sat = asyncio.run(latency_run(url, args.clients, 2, 0.0))
                n_sat = sum(len(v) for v in sat.values())
                sat_s = sum(sum(v) for v in sat.values()) / 1000 / args.clients
                health = c.get("/healthz").json()
                for j in busy:
                    c.post(f"/v1/jobs/{j}/cancel")
            for key, label in ((("POST", "/v1/jobs"), "submit"), (("GET", "/v1/jobs/{job_id}"), "poll")):
                b0, b1 = hist0.get(key, {}), hist1.get(key, {})
                if b1:
                    print(f"{label:6s} latency inside the server (histogram bucket bounds): "
                          f"p50 <= {bucket_quantile(b0, b1, 0.5) * 1000:.0f} ms, p95 <= {bucket_quantile(b0, b1, 0.95) * 1000:.0f} ms")
            for name, values in res.items():
                print(f"{name:6s} latency at the clients, {args.clients} clients, all {args.workers} workers busy: "
                      f"n={len(values)} p50={statistics.median(values):.1f} ms p95={pct(values, 0.95):.1f} ms "
                      f"max={max(values):.1f} ms")
            print(f"saturation (closed loop, no think time): {n_sat} requests, mean latency "
                  f"{statistics.mean(sat['submit'] + sat['poll']):.0f} ms, ~{n_sat / sat_s:.0f} requests/s")
            print(f"queue depth at the end: {health['queue_depth']}")
        except Exception:
            print((Path(tmp) / "server.log").read_text()[-3000:])
            raise
        finally:
            stop_server(proc)


def bench_throughput(args: argparse.Namespace, executor: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        proc, url = start_server(Path(tmp), args.workers, executor)
        try:
            with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30) as c:
                warm = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "trivial", "seed": -0 + 1}}).json()
                wait_done(c, [warm["id"]], 180)  # workers up (Ray needs seconds to start)
                t = time.perf_counter()
                ids = [c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "trivial", "seed": 10 + i}}).json()["id"]
                       for i in range(args.trivial)]
                wait_done(c, [warm["id"], *ids], 600)
                elapsed = time.perf_counter() - t
            print(f"throughput, {executor:5s} executor, {args.workers} workers: {args.trivial} trivial jobs in "
                  f"{elapsed:.1f} s = {args.trivial / elapsed * 60:.0f} jobs/min")
        finally:
            stop_server(proc)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=5, help="submissions per client (each polled 3 times)")
    ap.add_argument("--think-s", type=float, default=0.5, help="pause between one client's requests, s")
    ap.add_argument("--trivial", type=int, default=200, help="trivial jobs for the throughput runs")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-ray", action="store_true")
    args = ap.parse_args()
    bench_latency(args)
    bench_throughput(args, "local")
    if not args.no_ray:
        try:
            import ray  # noqa: F401
        except ImportError:
            print("ray not installed: no Ray throughput figure")
            return
        bench_throughput(args, "ray")


if __name__ == "__main__":
    main()
