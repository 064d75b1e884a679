"""Typed configuration of the planning service (pydantic-settings).

Values come, lowest priority first, from the defaults below, a config file
(YAML, JSON or TOML, given with ``--config FILE`` or ``REGRASP_CONFIG``), the
environment (``REGRASP_`` prefix, e.g. ``REGRASP_WORKERS=4``; nested and dict
values as JSON, e.g. ``REGRASP_TOKENS='{"t0k3n": {"user": "ann", "roles": ["planner"]}}'``),
and finally the command line flags of ``regrasp serve`` / ``regrasp worker``.
"""

from __future__ import annotations

import json
import os
import tomllib
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, Field, field_validator, model_validator
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

from schemas.policy import SafetyPolicy, policy_from

#: Job kind -> "module:function" run by the workers (planner/jobs/entry.py).
DEFAULT_HANDLERS: dict[str, str] = {
    "plan": "planner.jobs.entry:run_plan",
    "survey": "planner.jobs.entry:run_survey",
    "recover": "planner.jobs.entry:run_recover",
}


class TokenEntry(BaseModel):
    user: str = Field(min_length=1, max_length=128)
    roles: list[Literal["planner", "approver", "operator", "admin"]]


class ServiceSettings(BaseSettings):
    """Every knob of ``regrasp serve`` and ``regrasp worker``, with its default."""

    model_config = SettingsConfigDict(env_prefix="REGRASP_", extra="ignore", validate_default=True)

    host: str = Field("127.0.0.1", description="address the HTTP server binds")
    port: int = Field(8000, ge=0, le=65535)
    data_dir: Path = Field(Path("var"), description="embedded job store, audit files, dev tokens")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; default sqlite:///<data_dir>/jobs.sqlite (e.g. postgresql+psycopg://u:p@h/db)",
    )
    workers: int = Field(2, ge=0, le=256, description="planning worker processes (0: API only, for split deployments)")
    executor: Literal["local", "ray"] = "local"
    ray_address: str | None = Field(None, description="Ray cluster address; default starts a local Ray instance")
    ray_num_cpus: float | None = Field(
        None, gt=0, description="CPUs a local Ray instance offers (default: one per worker); the workers' actors share them")
    ray_object_store_bytes: int | None = Field(
        None, ge=80 * 1024**2, description="object store of a local Ray instance, bytes (default: Ray's, ~30% of RAM)")
    robot: str = Field("hrp5p", description="robot model the workers load once at start")
    worker_nice: int = Field(10, ge=0, le=19, description="niceness of worker processes, so planning never starves the API")
    preload_robot: bool = Field(True, description="load the robot model in each worker before its first job")
    handlers: dict[str, str] = Field(default_factory=lambda: dict(DEFAULT_HANDLERS))
    check_scenario_names: bool = Field(True, description="refuse unknown built-in scenario names at submit time")

    queue_limit: int = Field(1000, ge=1, description="queued jobs beyond which submissions get 429")
    user_queue_limit: int = Field(100, ge=1, description="jobs one user may have queued or planning; beyond: 429")
    user_stream_limit: int = Field(8, ge=1, description="event streams one user may hold open (per API process); beyond: 429")
    max_states_per_configuration: int = Field(
        500_000, ge=1, description="largest survey a request may ask for: states per hand configuration (or per seed)")
    retry_after_s: int = Field(5, ge=1, description="Retry-After of a 429")
    job_timeout_s: float = Field(900.0, gt=0, description="hard limit of one job's planning time")
    timeout_margin_s: float = Field(10.0, ge=0, description="a job with time_limit_s times out at time_limit_s + this (capped by job_timeout_s)")
    cancel_grace_s: float = Field(0.5, gt=0, description="after a cancel or timeout, how long a worker may take to stop before it is killed")
    max_attempts: int = Field(2, ge=1, description="runs of one job before an interruption fails it")
    lease_s: float = Field(15.0, gt=0, description="a claimed job whose runner has not renewed it for this long is recovered")
    poll_interval_s: float = Field(0.05, gt=0, description="runner loop period")
    progress_min_interval_s: float = Field(0.2, gt=0, description="progress events stored at most this often per job")

    approval_ttl_s: float = Field(900.0, gt=0, description="an approval expires after this long")
    max_body_bytes: int = Field(1_000_000, ge=1024, description="larger request bodies get 413, declared or chunked")
    body_read_timeout_s: float = Field(
        10.0, gt=0, description="a request body not received in full within this long gets 408 and is closed")
    disk_min_free_bytes: int = Field(
        32_000_000, ge=0, description="below this much free space on the data directory's disk the service is sick "
                                      "(503, running jobs fail with the reason)")
    disk_reserve_bytes: int = Field(
        1_000_000, ge=0, description="a file this large is kept in the data directory and given up when the disk "
                                     "fills, so that the jobs' failures can still be recorded")
    header_read_timeout_s: float = Field(
        10.0, gt=0, le=10.0, description="a connection whose request line and headers are not complete within this "
                                         "long (from its opening, or from a request's first byte) is closed")
    list_limit_max: int = Field(500, ge=1)
    list_results_max: int = Field(
        10, ge=1, description="largest page of GET /v1/jobs?include_result=true (results are large); page with offset")
    gzip_min_bytes: int = Field(4096, ge=0, description="responses at least this large are gzipped for clients that accept it")
    sse_poll_s: float = Field(0.2, gt=0, description="how often an SSE stream looks for new events")
    sse_keepalive_s: float = Field(15.0, gt=0)

    tokens: dict[str, TokenEntry] = Field(default_factory=dict, description="bearer token -> user and roles (hashed on load)")
    tokens_file: Path | None = Field(None, description="JSON or YAML file of the same shape as tokens")
    tokens_reload_s: float = Field(2.0, gt=0, description="how often the tokens file is checked for changes (reloaded without a restart)")
    dev: bool = Field(False, description="make demo tokens (loopback only) and print them")
    require_physics_pass: bool = Field(
        False, description="dispatch only plans whose physics dry run (the risk card's) stood, whatever the site policy "
                           "says (it can only add this rule); on under --dev and in the demo")
    metrics_token: str | None = Field(
        None, min_length=16, description="bearer token Prometheus sends for /metrics (user tokens are accepted too)")
    metrics_host: str = Field("127.0.0.1", description="bind address of the separate metrics listener")
    metrics_port: int | None = Field(
        None, ge=1, le=65535, description="serve /metrics without a token on this separate port (e.g. loopback only)")

    tls_cert_file: Path | None = Field(None, description="PEM certificate (chain) of the API's TLS; with tls_key_file")
    tls_key_file: Path | None = Field(None, description="PEM private key of the API's TLS certificate")
    init_store: bool = Field(False, description="initialise a store file that is empty or damaged (moved aside first)")

    audit: bool = Field(True, description="write one MCAP audit file per job when service.audit is installed")
    policy: Path | None = Field(
        None, description="the site's safety policy file (regrasp.policy/1; REGRASP_POLICY, regrasp serve --policy): the "
                          "gate's margin floor, mass and speed caps. Default: the built-in policy (30 mm floor). A "
                          "request never changes it")
    config_file: Path | None = Field(None, alias="REGRASP_CONFIG", description="the file these settings came from")

    @model_validator(mode="after")
    def _tls_pair(self) -> "ServiceSettings":
        if (self.tls_cert_file is None) != (self.tls_key_file is None):
            raise ValueError("TLS needs both tls_cert_file and tls_key_file (or neither)")
        for label, path in (("tls_cert_file", self.tls_cert_file), ("tls_key_file", self.tls_key_file)):
            if path is not None and not path.is_file():
                raise ValueError(f"{label} {path} does not exist")
        return self

    @field_validator("handlers")
    @classmethod
    def _handlers(cls, value: dict[str, str]) -> dict[str, str]:
        for kind, target in value.items():
            if ":" not in target:
                raise ValueError(f"handler for {kind!r} must be 'module:function', got {target!r}")
        return value

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        return (init_settings, env_settings, _ConfigFileSource(settings_cls))

    def safety_policy(self) -> SafetyPolicy:
        """The policy of :attr:`policy` (read now), or the built-in one; :class:`PolicyError` names what is wrong."""
        return policy_from(self.policy)

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'jobs.sqlite').resolve()}"

    @property
    def audit_dir(self) -> Path:
        return self.data_dir / "audit"


def read_config_file(path: Path) -> dict[str, Any]:
    """Parse a YAML, JSON or TOML settings file; errors name the file."""
    if not path.is_file():
        raise ValueError(f"config file {path} does not exist")
    text = path.read_text()
    try:
        if path.suffix == ".json":
            data = json.loads(text)
        elif path.suffix == ".toml":
            data = tomllib.loads(text)
        else:
            data = yaml.safe_load(text)
    except Exception as exc:  # noqa: BLE001 - any parse error is reported the same way
        raise ValueError(f"config file {path} cannot be parsed: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f"config file {path} must hold a mapping of settings, got {type(data).__name__}")
    return data


class _ConfigFileSource(PydanticBaseSettingsSource):
    """Settings from the file named by REGRASP_CONFIG (lowest priority after the defaults)."""

    def get_field_value(self, field: Any, field_name: str) -> tuple[Any, str, bool]:  # pragma: no cover - unused
        return None, field_name, False

    def __call__(self) -> dict[str, Any]:
        name = os.environ.get("REGRASP_CONFIG")
        if not name:
            return {}
        data = read_config_file(Path(name))
        return {k: v for k, v in data.items() if k in self.settings_cls.model_fields}


def load_settings(config_file: Path | None = None, **overrides: Any) -> ServiceSettings:
    """Settings from defaults < config file < environment < explicit overrides (CLI flags)."""
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if config_file is not None:
        file_values = read_config_file(config_file)
        env_values = ServiceSettings().model_dump(exclude_unset=True)
        merged = {**file_values, **env_values, **overrides}
        merged = {k: v for k, v in merged.items() if k in ServiceSettings.model_fields and k != "config_file"}
        return ServiceSettings(**merged, REGRASP_CONFIG=config_file)
    return ServiceSettings(**overrides)
