"""Typed settings of the bridge's zenoh peers (environment prefix ``REGRASP_BRIDGE_``).

Defaults are for one machine (loopback, multicast scouting off). On the robot
network set the endpoints, e.g. ``REGRASP_BRIDGE_CONNECT='["tcp/10.0.0.2:7447"]'``.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

#: The contract's default robot id, the ROBOT part of every key expression.
DEFAULT_ROBOT_ID = "hrp5p"
#: Default endpoint of the controller peer (it listens, the bridge connects).
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class BridgeSettings(BaseSettings):
    """How a bridge or controller peer opens zenoh, and the liveness timing both follow."""

    model_config = SettingsConfigDict(env_prefix="REGRASP_BRIDGE_", frozen=True, extra="forbid")

    robot_id: str = Field(DEFAULT_ROBOT_ID, pattern=r"^[A-Za-z0-9_\-]+$", description="ROBOT in regrasp/ROBOT/...")
    listen: list[str] = Field(default_factory=list, description="zenoh endpoints this peer listens on")
    connect: list[str] = Field(default_factory=lambda: [DEFAULT_ENDPOINT], description="zenoh endpoints this peer connects to")
    multicast_scouting: bool = Field(False, description="off: explicit endpoints only (fast, no surprise peers)")
    lease_s: float = Field(1.0, gt=0, le=60, description="zenoh transport lease: a silent peer is dropped after it")
    connect_retry_s: float = Field(
        0.1, gt=0, le=10.0,
        description="first wait before a lost or absent connect endpoint is tried again; each wait doubles up to "
                    "connect_retry_max_s. zenoh's own 1 s doubling to 4 s left a peer of the service (its balance "
                    "telemetry) unconnected for seconds after a controller restart")
    connect_retry_max_s: float = Field(1.0, gt=0, le=60.0, description="the longest wait between connect attempts")
    heartbeat_period_s: float = Field(0.05, gt=0, le=1.0, description="controller heartbeat period")
    watchdog_timeout_s: float = Field(
        0.25, gt=0, le=5.0,
        description="no heartbeat for this long = controller lost (0.25 s leaves room to abort and stop within 300 ms)",
    )
    tx_queue_batches: int = Field(
        16, ge=1, le=64,
        description="zenoh real-time transmit queue, in batches of 64 KB: room for a burst of segments, so drop-on-congestion "
                    "drops only under real congestion",
    )
    shared_memory: bool = Field(
        False,
        description="zenoh's shared-memory transport between peers of one host. Off: the robot's controller is on "
                    "another host, where it is never used, and on one host its lazily created pool and segment mappings "
                    "held the first messages over 3 kB of each new link for milliseconds",
    )
    stop_repeats: int = Field(3, ge=1, le=20, description="a stop is re-sent this many times until acknowledged")
    stop_repeat_period_s: float = Field(0.02, gt=0, le=1.0)

    # ---- authenticated commands (docs/robot_bridge.md)
    signing_key: Path | None = Field(
        None, description="dispatcher: PEM (PKCS#8) Ed25519 private key every cmd/* message is signed with "
                          "(REGRASP_BRIDGE_SIGNING_KEY); without one the service refuses to dispatch")
    trusted_key: Path | None = Field(
        None, description="controller: PEM public key of the dispatcher; without one it obeys only cmd/stop")
    clock_skew_s: float = Field(0.5, ge=0, le=5.0,
                                description="how far the peers' clocks may disagree; the controller allows it on expires_at")
    segment_expiry_s: float = Field(
        1.0, gt=0, le=10.0,
        description="a segment's expires_at is its send time plus this: a segment that waited longer (a frozen "
                    "controller, a replay) is refused, not played")
    heartbeat_expiry_s: float = Field(0.25, gt=0, le=10.0, description="a dispatcher heartbeat's expires_at is its "
                                                                        "send time plus this")
    thread_nice: int | None = Field(
        -10, ge=-20, le=19,
        description="niceness of the threads that carry bridge traffic (zenoh's, the heartbeat, the execution loop, "
                    "the controller's); below 0 needs CAP_SYS_NICE and is skipped without it. None: leave it")

    realtime_priority: int | None = Field(
        10, ge=1, le=99,
        description="run the bridge's threads (the controller simulator's, the dispatcher's process) under SCHED_RR at "
                    "this priority, where allowed (CAP_SYS_NICE): they then preempt ordinary work however busy the "
                    "cores are (with both cores busy at a load of 14-17, 0 of 30 executions aborted falsely with it, 6 "
                    "of 30 without). None: the niceness above only")

    # ---- zenoh transport security
    tls_root_ca: Path | None = Field(None, description="zenoh TLS: CA certificate (PEM) both peers trust")
    tls_cert: Path | None = Field(None, description="zenoh TLS: this peer's certificate (PEM), for mutual TLS")
    tls_key: Path | None = Field(None, description="zenoh TLS: this peer's private key (PEM)")

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, values: list[str]) -> list[str]:
        for v in values:
            if "/" not in v or v.split("/", 1)[0] not in ("tcp", "udp", "tls", "quic", "unixsock-stream", "ws"):
                raise ValueError(f"endpoint {v!r} is not a zenoh locator like tcp/127.0.0.1:7447")
        return values

    @model_validator(mode="after")
    def _check(self) -> "BridgeSettings":
        if self.watchdog_timeout_s <= 2 * self.heartbeat_period_s:
            raise ValueError("watchdog_timeout_s must exceed two heartbeat periods, or one late heartbeat aborts a job")
        if self.connect_retry_max_s < self.connect_retry_s:
            raise ValueError(f"connect_retry_max_s ({self.connect_retry_max_s} s) is below connect_retry_s "
                             f"({self.connect_retry_s} s)")
        tls = [self.tls_root_ca, self.tls_cert, self.tls_key]
        if any(v is not None for v in tls) and any(v is None for v in tls):
            raise ValueError("mutual TLS needs tls_root_ca, tls_cert and tls_key together")
        return self


class Keys:
    """The key expressions of docs/contract.md section 6 for one robot id."""

    def __init__(self, robot_id: str = DEFAULT_ROBOT_ID):
        base = f"regrasp/{robot_id}"
        self.trajectory = f"{base}/cmd/trajectory"
        self.stop = f"{base}/cmd/stop"
        self.command_heartbeat = f"{base}/cmd/heartbeat"
        self.joints = f"{base}/state/joints"
        self.exec = f"{base}/state/exec"
        self.heartbeat = f"{base}/state/heartbeat"
        self.balance = f"{base}/state/balance"
        self.alive = f"{base}/alive/controller"
