"""Open zenoh 1.x sessions with an explicit configuration, and publish control traffic.

Never the library defaults: multicast scouting is off and the endpoints are
explicit (a peer opens in milliseconds instead of half a second, and no stray
peer on the network joins). A lost endpoint is tried again within the settings'
``connect_retry_max_s`` (1 s), so a restarted controller is found again by every
peer of the service, its telemetry's as well as its commands'. The transport
lease is shortened so a frozen peer's liveliness token goes away in about a
second; the application heartbeat covers the rest. Shared memory between peers
of one host is off by default: the robot's controller is on another host, so
loopback then measures the TCP path the robot uses (zenoh's lazily set-up shared
memory delays the first large messages of each link).

zenoh's own mutual TLS is switched on by the settings' ``tls_root_ca``,
``tls_cert`` and ``tls_key`` (both peers; endpoints ``tls/HOST:PORT``): each peer
then proves itself with a certificate of the shared CA, listening and connecting,
and a peer without one is not let in. It complements the signed commands, which
hold even where the transport is not encrypted.

Control traffic is published with real-time priority, express (no batching) and
drop on congestion: a stale command is worthless, and blocking would stall the
sender (a 5 s block closes the transport).
"""

from __future__ import annotations

import json
from typing import Any

import zenoh

from .settings import BridgeSettings

#: zenoh's keep-alive messages per lease period.
KEEP_ALIVE_PER_LEASE = 4
#: Growth of the wait between connect attempts (up to the settings' maximum).
CONNECT_RETRY_FACTOR = 2.0


def make_config(settings: BridgeSettings) -> zenoh.Config:
    """The zenoh configuration of a peer from typed settings."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    config.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
    config.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    config.insert_json5("connect/retry", json.dumps({
        "period_init_ms": int(settings.connect_retry_s * 1000), "period_max_ms": int(settings.connect_retry_max_s * 1000),
        "period_increase_factor": CONNECT_RETRY_FACTOR}))
    config.insert_json5("transport/link/tx/lease", json.dumps(int(settings.lease_s * 1000)))
    config.insert_json5("transport/link/tx/keep_alive", json.dumps(KEEP_ALIVE_PER_LEASE))
    config.insert_json5("transport/link/tx/queue/size/real_time", json.dumps(settings.tx_queue_batches))
    config.insert_json5("transport/shared_memory/enabled", json.dumps(settings.shared_memory))
    if settings.tls_root_ca is not None:
        cert, key = str(settings.tls_cert), str(settings.tls_key)
        config.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": str(settings.tls_root_ca), "enable_mtls": True,
            "listen_certificate": cert, "listen_private_key": key,
            "connect_certificate": cert, "connect_private_key": key,
        }))
    return config


def open_session(settings: BridgeSettings) -> zenoh.Session:
    """Open a peer session; an unusable configuration raises with zenoh's message."""
    return zenoh.open(make_config(settings))


def control_publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    """A publisher for commands: real-time priority, express, drop on congestion."""
    return session.declare_publisher(
        key,
        priority=zenoh.Priority.REAL_TIME,
        express=True,
        congestion_control=zenoh.CongestionControl.DROP,
    )


def telemetry_publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    """A publisher for state streams: high priority, express, drop (the next sample supersedes)."""
    return session.declare_publisher(
        key,
        priority=zenoh.Priority.INTERACTIVE_HIGH,
        express=True,
        congestion_control=zenoh.CongestionControl.DROP,
    )


def encode(doc: Any) -> bytes:
    """JSON bytes of a message. Models serialise in pydantic's Rust core (a 1 s segment in about a
    millisecond); their validators already refused NaN and Inf. Plain data goes through ``json``
    with NaN refused: it must never reach a controller."""
    if hasattr(doc, "model_dump_json"):
        return doc.model_dump_json().encode()
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()
