"""Hostile inputs against a real `regrasp serve` on 127.0.0.1 (prints its counts; no pass/fail).

Throws crafted requests at the API: file names and paths where names belong, unknown names,
wrong types, non-finite numbers, oversized and deeply nested bodies, chunked and slow bodies,
malformed JSON and encodings, wrong media types, bad headers and tokens, wrong methods on
every route, odd path and query parameters. It prints how many inputs it tried, the answers by
status, how many were 5xx, how many hung (no answer within HANG_S) and the slowest /healthz
seen meanwhile.

    python benchmarks/bench_hostile.py [--hang-s 30]

The server runs with the default settings, no workers (accepted jobs stay queued) and a
SQLite store in a temporary directory.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

import httpx

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.service.conftest import free_port  # noqa: E402  (the service tests' helpers, one copy)
from tests.service.conftest import inline_scenario as inline  # noqa: E402
TOKEN = "bench-hostile-planner"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
#: An answer later than this is a hang (the server's body read timeout is 10 s).
HANG_S = 30.0

PATHS = ["/etc/passwd", "../../etc/passwd", "tokens.json", "./x.yaml", "var/jobs.sqlite", "..", ".hidden",
         "C:\\Windows\\win.ini", "file:///etc/passwd", "x" * 300, "a/b", "%2e%2e%2fetc", "upright.yaml",
         "\u0000upright", "~/.ssh/id_rsa"]
UNKNOWN = ["kneeling", "nao", "UPRIGHT", "upright ", "teapot"]
WRONG_TYPES: list[Any] = ["1", True, 1.5, [], {}, None, 2**70, -1, "0.06", [1, 2], {"$ne": 1}]


def job(request: dict[str, Any], kind: str = "plan") -> bytes:
    return json.dumps({"kind": kind, "request": request}).encode()


def cases() -> list[tuple[str, str, dict[str, str], bytes]]:
    """(method, path, headers, body) of every hostile HTTP request."""
    out: list[tuple[str, str, dict[str, str], bytes]] = []
    js = {**AUTH, "Content-Type": "application/json"}
    for p in PATHS + UNKNOWN:
        out += [("POST", "/v1/jobs", js, job({"scenario": "upright", "stance": p})),
                ("POST", "/v1/jobs", js, job({"scenario": p})),
                ("POST", "/v1/jobs", js, job({"scenario": "upright", "robot": p})),
                ("POST", "/v1/jobs", js, job({"scenario": inline(robot=p)})),
                ("POST", "/v1/jobs", js, job({"scenario": inline(stance=p)})),
                ("POST", "/v1/jobs", js, job({"scenario": inline(object={"shape": "mesh", "mesh": {"path": p}, "mass_kg": 1})})),
                ("POST", "/v1/jobs", js, job({"scenario": inline(object={"shape": "mesh", "mesh": {"name": p}, "mass_kg": 1})}))]
    for field in ("scenario", "stance", "robot", "threshold_m", "hands", "seed", "states_per_configuration", "time_limit_s"):
        for value in WRONG_TYPES:
            out.append(("POST", "/v1/jobs", js, job({"scenario": "upright", field: value})))
    for raw in (b"NaN", b"Infinity", b"-Infinity", b"1e400"):
        out.append(("POST", "/v1/jobs", js, b'{"kind": "plan", "request": {"scenario": "upright", "threshold_m": ' + raw + b"}}"))
        out.append(("POST", "/v1/jobs", js, job({"scenario": inline()}).replace(b"0.8,", raw + b",", 1)))
    for changes in ({"start_pose": [0.5, 0, 0.8, 0, 0, 0, 2]}, {"tables": []}, {"tables": [0] * 150_000},
                    {"tables": [{"name": "t", "pose": [0, 0, 0, 0, 0, 0, 1], "size": [1, 1, 1]}] * 65},
                    {"object": {"shape": "box", "size": [1e9, 1, 1], "mass_kg": 1}},
                    {"object": {"shape": "box", "size": [0.1, 0.1, 0.1], "mass_kg": -5}},
                    {"survey": {"states_per_configuration": 1_000_000}}, {"limits": {"time_s": 3600}},
                    {"deep": json.loads("[" * 500 + "]" * 500)}, {"object": [1]}, {"schema": "regrasp.scenario/9"}):
        out.append(("POST", "/v1/jobs", js, job({"scenario": inline(**changes)})))
    out += [("POST", "/v1/jobs", js, job({"scenario": "upright", "states_per_configuration": 1_000_000}, "survey")),
            ("POST", "/v1/jobs", js, job({"scenario": "upright"}, "recover-all")),
            ("POST", "/v1/jobs", js, b"[" * 200_000), ("POST", "/v1/jobs", js, b"{" * 200_000),
            ("POST", "/v1/jobs", js, b"\xff\xfe\x00"), ("POST", "/v1/jobs", js, b"{\"kind\": "),
            ("POST", "/v1/jobs", js, b""), ("POST", "/v1/jobs", js, b"null"), ("POST", "/v1/jobs", js, b"1" * 900_000),
            ("POST", "/v1/jobs", js, b" " * 2_000_000),
            ("POST", "/v1/jobs", {**AUTH, "Content-Type": "text/plain"}, job({"scenario": "upright"})),
            ("POST", "/v1/jobs", {**AUTH, "Content-Type": "application/x-www-form-urlencoded"}, b"kind=plan"),
            ("POST", "/v1/jobs", {**AUTH, "Content-Type": "multipart/form-data; boundary=x"}, b"--x--"),
            ("POST", "/v1/jobs", {**AUTH, "Content-Type": "application/json", "Content-Length": "-5"}, b""),
            ("POST", "/v1/jobs", {**js, "Idempotency-Key": "k" * 5000}, job({"scenario": "upright"}))]
    for auth in ("Bearer", "Bearer ", "Basic dXNlcjpwYXNz", "Bearer " + "x" * 10_000, "bearer tok", "Token abc",
                 "Bearer \u00e9\u00e9", "Bearer a b c"):
        out.append(("GET", "/v1/jobs", {"Authorization": auth}, b""))
    routes = ["/v1/jobs", "/v1/jobs/abc", "/v1/jobs/abc/events", "/v1/jobs/abc/audit", "/v1/jobs/abc/cancel",
              "/v1/jobs/abc/approve", "/v1/jobs/abc/reject", "/v1/jobs/abc/dispatch", "/v1/jobs/abc/stop",
              "/healthz", "/metrics", "/v1/me"]
    for route in routes:
        for method in ("GET", "POST", "PUT", "PATCH", "DELETE"):
            out.append((method, route, AUTH, b""))
    for job_id in ("a" * 10_000, "..%2F..%2Fetc%2Fpasswd", "%00", "\u2603", "1 OR 1=1", "'; DROP TABLE jobs;--"):
        out += [("GET", f"/v1/jobs/{job_id}", AUTH, b""), ("POST", f"/v1/jobs/{job_id}/cancel", AUTH, b"")]
    for query in ("limit=-1", "limit=1000000000", "offset=abc", "include_result=maybe", "state=bogus",
                  "limit=500&include_result=true", "submitter=" + "x" * 1000, "kind=plan&kind=survey"):
        out.append(("GET", f"/v1/jobs?{query}", AUTH, b""))
    for value in ("99999999999999999999", "-1", "abc", "1e5", "0x10", " " * 40, "9" * 300):
        out.append(("GET", "/v1/jobs/abc/events?follow=false", {**AUTH, "Last-Event-ID": value}, b""))
    for body in (b'{"plan_sha256": "zz"}', b'{"comment": "' + b"c" * 5000 + b'"}', b'{"reason": 5}', b"[]"):
        out += [("POST", "/v1/jobs/abc/approve", {**js}, body), ("POST", "/v1/jobs/abc/cancel", {**js}, body)]
    return out


RAW_NAMES = ["5 MB chunked body", "declares 1000 bytes, sends 11", "declares 5 MB", "100 bytes, 1 byte a second",
             "chunked body that stops"]


def send_raw(port: int, head: bytes, body_parts: list[bytes], pause_s: float = 0.0) -> int | None:
    """Send bytes as they are; the answer's status, 0 when the connection closed without one, None on a hang."""
    with socket.create_connection(("127.0.0.1", port), timeout=HANG_S) as sock:
        try:
            sock.sendall(head)
            for part in body_parts:
                sock.sendall(part)
                if pause_s:
                    time.sleep(pause_s)
        except OSError:
            pass
        data = b""
        try:
            while b"\r\n" not in data:
                chunk = sock.recv(4096)
                if not chunk:
                    break
                data += chunk
        except socket.timeout:
            return None
        except OSError:
            pass
        return int(data.split(b" ")[1]) if data.startswith(b"HTTP/1.1 ") else 0


def raw_cases(port: int) -> list[Callable[[], int | None]]:
    """Requests httpx will not send: chunked over the limit, a body that never arrives, a declared 5 MB body."""

    def send(head: bytes, body_parts: list[bytes], pause_s: float = 0.0) -> int | None:
        return send_raw(port, head, body_parts, pause_s)

    base = f"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {TOKEN}\r\nContent-Type: application/json\r\n"
    chunk = b"x" * 65536
    return [
        lambda: send((base + "Transfer-Encoding: chunked\r\n\r\n").encode(),
                     [b"%x\r\n" % len(chunk) + chunk + b"\r\n"] * 80),
        lambda: send((base + "Content-Length: 1000\r\n\r\n").encode(), [b'{"kind": "p']),
        lambda: send((base + "Content-Length: 5000000\r\n\r\n").encode(), [b"x" * 65536]),
        lambda: send((base + "Content-Length: 100\r\n\r\n").encode(), [b"{"] * 5, pause_s=1.0),
        lambda: send((base + "Transfer-Encoding: chunked\r\n\r\n").encode(), [b"5\r\n{\"ki\r\n"]),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--hang-s", type=float, default=HANG_S)
    args = parser.parse_args()
    data_dir = Path(tempfile.mkdtemp(prefix="bench-hostile-"))
    port = free_port()
    env = dict(os.environ)
    env.update({"PYTHONPATH": os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]),
                "REGRASP_TOKENS": json.dumps({TOKEN: {"user": "mallory", "roles": ["planner"]}}),
                "REGRASP_PRELOAD_ROBOT": "false", "REGRASP_AUDIT": "false",
                "REGRASP_BRIDGE_CONNECT": json.dumps([f"tcp/127.0.0.1:{free_port()}"])})
    log = open(data_dir / "server.log", "ab")
    proc = subprocess.Popen([sys.executable, "-m", "service.cli.main", "serve", "--port", str(port), "--data-dir",
                             str(data_dir), "--workers", "0", "--log-level", "warning"],
                            cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(url + "/healthz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline or proc.poll() is not None:
                raise SystemExit("the server did not start: " + (data_dir / "server.log").read_text()[-2000:])
            time.sleep(0.2)
        statuses: Counter[str] = Counter()
        health: list[float] = []
        done = threading.Event()

        def watch_health() -> None:
            while not done.is_set():
                t0 = time.monotonic()
                try:
                    httpx.get(url + "/healthz", timeout=args.hang_s)
                    health.append(time.monotonic() - t0)
                except httpx.HTTPError:
                    health.append(float("inf"))
                time.sleep(0.05)

        watcher = threading.Thread(target=watch_health)
        watcher.start()
        t_start = time.monotonic()
        http_cases = cases()
        closed: list[str] = []
        with httpx.Client(base_url=url, timeout=args.hang_s) as client:
            def one(case: tuple[str, str, dict[str, str], bytes]) -> str:  # noqa: PLR0911
                method, path, headers, body = case
                raw_headers = [(k.encode(), v.encode("utf-8")) for k, v in headers.items()]
                try:
                    return str(client.request(method, path, headers=raw_headers, content=body or None).status_code)
                except httpx.TimeoutException:
                    return "hang"
                except httpx.LocalProtocolError:  # httpx will not send it: send the bytes as they are
                    head = f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n".encode()
                    head += b"".join(k.encode() + b": " + v.encode("utf-8") + b"\r\n" for k, v in headers.items())
                    status = send_raw(port, head + b"Connection: close\r\n\r\n", [body] if body else [])
                    if not status:
                        closed.append(f"{method} {path[:40]} ({len(body)} bytes)")
                    return "hang" if status is None else str(status) if status else "closed"
                except httpx.HTTPError:
                    closed.append(f"{method} {path[:40]} ({len(body)} bytes)")
                    return "closed"

            with ThreadPoolExecutor(max_workers=8) as pool:
                statuses.update(pool.map(one, http_cases))
                raws = raw_cases(port)
                for name, status in zip(RAW_NAMES, pool.map(lambda f: f(), raws)):
                    statuses["hang" if status is None else str(status) if status else "closed"] += 1
                    if status == 0:
                        closed.append(name)
        elapsed = time.monotonic() - t_start
        done.set()
        watcher.join()
        tried = len(http_cases) + len(raws)
        fivexx = sum(n for s, n in statuses.items() if s.startswith("5"))
        print(f"hostile inputs tried: {tried} (in {elapsed:.1f} s, 8 at a time)")
        print("answers by status: " + ", ".join(f"{s}: {n}" for s, n in sorted(statuses.items())))
        print(f"5xx answers: {fivexx}")
        print(f"hangs (no answer within {args.hang_s:g} s): {statuses['hang']}")
        print(f"connections closed without an answer: {statuses['closed']} (" + "; ".join(closed) + ")")
        finite = [h for h in health if h != float("inf")]
        print(f"/healthz meanwhile: {len(health)} probes, slowest {max(finite) * 1000:.0f} ms, "
              f"failed {len(health) - len(finite)}")
        print(f"server still up: {proc.poll() is None}")
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()


if __name__ == "__main__":
    main()
