"""The executor a service's settings ask for: local worker processes, or a Ray cluster."""

from __future__ import annotations

from ..settings import ServiceSettings
from .base import Executor


def make_executor(settings: ServiceSettings) -> Executor:
    """A local executor, or a Ray one when ``settings.executor == "ray"`` (Ray imported only then)."""
    if settings.executor == "ray":
        from .ray_executor import RayExecutor

        return RayExecutor(settings)
    from .local import LocalExecutor

    return LocalExecutor(settings)
