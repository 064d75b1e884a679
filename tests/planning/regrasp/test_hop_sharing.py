"""A candidate path's motions planned in this process and a forked helper at once.

Forking is safe only from a single-threaded process, and the test process may hold threads of
other tests (zenoh, uvicorn): each case runs in a fresh interpreter.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
SMALL_BOX = REPO / "tests" / "data" / "small-box.yaml"


def _run(script: str, timeout_s: float = 300.0):
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(script)], cwd=REPO, capture_output=True, text=True,
                         timeout=timeout_s)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("scenario", [str(SMALL_BOX), "drill-handover"], ids=["small-box", "drill-handover"])
def test_shared_hops_give_the_plan_planned_one_by_one(scenario):
    """Each hop draws from its own generator: the helper changes where a motion is planned, not what it
    is, to the last bit of every point (CoM, margin and object pose included). Handover plans, so the
    handover's own motions (planned by the helper) come back too."""
    out = _run(f"""
        import json
        from planner.jobs.plan_job import PlanOptions, build_task, plan_scenario
        from planner.regrasp.settings import PlannerSettings
        from planner.scene.scenarios import load_scenario
        sc = load_scenario({scenario!r})
        docs = {{}}
        for shared in (True, False):
            task = build_task(sc, PlannerSettings(parallel_motions=shared))
            docs[shared] = plan_scenario(sc, PlanOptions(hands="right-left"), task=task)
        print(json.dumps({{str(k): {{"status": d["status"], "q": d["trajectory"],
                           "helper": d["stats"]["configurations"]["right-left"]["hops_by_helper"],
                           "counters": d["stats"]["counters"],
                           "errors": d["stats"]["configurations"]["right-left"].get("helper_errors")}}
                          for k, d in docs.items()}}))
    """)
    shared, alone = out["True"], out["False"]
    assert shared["status"] == alone["status"] == "solved"
    assert shared["errors"] is None
    assert shared["helper"] > 0 and alone["helper"] == 0
    assert shared["q"] == alone["q"]
    # the helper's checks add to this process's (it may plan a hop the one-by-one search never reaches)
    assert all(shared["counters"][k] >= n > 0 for k, n in alone["counters"].items()), (shared["counters"], alone["counters"])


@pytest.mark.host_pauses(limit_s=0.2)
def test_a_cancel_while_sharing_lands_within_a_second_and_ends_the_helper():
    out = _run("""
        import json, os, time
        from planner.regrasp.fork_share import share_with_child
        from planner.regrasp.graph import Canceled
        t0 = time.monotonic()
        stop = lambda: time.monotonic() - t0 > 0.3
        def work(job, in_child):
            end = time.monotonic() + job
            while time.monotonic() < end:  # the helper does not see the cancel: it is ended
                if not in_child and stop():
                    raise Canceled()
                time.sleep(0.005)
            return job
        try:
            share_with_child([0.05, 30.0, 30.0], work, stop)
            outcome = "finished"
        except Canceled:
            outcome = "canceled"
        after_s = time.monotonic() - t0
        me = str(os.getpid())
        children = [p for p in os.listdir("/proc") if p.isdigit() and
                    open(f"/proc/{p}/stat").read().rsplit(")", 1)[1].split()[1] == me]
        print(json.dumps({"outcome": outcome, "after_s": after_s, "children": children}))
    """)
    assert out["outcome"] == "canceled"
    assert out["after_s"] < 0.3 + 1.0
    assert out["children"] == []  # killed and reaped


def test_a_failing_helper_is_reported_and_leaves_its_jobs_to_the_caller():
    out = _run("""
        import json, os, time
        from planner.regrasp.fork_share import share_with_child
        parent = os.getpid()
        def work(job, in_child):
            if in_child:
                raise ValueError(f"job {job} failed in the helper")
            time.sleep(0.2)  # leaves the helper time to start and take a job
            return (job, os.getpid() == parent)
        done, error = share_with_child(list(range(6)), work, lambda: False)
        print(json.dumps({"done": sorted(done), "here": all(v[1] for v in done.values()), "error": error}))
    """)
    assert "ValueError: job" in out["error"] and "failed in the helper" in out["error"]
    assert out["here"]  # what came back was computed here
    assert len(out["done"]) == 5  # the helper took one job and failed it; the caller ran the rest


def test_only_threads_declared_benign_leave_forking_safe():
    """A service worker keeps a thread that watches its parent (sleeps and a system call): declared
    benign, the planner may still fork there; any other thread makes it fall back to one process."""
    out = _run("""
        import json, threading
        from planner.forking import declare_fork_benign, fork_is_safe
        alone = fork_is_safe()
        stop = threading.Event()
        watch = threading.Thread(target=stop.wait, daemon=True)
        watch.start()
        with_undeclared = fork_is_safe()
        declare_fork_benign(watch)
        with_declared = fork_is_safe()
        other = threading.Thread(target=stop.wait, daemon=True)
        other.start()
        with_another = fork_is_safe()
        stop.set()
        print(json.dumps([alone, with_undeclared, with_declared, with_another]))
    """)
    assert out == [True, False, True, False]


@pytest.mark.parametrize("streamed", [True, False], ids=["streamed", "at-the-end"])
def test_the_helper_goes_on_while_its_large_results_wait_to_be_read(streamed):
    """A helper's result larger than the pipe holds (a hop's timed motion is 0.2-0.4 MB), streamed to a caller with
    work of its own (``idle``), is written while the helper works on its next job: the caller, which reads only
    once its own jobs are done, does not end up with the jobs the helper would have taken (a helper stuck on its
    first write does one of the eight). Sent at the end, in one message, they all come back too."""
    out = _run("""
        import json, os, time
        from planner.regrasp.fork_share import share_with_child
        parent = os.getpid()
        def work(job, in_child):
            time.sleep(0.25)
            return (os.getpid() != parent, b"x" * 1_000_000)  # far more than a pipe's 64 KiB
        done, error = share_with_child(list(range(8)), work, lambda: False, (lambda results: False) if STREAMED else None)
        print(json.dumps({"jobs": len(done), "by_helper": sum(1 for by_helper, _ in done.values() if by_helper),
                          "sizes": sorted({len(blob) for _, blob in done.values()}), "error": error}))
    """.replace("STREAMED", repr(streamed)))
    assert out["error"] is None and out["jobs"] == 8 and out["sizes"] == [1_000_000]
    assert out["by_helper"] >= 3  # about half


def test_the_helpers_results_come_back_as_they_are_found():
    """While the caller waits, ``idle`` sees the helper's results so far: the helper's second job waits until
    ``idle`` has seen its first (at most 5 s), which it can only if the first came back before the last."""
    out = _run("""
        import json, os, tempfile, time
        from planner.regrasp.fork_share import share_with_child
        flag = os.path.join(tempfile.mkdtemp(), "seen")
        parent, mine = os.getpid(), []
        def work(job, in_child):
            if in_child:
                mine.append(job)  # the helper's own list after the fork
                end = time.monotonic() + (5.0 if len(mine) == 2 else 0.1)
                while time.monotonic() < end and not (len(mine) == 2 and os.path.exists(flag)):
                    time.sleep(0.01)
            else:
                time.sleep(0.05)
            return os.getpid() != parent
        seen = []
        def idle(results):
            if any(results.values()):
                open(flag, "w").close()
                seen.append(sum(results.values()))
            return False
        t0 = time.monotonic()
        done, error = share_with_child(list(range(6)), work, lambda: False, idle)
        print(json.dumps({"jobs": len(done), "by_helper": sum(done.values()), "seen": seen[:1], "error": error,
                          "took_s": time.monotonic() - t0}))
    """)
    assert out["error"] is None and out["jobs"] == 6
    assert out["seen"] == [1] and out["by_helper"] == 2  # its first result, seen while it worked on its second
    assert out["took_s"] < 4.0  # the second job did not wait out its 5 s
