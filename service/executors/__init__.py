"""Executors run claimed jobs somewhere: local spawn worker processes, or a Ray cluster."""

from .base import ExecEvent, Executor
from .factory import make_executor

__all__ = ["ExecEvent", "Executor", "make_executor"]
