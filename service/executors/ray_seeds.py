"""A survey's seeds as Ray tasks spread over a cluster's nodes (a :class:`planner.survey.seed_map.SeedMap`).

Each seed is one task (one CPU, ``SPREAD`` scheduling, never retried: a seed is cheap to run again
by asking again, and a retried one would only hide a lost node). The per-seed function travels with
the task's definition, so a worker process unpickles it, and builds the task's robot model, once;
later seeds on that worker reuse it. Cancelling a seed (one a converged row no longer needs) cancels its
task (``ray.cancel``: a task still queued never runs, a running one is interrupted and its worker, with the
task it built, is kept for the next seed); closing a cancelled session (the job was cancelled or failed)
force-cancels every task still running, ending its worker process. A soft cancel reaches a task only between
Python bytecodes: a worker busy in a long C call (loading the robot model, compiling the kernels on a cold
worker) can hold its CPU for many seconds after the job ended, and a cancelled job must give the cluster its
CPUs back at once. ``placements`` records where each seed ran (hands, seed, node id): the proof that the
seeds used the cluster's nodes.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future
from typing import Any

from planner.api.jobs import SeedFn


#: How long a cluster's head may take to accept a connection before the address counts as wrong.
REACH_TIMEOUT_S = 5.0


def check_reachable(address: str) -> None:
    """Raise ConnectionError when nothing accepts a connection at a ``host:port`` address (Ray itself
    would retry for minutes); other forms (``auto``, ``ray://...``) are left to Ray."""
    import socket

    host, sep, port = address.rpartition(":")
    if not sep or "://" in address or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=REACH_TIMEOUT_S).close()
    except OSError as exc:
        raise ConnectionError(f"nothing answers at {address} ({exc.strerror or exc})") from None


def connect(address: str | None) -> None:
    """Join the Ray cluster at ``address`` (``auto``: the one this machine belongs to) unless already in one."""
    import ray

    if not ray.is_initialized():
        if address:
            check_reachable(address)
        ray.init(address=address, log_to_driver=False, ignore_reinit_error=True)


def _node_id() -> str:
    import ray

    return ray.get_runtime_context().get_node_id()


class _RaySession:
    def __init__(self, owner: "RaySeeds", fn: SeedFn) -> None:
        import ray

        self._ray = ray
        self._owner = owner

        def run_seed(hands: str, seed: int, keep: bool, _fn: SeedFn = fn) -> tuple[Any, str]:
            return _fn(hands, seed, keep), _node_id()

        self._remote = ray.remote(num_cpus=1, max_retries=0, scheduling_strategy="SPREAD")(run_seed)
        self._refs: dict[Future, Any] = {}

    def submit(self, hands: str, seed: int, keep_states: bool) -> Future:
        ref = self._remote.remote(hands, seed, keep_states)
        out: Future = Future()
        out.set_running_or_notify_cancel()

        def done(inner: Future) -> None:
            try:
                count, node = inner.result()
            except BaseException as exc:  # noqa: BLE001 - handed to the waiting survey as the seed's outcome
                out.set_exception(exc)
                return
            self._owner.record(hands, seed, node)
            out.set_result(count)

        ref.future().add_done_callback(done)
        self._refs[out] = ref
        return out

    def cancel(self, future: Future) -> None:
        ref = self._refs.pop(future, None)
        if ref is not None and not future.done():
            self._ray.cancel(ref)

    def close(self, cancel: bool) -> None:
        if cancel:
            for future, ref in self._refs.items():
                if not future.done():
                    self._ray.cancel(ref, force=True)
        self._refs.clear()


class RaySeeds:
    """Seeds as tasks on the Ray cluster this process is connected to; ``slots`` defaults to its CPUs."""

    def __init__(self, slots: int | None = None) -> None:
        import ray

        self.slots = max(1, int(slots if slots is not None else ray.cluster_resources().get("CPU", 1)))
        self._lock = threading.Lock()
        self.placements: list[tuple[str, int, str]] = []

    def record(self, hands: str, seed: int, node_id: str) -> None:
        with self._lock:
            self.placements.append((hands, seed, node_id))

    def nodes(self) -> set[str]:
        """The ids of the nodes that ran at least one seed."""
        with self._lock:
            return {node for _, _, node in self.placements}

    def open(self, fn: SeedFn) -> _RaySession:
        return _RaySession(self, fn)
