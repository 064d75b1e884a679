"""A small synchronous client of the planning service (httpx), for scripts and the demo.

    from service.client import ServiceClient
    alice = ServiceClient("http://127.0.0.1:8000", token=ALICE)
    job = alice.submit("plan", {"scenario": "paper-box"})
    job = alice.wait(job["id"])                       # planned, or an end state
    bob.approve(job["id"], plan_sha256=job["plan_sha256"])
    bob.dispatch(job["id"]); bob.wait(job["id"])

Errors come back as :class:`ServiceError` carrying the problem document.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import httpx

from schemas.jobs import TERMINAL_STATES
from service.errors import RegraspServiceError

#: States :meth:`ServiceClient.wait` stops at by default: a plan is ready for review, or the job ended.
SETTLED_STATES: frozenset[str] = TERMINAL_STATES | {"planned"}


class ServiceError(RegraspServiceError, RuntimeError):
    """An error answer of the service (its RFC 9457 problem document in ``problem``)."""

    def __init__(self, status: int, problem: dict[str, Any]) -> None:
        self.status = status
        self.problem = problem
        super().__init__(f"HTTP {status}: {problem.get('detail') or problem.get('title') or problem}")


class ServiceClient:
    def __init__(self, base_url: str, token: str | None = None, *, timeout: float = 30.0,
                 client: httpx.Client | None = None) -> None:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.base_url = base_url.rstrip("/")
        self._http = client or httpx.Client(base_url=self.base_url, timeout=timeout, headers=headers)
        if client is not None and token:
            self._http.headers.update(headers)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> "ServiceClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ basics
    def _call(self, method: str, path: str, **kwargs: Any) -> Any:
        response = self._http.request(method, path, **kwargs)
        if response.status_code >= 400:
            try:
                problem = response.json()
            except ValueError:
                problem = {"detail": response.text[:500]}
            raise ServiceError(response.status_code, problem)
        return response.json()

    def health(self) -> dict[str, Any]:
        return self._call("GET", "/healthz")

    def submit(self, kind: str, request: dict[str, Any], *, idempotency_key: str | None = None) -> dict[str, Any]:
        headers = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        return self._call("POST", "/v1/jobs", json={"kind": kind, "request": request}, headers=headers)

    def get(self, job_id: str, *, include_result: bool = True) -> dict[str, Any]:
        params = None if include_result else {"include_result": "false"}
        return self._call("GET", f"/v1/jobs/{job_id}", params=params)

    def list(self, **filters: Any) -> dict[str, Any]:
        return self._call("GET", "/v1/jobs", params={k: v for k, v in filters.items() if v is not None})

    def cancel(self, job_id: str, reason: str | None = None) -> dict[str, Any]:
        return self._call("POST", f"/v1/jobs/{job_id}/cancel", json={"reason": reason} if reason else None)

    def approve(self, job_id: str, *, plan_sha256: str | None = None, comment: str | None = None) -> dict[str, Any]:
        body = {k: v for k, v in {"plan_sha256": plan_sha256, "comment": comment}.items() if v is not None}
        return self._call("POST", f"/v1/jobs/{job_id}/approve", json=body or None)

    def reject(self, job_id: str, reason: str | None = None) -> dict[str, Any]:
        return self._call("POST", f"/v1/jobs/{job_id}/reject", json={"reason": reason} if reason else None)

    def risk(self, job_id: str) -> dict[str, Any]:
        """The plan's risk card (with its physics dry run) and the gate's verdicts."""
        return self._call("GET", f"/v1/jobs/{job_id}/risk")

    def dispatch(self, job_id: str) -> dict[str, Any]:
        return self._call("POST", f"/v1/jobs/{job_id}/dispatch")

    def stop(self, job_id: str, reason: str | None = None) -> dict[str, Any]:
        return self._call("POST", f"/v1/jobs/{job_id}/stop", json={"reason": reason} if reason else None)

    def download_audit(self, job_id: str, out: str | Path) -> Path:
        response = self._http.get(f"/v1/jobs/{job_id}/audit")
        if response.status_code >= 400:
            raise ServiceError(response.status_code, response.json())
        out = Path(out)
        out.write_bytes(response.content)
        return out

    # ------------------------------------------------------------------ events
    def events(self, job_id: str, *, after: int = 0, timeout: float | None = None) -> Iterator[dict[str, Any]]:
        """Yield the job's events (SSE) until the stream ends (terminal state) or ``timeout`` s pass."""
        deadline = None if timeout is None else time.monotonic() + timeout
        read_timeout = 5.0 if timeout is None else min(5.0, max(timeout, 0.1))
        with self._http.stream("GET", f"/v1/jobs/{job_id}/events", params={"after": after},
                               timeout=httpx.Timeout(10.0, read=read_timeout + 20.0)) as response:
            if response.status_code >= 400:
                response.read()
                raise ServiceError(response.status_code, response.json())
            for event in parse_sse(response.iter_lines()):
                yield event
                if deadline is not None and time.monotonic() > deadline:
                    return

    def wait(self, job_id: str, states: Iterable[str] = SETTLED_STATES, *, timeout: float = 600.0,
             on_event: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
        """Follow the job's events until it reaches one of ``states``; returns the job.

        ``on_event`` sees every event from the job's first, also when the job got there before this
        call (the stream replays the history), so a caller never misses the progress of a fast job.
        """
        wanted = set(states)
        deadline = time.monotonic() + timeout
        job = self.get(job_id, include_result=False)
        if job["state"] in wanted and on_event is None:
            return self.get(job_id)
        try:
            for event in self.events(job_id, timeout=timeout):
                if on_event is not None:
                    on_event(event)
                if event.get("kind") == "state" and event.get("state") in wanted:
                    return self.get(job_id)
                if time.monotonic() > deadline:
                    break
        except (httpx.HTTPError, ServiceError):
            pass
        while time.monotonic() < deadline:  # fallback: poll (without the result, which can be MBs)
            job = self.get(job_id, include_result=False)
            if job["state"] in wanted:
                return self.get(job_id)
            time.sleep(0.2)
        raise TimeoutError(f"job {job_id} did not reach {sorted(wanted)} within {timeout} s (now {job['state']})")


def parse_sse(lines: Iterable[str]) -> Iterator[dict[str, Any]]:
    """Parse a text/event-stream into the JSON ``data`` of each event."""
    data: list[str] = []
    for line in lines:
        if line == "":
            if data:
                try:
                    yield json.loads("\n".join(data))
                except ValueError:
                    pass
                data = []
        elif line.startswith("data:"):
            data.append(line[5:].lstrip())
    if data:
        try:
            yield json.loads("\n".join(data))
        except ValueError:
            pass
