"""The job handler table: job kind -> ``"module:function"`` run by the workers.

The default table points at ``planner.jobs.entry`` (one function per job kind of docs/contract.md section 5);
tests and deployments can point a kind somewhere else through settings.
"""

from __future__ import annotations

import importlib
from typing import Any, Callable

from planner.errors import Canceled
from service.errors import RegraspServiceError

Handler = Callable[[dict[str, Any], Any], dict[str, Any]]


class HandlerError(RegraspServiceError, ValueError):
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


class JobCanceled(RegraspServiceError, Canceled):
    """Raised by service-side contexts when a cancelled job polls: the planner's one cancellation type."""


#: The exception types that mean "the job was cancelled" (every one derives from the planner's).
CANCELED_TYPES: tuple[type[BaseException], ...] = (Canceled,)
