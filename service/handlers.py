"""The job handler table: job kind -> ``"module:function"`` run by the workers.

The default table points at ``planner.entry`` (docs/contract.md section 5 job kinds);
tests and deployments can point a kind somewhere else through settings.
"""

from __future__ import annotations

import importlib
from typing import Any, Callable

from planner.entry import Canceled

Handler = Callable[[dict[str, Any], Any], dict[str, Any]]


class HandlerError(ValueError):
    """A handler target that cannot be imported."""


def resolve(target: str) -> Handler:
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise HandlerError(f"job handler {target!r}: cannot import module {module_name!r} ({exc})") from None
    try:
        fn = getattr(module, attr)
    except AttributeError:
        raise HandlerError(f"job handler {target!r}: module {module_name!r} has no attribute {attr!r}") from None
    if not callable(fn):
        raise HandlerError(f"job handler {target!r} is not callable")
    return fn


class JobCanceled(Exception):
    """Raised by service-side contexts when a cancelled job polls (handlers may raise planner.entry.Canceled too)."""


#: The exception types that mean "the job was cancelled": ours and planner.entry.Canceled.
CANCELED_TYPES: tuple[type[BaseException], ...] = (JobCanceled, Canceled)
