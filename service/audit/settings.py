"""Tunables of the audit writer and its error type."""

from __future__ import annotations

from typing import Literal

from pydantic_settings import BaseSettings, SettingsConfigDict

from service.errors import RegraspServiceError


class AuditSettings(BaseSettings):
    """Tunables of the audit writer (environment: ``REGRASP_AUDIT_*``)."""

    model_config = SettingsConfigDict(env_prefix="REGRASP_AUDIT_")

    #: Upper bound of one MCAP chunk; a bulk write (plan playback) spans several.
    chunk_size_bytes: int = 256 * 1024
    #: ``zstd`` (the default; the ``zstandard`` package at its default level) compresses every chunk;
    #: ``none`` keeps the file greppable (debugging).
    compression: Literal["none", "zstd"] = "zstd"
    #: fsync after every call: survives power loss, not only a killed process.
    fsync: bool = False
    #: Rate at which a plan is sampled for playback in Foxglove (the full plan is
    #: in its ``plan`` event at full rate).
    plan_playback_rate_hz: float = 50.0
    #: Height of the support-polygon outlines above the ground (visible over a grid).
    marker_lift_m: float = 0.002
    #: Diameter of the CoM sphere marker.
    com_marker_diameter_m: float = 0.04
    #: Diameter of the ZMP disc on the floor.
    zmp_marker_diameter_m: float = 0.03
    #: Derive Foxglove views (plan playback, executed joint states) from ``record`` payloads.
    auto_visualize: bool = True
    #: Highest rate of the robot's /tf (every joint state is still recorded;
    #: the transforms only animate the model). 0 = a transform for every state.
    executed_tf_rate_hz: float = 25.0
    #: Rate at which the plan is replayed on the execution's timeline (``/executed_plan/``, per second of plan).
    executed_plan_rate_hz: float = 25.0
    #: Attach the Foxglove layout shipped with the package to every file.
    attach_layout: bool = True


class AuditError(RegraspServiceError, RuntimeError):
    """The audit file cannot be written (closed writer, bad input)."""
