"""Hostile requests against a real `regrasp serve` on 127.0.0.1: names not files, bounded work, operations.

The server runs no workers (jobs stay queued), checks scenario names as a deployment does, and
has small limits so each bound is reached by a few requests: 1 s to send a body, 3 jobs queued
per user, 2 event streams per user, 2 results per listed page, tokens re-read from their file
every 0.2 s, and its metrics on a separate loopback port as well.
"""

from __future__ import annotations

import json
import select
import socket
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import httpx
import pytest
from conftest import TOKEN, Server, free_port, inline_scenario

#: The server's limits (see the module docstring).
READ_TIMEOUT_S = 1.0
USER_QUEUE_LIMIT = 3
USER_STREAM_LIMIT = 2
LIST_RESULTS_MAX = 2
TOKENS_RELOAD_S = 0.2
#: Bounds a client waits for; generous against a loaded 2-core machine, far under the failures they catch.
ANSWER_S = 10.0

#: A token only the tokens file knows (added and revoked by the reload test).
FILE_TOKEN = "tok-file-erin-planner"
SECRET = "tok-secret-admin-SHOULD-NEVER-LEAVE-THE-SERVER"


@pytest.fixture(scope="module")
def hardened(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, int, Path]]:
    data_dir = tmp_path_factory.mktemp("hardened")
    tokens_file = data_dir / "tokens.json"
    tokens_file.write_text(json.dumps({SECRET: {"user": "root", "roles": ["admin"]}}))
    metrics_port = free_port()
    srv = Server(data_dir, workers=0, check_scenario_names="true", body_read_timeout_s=str(READ_TIMEOUT_S),
                 user_queue_limit=str(USER_QUEUE_LIMIT), user_stream_limit=str(USER_STREAM_LIMIT),
                 list_results_max=str(LIST_RESULTS_MAX), tokens_file=str(tokens_file),
                 tokens_reload_s=str(TOKENS_RELOAD_S), metrics_port=str(metrics_port)).start()
    try:
        yield srv, metrics_port, tokens_file
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def srv(hardened: tuple[Server, int, Path]) -> Server:
    return hardened[0]


@pytest.fixture(scope="module")
def queued_job(srv: Server) -> str:
    """A job that stays queued (no workers): a target for reads and streams."""
    with srv.client("admin") as c:
        r = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "upright"}})
        assert r.status_code == 202, r.text
        return r.json()["id"]


def _submit(c: httpx.Client, request: dict[str, Any], kind: str = "plan") -> httpx.Response:
    return c.post("/v1/jobs", json={"kind": kind, "request": request})


def _problem(r: httpx.Response, status: int) -> dict[str, Any]:
    assert r.status_code == status, (r.status_code, r.text[:500])
    assert r.headers["content-type"].startswith("application/problem+json"), r.headers
    body = r.json()
    assert body["status"] == status and body["detail"]
    return body


# --------------------------------------------------------------- names, never files
def test_a_stance_that_names_a_server_file_is_refused_without_reading_it(srv: Server, hardened: Any) -> None:
    tokens_file = hardened[2]
    with srv.client("alice") as c:
        for stance in (str(tokens_file), "../" + tokens_file.name, tokens_file.name, "./tokens.yaml"):
            body = _problem(_submit(c, {"scenario": "upright", "stance": stance}), 422)
            assert "never a file" in body["detail"] and "upright" in body["detail"], body
            assert SECRET not in json.dumps(body)


def test_unknown_names_are_refused_at_submission_listing_the_valid_ones(srv: Server) -> None:
    with srv.client("alice") as c:
        cases = [({"scenario": "upright", "stance": "kneeling"}, "stance", ["upright", "crouched", "one-legged"]),
                 ({"scenario": "nosuch"}, "scenario", ["upright", "staggered"]),
                 ({"scenario": "upright", "robot": "nao"}, "robot", ["hrp5p", "jvrc1"]),
                 ({"scenario": inline_scenario(robot="nao")}, "robot", ["hrp5p", "jvrc1"]),
                 ({"scenario": inline_scenario(stance="kneeling")}, "stance", ["upright"]),
                 ({"scenario": inline_scenario(object={"shape": "mesh", "mesh": {"name": "teapot"}, "mass_kg": 2.0})},
                  "mesh", ["carrier_px", "carrier_nx"])]
        for request, what, valid in cases:
            body = _problem(_submit(c, request), 422)
            assert f"unknown {what}" in body["detail"] and all(v in body["detail"] for v in valid), body
            assert set(valid) <= set(body["valid"])
        assert _submit(c, {"scenario": "upright", "hands": "both-hands"}).status_code == 422


def test_paths_in_an_inline_scenario_are_refused_and_do_not_tell_whether_a_file_exists(srv: Server, hardened: Any) -> None:
    tokens_file = hardened[2]
    with srv.client("alice") as c:
        details = []
        for path in (str(tokens_file), str(tokens_file) + ".missing"):
            mesh = {"shape": "mesh", "mesh": {"path": path}, "mass_kg": 2.0}
            details.append(_problem(_submit(c, {"scenario": inline_scenario(object=mesh)}), 422)["detail"])
        assert details[0] == details[1] and "registered mesh" in details[0]
        for robot in ("../../../tmp/robot", "/etc/robot.yaml"):
            assert "never a file" in _problem(_submit(c, {"scenario": inline_scenario(robot=robot)}), 422)["detail"]
        assert "never a file" in _problem(_submit(c, {"scenario": inline_scenario(stance=str(tokens_file))}), 422)["detail"]
        # a registered mesh by name is accepted
        mesh = {"shape": "mesh", "mesh": {"name": "carrier_px"}, "mass_kg": 2.0}
        assert _submit(c, {"scenario": inline_scenario(object=mesh)}).status_code in (202, 429)


def test_types_are_strict_and_only_json_bodies_are_taken(srv: Server) -> None:
    with srv.client("alice") as c:
        for field, value in (("seed", "1"), ("seed", True), ("seed", 1.5), ("threshold_m", "0.06"),
                             ("threshold_m", True), ("hands", 1), ("scenario", ["upright"])):
            body = _problem(_submit(c, {"scenario": "upright", field: value}), 422)
            assert "function-before" not in body["detail"] and "Error" not in body["detail"], body
        r = c.post("/v1/jobs", content=b'{"kind": "plan", "request": {"scenario": "upright"}}',
                   headers={"Content-Type": "text/plain"})
        _problem(r, 415)


# ---------------------------------------------------------------- bounded work
def test_a_150000_item_list_is_refused_fast_and_health_stays_responsive(srv: Server) -> None:
    body = json.dumps({"kind": "plan", "request": {"scenario": inline_scenario(tables=[0] * 150_000)}})
    assert len(body) > 290_000
    latencies: list[float] = []
    stop = threading.Event()

    def poll_health() -> None:
        while not stop.is_set():
            t0 = time.monotonic()
            httpx.get(srv.url + "/healthz", timeout=ANSWER_S)
            latencies.append(time.monotonic() - t0)
            time.sleep(0.02)

    poller = threading.Thread(target=poll_health)
    poller.start()
    try:
        with srv.client("alice") as c:
            t0 = time.monotonic()
            r = c.post("/v1/jobs", content=body, headers={"Content-Type": "application/json"})
            elapsed = time.monotonic() - t0
    finally:
        stop.set()
        poller.join()
    detail = _problem(r, 422)["detail"]
    assert "5000 values" in detail, detail
    # The issue measured 5.2 s for the 422 and a 3.6 s stall of /healthz; counting stops at 5,000 values.
    assert elapsed < 2.0, elapsed
    assert latencies and max(latencies) < 1.5, latencies


def _raw(srv: Server, head: str) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", srv.port), timeout=ANSWER_S)
    sock.sendall(head.encode())
    return sock


def _read_status(sock: socket.socket, timeout: float) -> tuple[int, bytes]:
    sock.settimeout(timeout)
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        if not chunk:
            break
        data += chunk
    status = int(data.split(b" ", 2)[1]) if data.startswith(b"HTTP/1.1 ") else 0
    return status, data


def test_a_chunked_body_over_the_limit_gets_413(srv: Server) -> None:
    head = (f"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {TOKEN['alice']}\r\n"
            "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n")
    chunk = b"x" * 65536
    with _raw(srv, head) as sock:
        sent = 0
        answered = False
        while sent < 5 * 1024 * 1024 and not answered:
            try:
                sock.sendall(b"%x\r\n" % len(chunk) + chunk + b"\r\n")
            except OSError:
                break
            sent += len(chunk)
            answered = bool(select.select([sock], [], [], 0.02)[0])
        status, data = _read_status(sock, ANSWER_S)
    assert status == 413, data[:300]
    assert sent < 2 * 1024 * 1024  # refused once past the 1 MB limit, not after reading all 5 MB


def test_a_client_that_declares_more_than_it_sends_is_cut_off(srv: Server) -> None:
    head = (f"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {TOKEN['alice']}\r\n"
            "Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n")
    with _raw(srv, head + '{"kind": "p') as sock:
        t0 = time.monotonic()
        status, data = _read_status(sock, ANSWER_S)
        elapsed = time.monotonic() - t0
        sock.settimeout(ANSWER_S)
        while chunk := sock.recv(65536):  # the server closes the connection after its answer
            data += chunk
    assert status == 408 and b"not received within" in data, data[:300]
    assert READ_TIMEOUT_S * 0.9 <= elapsed < READ_TIMEOUT_S + 5.0, elapsed


def test_every_405_names_the_allowed_methods(srv: Server) -> None:
    cases = [("DELETE", "/v1/jobs", {"GET", "POST"}), ("POST", "/v1/jobs/abc", {"GET"}),
             ("GET", "/v1/jobs/abc/cancel", {"POST"}), ("PUT", "/v1/jobs/abc/approve", {"POST"}),
             ("POST", "/healthz", {"GET"}), ("DELETE", "/metrics", {"GET"}), ("POST", "/v1/jobs/abc/events", {"GET"}),
             ("PATCH", "/v1/jobs/abc/audit", {"GET"})]
    with srv.client("alice") as c:
        for method, path, allowed in cases:
            r = c.request(method, path)
            _problem(r, 405)
            assert {m.strip() for m in r.headers["allow"].split(",")} == allowed, (method, path, r.headers.get("allow"))


def test_last_event_id_out_of_range_or_garbage_is_a_400_problem(srv: Server, queued_job: str) -> None:
    with srv.client("alice") as c:
        for value in ("99999999999999999999", "-1", "abc", "1e5", "١٢".encode()):
            r = c.get(f"/v1/jobs/{queued_job}/events", params={"follow": "false"}, headers={"Last-Event-ID": value})
            assert "Last-Event-ID" in _problem(r, 400)["detail"]
        r = c.get(f"/v1/jobs/{queued_job}/events", params={"follow": "false"}, headers={"Last-Event-ID": "0"})
        assert r.status_code == 200 and "event: state" in r.text


def test_queued_jobs_per_user_are_capped_with_retry_after(srv: Server) -> None:
    with srv.client("dave") as dave, srv.client("alice") as alice:
        for _ in range(USER_QUEUE_LIMIT):
            assert _submit(dave, {"scenario": "upright"}).status_code == 202
        r = _submit(dave, {"scenario": "upright"})
        body = _problem(r, 429)
        assert int(r.headers["retry-after"]) >= 1 and "dave" in body["detail"]
        assert _submit(alice, {"scenario": "upright"}).status_code == 202  # another user is not held up


def test_open_event_streams_per_user_are_capped(srv: Server, queued_job: str) -> None:
    url = f"{srv.url}/v1/jobs/{queued_job}/events"
    headers = {"Authorization": f"Bearer {TOKEN['bob']}"}
    clients = [httpx.Client(timeout=ANSWER_S) for _ in range(USER_STREAM_LIMIT)]
    streams = []
    try:
        for client in clients:
            cm = client.stream("GET", url, headers=headers)
            streams.append((cm, cm.__enter__()))
            assert streams[-1][1].status_code == 200
        r = httpx.get(url, headers=headers, timeout=ANSWER_S)
        _problem(r, 429)
        assert int(r.headers["retry-after"]) >= 1
        other = httpx.get(url, params={"follow": "false"}, headers={"Authorization": f"Bearer {TOKEN['alice']}"},
                          timeout=ANSWER_S)
        assert other.status_code == 200
    finally:
        for cm, _ in streams:
            cm.__exit__(None, None, None)
        for client in clients:
            client.close()
    deadline = time.monotonic() + ANSWER_S  # closed streams are released once the server sees the disconnect
    while True:
        r = httpx.get(url, params={"follow": "false"}, headers=headers, timeout=ANSWER_S)
        if r.status_code == 200 or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert r.status_code == 200, r.text


def test_states_and_time_per_job_are_capped_by_the_settings(srv: Server) -> None:
    with srv.client("alice") as c:
        body = _problem(_submit(c, {"scenario": "upright", "states_per_configuration": 1_000_000}, kind="survey"), 422)
        assert "at most 500000 states" in body["detail"], body
        inline = inline_scenario(survey={"states_per_configuration": 1_000_000})
        assert "at most 500000" in _problem(_submit(c, {"scenario": inline}, kind="survey"), 422)["detail"]
        body = _problem(_submit(c, {"scenario": "upright", "time_limit_s": 3000}), 422)
        assert "limit of 900 s" in body["detail"], body


def test_listing_with_results_is_capped_to_a_page(srv: Server, queued_job: str) -> None:
    with srv.client("alice") as c:
        page = c.get("/v1/jobs", params={"include_result": "true", "limit": 500}).json()
        assert page["limit"] == LIST_RESULTS_MAX and len(page["jobs"]) <= LIST_RESULTS_MAX
        assert page["total"] > LIST_RESULTS_MAX  # the rest is reached with offset
        rest = c.get("/v1/jobs", params={"include_result": "true", "limit": 500, "offset": LIST_RESULTS_MAX}).json()
        assert {j["id"] for j in rest["jobs"]}.isdisjoint({j["id"] for j in page["jobs"]})
        assert len(c.get("/v1/jobs", params={"limit": 500}).json()["jobs"]) == page["total"]


def test_large_responses_are_gzipped_streams_are_not(srv: Server, queued_job: str) -> None:
    with srv.client("alice") as c:
        r = c.get("/openapi.json", headers={"Accept-Encoding": "gzip"})
        assert r.status_code == 200 and r.headers.get("content-encoding") == "gzip"
        assert int(r.headers["content-length"]) < len(r.content)
        r = c.get(f"/v1/jobs/{queued_job}/events", params={"follow": "false"}, headers={"Accept-Encoding": "gzip"})
        assert r.status_code == 200 and "content-encoding" not in r.headers


# ------------------------------------------------------------------ operations
def test_failed_authentication_is_logged_with_user_and_address(srv: Server, queued_job: str) -> None:
    assert httpx.get(srv.url + "/v1/jobs", headers={"Authorization": "Bearer not-a-token-1234"}).status_code == 401
    with srv.client("carol") as carol:  # an approver cannot submit
        assert _submit(carol, {"scenario": "upright"}).status_code == 403
    deadline = time.monotonic() + ANSWER_S
    while time.monotonic() < deadline:
        log = srv.log_path.read_text()
        if "authentication failed from 127.0.0.1" in log and "user 'carol'" in log:
            break
        time.sleep(0.1)
    assert "authentication failed from 127.0.0.1" in log and "unknown token" in log
    assert "not-a-token-1234" not in log  # the token itself never goes to the log
    line = next(ln for ln in log.splitlines() if "user 'carol'" in ln)
    assert "from 127.0.0.1:" in line and "planner" in line


def test_tokens_are_reloaded_from_their_file_without_a_restart(hardened: tuple[Server, int, Path]) -> None:
    srv, _, tokens_file = hardened
    headers = {"Authorization": f"Bearer {FILE_TOKEN}"}
    assert httpx.get(srv.url + "/v1/me", headers=headers).status_code == 401
    assert httpx.get(srv.url + "/v1/me", headers={"Authorization": f"Bearer {SECRET}"}).json()["user"] == "root"
    tokens_file.write_text(json.dumps({FILE_TOKEN: {"user": "erin", "roles": ["planner"]}}))

    def me(token: str) -> httpx.Response:
        deadline = time.monotonic() + ANSWER_S
        while True:
            r = httpx.get(srv.url + "/v1/me", headers={"Authorization": f"Bearer {token}"})
            if (r.status_code == 200) == (token == FILE_TOKEN) or time.monotonic() > deadline:
                return r
            time.sleep(TOKENS_RELOAD_S)

    assert me(FILE_TOKEN).json()["user"] == "erin"
    assert me(SECRET).status_code == 401  # revoked: no longer in the file
    assert httpx.get(srv.url + "/v1/me", headers={"Authorization": f"Bearer {TOKEN['alice']}"}).status_code == 200
    tokens_file.write_text("{not json")  # a broken file keeps the tokens loaded before
    time.sleep(3 * TOKENS_RELOAD_S)
    assert httpx.get(srv.url + "/v1/me", headers=headers).status_code == 200


def test_metrics_need_a_token_or_the_separate_bind(hardened: tuple[Server, int, Path]) -> None:
    srv, metrics_port, _ = hardened
    _problem(httpx.get(srv.url + "/metrics"), 401)
    assert httpx.get(srv.url + "/metrics", headers={"Authorization": "Bearer wrong-token-1234"}).status_code == 401
    with srv.client("alice") as c:
        assert "regrasp_queue_depth" in c.get("/metrics").text
    r = httpx.get(f"http://127.0.0.1:{metrics_port}/metrics", timeout=ANSWER_S)
    assert r.status_code == 200 and "regrasp_queue_depth" in r.text


def test_no_answer_names_a_python_class(srv: Server) -> None:
    """Every problem so far came from the handlers above; an odd body or header must not leak either."""
    with srv.client("alice") as c:
        answers = [c.post("/v1/jobs", content=b"[" * 100_000, headers={"Content-Type": "application/json"}),
                   c.post("/v1/jobs", content=b"\xff\xfe", headers={"Content-Type": "application/json"}),
                   c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "upright"}, "x": 1}),
                   c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": inline_scenario(tables=[0])}}),
                   c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": inline_scenario(object=[1])}}),
                   c.get("/v1/jobs/" + "a" * 500)]
    for r in answers:
        assert 400 <= r.status_code < 500, (r.status_code, r.text[:300])
        text = json.dumps(r.json())
        assert not any(word in text for word in ("Error", "Exception", "instance of", "BoxDef", "ObjectDef")), text[:300]

