"""Bounded connections on a real server: unfinished request lines and headers are closed within the
header deadline, while /healthz keeps answering (docs/service.md, "Bounded connections")."""

from __future__ import annotations

import selectors
import socket
import time
from pathlib import Path

import httpx
from conftest import Server

#: The deadline the test server states (the default is 10 s; shorter keeps the test quick).
HEADER_TIMEOUT_S = 3.0
#: How late a close may come on a loaded two-core machine.
SLACK_S = 2.0
CONNECTIONS = 200


def _response(s: socket.socket) -> bytes:
    """One whole HTTP response (headers and the Content-Length body), however the segments arrive."""
    data = b""
    while b"\r\n\r\n" not in data:
        data += s.recv(4096)
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(int(line.split(b":", 1)[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length:"))
    while len(body) < length:
        body += s.recv(4096)
    return head + b"\r\n\r\n" + body


def _open(port: int, first_bytes: bytes) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    s.sendall(first_bytes)
    s.setblocking(False)
    return s


def test_200_slow_header_connections_are_closed_within_the_deadline_and_healthz_answers(tmp_path: Path) -> None:
    srv = Server(tmp_path, workers=0, header_read_timeout_s=str(HEADER_TIMEOUT_S))
    try:
        srv.start()
        partial = [b"GET /healthz HTTP/1.1\r\nHost: x\r\n", b"GET /hea", b"POST /v1/jobs HTTP/1.1\r\nContent-Ty"]
        t0 = time.monotonic()
        socks = [_open(srv.port, partial[i % len(partial)]) for i in range(CONNECTIONS)]
        opened = time.monotonic()
        sel = selectors.DefaultSelector()
        for s in socks:
            sel.register(s, selectors.EVENT_READ)
        closed_at: dict[socket.socket, float] = {}
        health: list[tuple[int, float]] = []
        next_probe = time.monotonic()
        with httpx.Client(base_url=srv.url, timeout=5) as c:
            while len(closed_at) < CONNECTIONS and time.monotonic() - t0 < HEADER_TIMEOUT_S + SLACK_S + 5:
                for key, _ in sel.select(timeout=0.05):
                    sock = key.fileobj
                    try:
                        data = sock.recv(4096)
                    except ConnectionResetError:
                        data = b""
                    if not data:  # closed by the server (a close without any answer to a request it never saw)
                        closed_at[sock] = time.monotonic()
                        sel.unregister(sock)
                if time.monotonic() >= next_probe and len(closed_at) < CONNECTIONS:
                    p0 = time.monotonic()
                    r = c.get("/healthz")
                    health.append((r.status_code, time.monotonic() - p0))
                    next_probe = time.monotonic() + 0.25
        for s in socks:
            s.close()
        assert len(closed_at) == CONNECTIONS, f"{CONNECTIONS - len(closed_at)} slow connections still open"
        latest = max(closed_at.values()) - t0
        earliest = min(closed_at.values()) - opened
        assert earliest >= HEADER_TIMEOUT_S - 0.05  # none closed before its deadline
        assert latest <= HEADER_TIMEOUT_S + SLACK_S, latest
        assert len(health) >= 4 and all(code == 200 for code, _ in health), health
        assert max(t for _, t in health) < 1.0, health
    finally:
        srv.stop()


def test_a_kept_alive_connection_gets_the_deadline_again_for_its_next_request(tmp_path: Path) -> None:
    srv = Server(tmp_path, workers=0, header_read_timeout_s=str(HEADER_TIMEOUT_S))
    try:
        srv.start()
        s = socket.create_connection(("127.0.0.1", srv.port), timeout=HEADER_TIMEOUT_S + SLACK_S + 5)
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        answer = _response(s)
        assert answer.startswith(b"HTTP/1.1 200"), answer
        time.sleep(1.0)  # inside the 5 s keep-alive: the connection stays for its next request
        t0 = time.monotonic()
        s.sendall(b"GET /healthz HTTP/1.1\r\nHo")
        assert s.recv(4096) == b""
        assert HEADER_TIMEOUT_S - 0.05 <= time.monotonic() - t0 <= HEADER_TIMEOUT_S + SLACK_S
        s.close()
    finally:
        srv.stop()
