"""Bounded connections: a request's line and headers must arrive within a deadline, or the connection closes.

uvicorn times out idle keep-alive connections and the body guard (:mod:`service.api.problems`) times out
slow bodies, but a connection that sends part of a request line or of its headers and then nothing is
held open for ever: a few hundred of them exhaust the server's file descriptors. The protocol here arms
a deadline when a connection opens, and again at the first byte of each following request, and disarms
it once the request's headers are complete (from then on the request is the app's, and the body guard's).
A connection still in its request line or headers at the deadline is closed. Answering ``/healthz``
takes no more than its own headers, so it keeps answering while slow connections wait for theirs.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from uvicorn.protocols.http.auto import AutoHTTPProtocol

log = logging.getLogger("regrasp.connections")


class _HeaderDeadline:
    """Mixin for a uvicorn HTTP protocol (h11 or httptools: both keep the request in ``self.cycle``)."""

    header_timeout_s: float = 10.0
    _header_timer: asyncio.TimerHandle | None = None

    def _between_requests(self) -> bool:
        cycle = getattr(self, "cycle", None)
        return cycle is None or cycle.response_complete

    def _arm(self) -> None:
        if self._header_timer is None:
            loop = asyncio.get_running_loop()
            self._header_timer = loop.call_later(self.header_timeout_s, self._header_deadline)

    def _disarm(self) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _header_deadline(self) -> None:
        self._header_timer = None
        transport = getattr(self, "transport", None)
        if self._between_requests() and transport is not None and not transport.is_closing():
            log.info("closed a connection from %s: no complete request headers within %g s",
                     getattr(self, "client", None), self.header_timeout_s)
            transport.close()

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)  # type: ignore[misc]
        self._arm()

    def data_received(self, data: bytes) -> None:
        if self._between_requests():
            self._arm()  # the first byte of a request starts its deadline (an armed one keeps running)
        super().data_received(data)  # type: ignore[misc]
        if not self._between_requests():
            self._disarm()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)  # type: ignore[misc]


def header_deadline_protocol(timeout_s: float) -> type:
    """uvicorn's HTTP protocol with a deadline of ``timeout_s`` on each request's line and headers."""
    return type("HeaderDeadlineProtocol", (_HeaderDeadline, AutoHTTPProtocol), {"header_timeout_s": float(timeout_s)})
