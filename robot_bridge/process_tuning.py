"""Process-wide tuning for the processes that carry bridge traffic (the controller, the service)."""

from __future__ import annotations

import gc


def freeze_startup_objects() -> None:
    """Move what exists now (modules, schemas, settings, sessions: it lives as long as the process) out of
    the garbage collector's reach. A full collection over it stops every thread, zenoh callbacks and the
    dispatcher's sends included: 20-40 ms in the controller (~40k objects), ~67 ms in the service (~113k)."""
    gc.collect()
    gc.freeze()
