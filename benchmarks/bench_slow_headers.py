"""Benchmark: slow-header connections against the header deadline (prints its figures; no pass/fail).

Opens N connections to a real `regrasp serve` on 127.0.0.1 that each send part of a request line or
of its headers and then nothing, and probes /healthz every 0.25 s until the server has closed them all.
Prints when the first and the last slow connection were closed (from their opening) against the
stated deadline, and the /healthz latencies meanwhile.

    python benchmarks/bench_slow_headers.py [--connections 200] [--timeout-s 10]
"""

from __future__ import annotations

import argparse
import os
import selectors
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parent.parent
PARTIAL = (b"GET /healthz HTTP/1.1\r\nHost: x\r\n", b"GET /hea", b"POST /v1/jobs HTTP/1.1\r\nContent-Ty")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connections", type=int, default=200)
    ap.add_argument("--timeout-s", type=float, default=10.0, help="the server's header_read_timeout_s")
    args = ap.parse_args()
    port = free_port()
    with tempfile.TemporaryDirectory() as data:
        env = dict(os.environ, PYTHONPATH=str(ROOT), REGRASP_HEADER_READ_TIMEOUT_S=str(args.timeout_s), REGRASP_TOKENS="{}")
        server = subprocess.Popen([sys.executable, "-m", "service.cli.main", "serve", "--port", str(port), "--data-dir",
                                   data, "--workers", "0", "--log-level", "warning"], cwd=ROOT, env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            url = f"http://127.0.0.1:{port}"
            for _ in range(300):
                try:
                    if httpx.get(url + "/healthz", timeout=1).status_code == 200:
                        break
                except httpx.HTTPError:
                    time.sleep(0.1)
            sel = selectors.DefaultSelector()
            opened: dict[socket.socket, float] = {}
            for i in range(args.connections):
                s = socket.create_connection(("127.0.0.1", port), timeout=5)
                s.sendall(PARTIAL[i % len(PARTIAL)])
                s.setblocking(False)
                opened[s] = time.monotonic()
                sel.register(s, selectors.EVENT_READ)
            closed: dict[socket.socket, float] = {}
            probes: list[float] = []
            codes: list[int] = []
            next_probe = time.monotonic()
            end = time.monotonic() + args.timeout_s + 30
            with httpx.Client(base_url=url, timeout=5) as c:
                while len(closed) < len(opened) and time.monotonic() < end:
                    for key, _ in sel.select(timeout=0.05):
                        try:
                            data_in = key.fileobj.recv(4096)
                        except ConnectionResetError:
                            data_in = b""
                        if not data_in:
                            closed[key.fileobj] = time.monotonic()
                            sel.unregister(key.fileobj)
                    if time.monotonic() >= next_probe:
                        p0 = time.monotonic()
                        codes.append(c.get("/healthz").status_code)
                        probes.append(time.monotonic() - p0)
                        next_probe = time.monotonic() + 0.25
            held = [closed[s] - opened[s] for s in closed]
            print(f"slow-header connections: {len(opened)}, closed by the server: {len(closed)}, "
                  f"deadline {args.timeout_s:g} s")
            if held:
                print(f"  closed after: first {min(held):.2f} s, median {statistics.median(held):.2f} s, "
                      f"last {max(held):.2f} s (from each connection's opening)")
            print(f"  /healthz meanwhile: {len(probes)} probes, {sum(c == 200 for c in codes)} answered 200, "
                  f"median {statistics.median(probes) * 1000:.1f} ms, max {max(probes) * 1000:.1f} ms")
            for s in opened:
                s.close()
        finally:
            server.terminate()
            server.wait(15)


if __name__ == "__main__":
    main()
