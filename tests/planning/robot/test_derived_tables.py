"""The tables derived from a shared robot model: built once even when threads race for them,
and kept through pickling (a model travels to spawned workers)."""

from __future__ import annotations

import pickle
import threading
import time

from planner.robot.model import DerivedTables


def test_racing_threads_build_a_table_once_and_all_get_it():
    tables = DerivedTables()
    builds = []

    def build():
        builds.append(threading.get_ident())
        time.sleep(0.05)  # wide enough that every thread arrives while the first one builds
        return object()

    got = []
    threads = [threading.Thread(target=lambda: got.append(tables.get("joint-table", build))) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(builds) == 1
    assert len(got) == 8 and all(g is got[0] for g in got)


def test_a_build_may_ask_for_another_table():
    tables = DerivedTables()
    outer = tables.get("outer", lambda: ("outer", tables.get("inner", lambda: "inner")))
    assert outer == ("outer", "inner")
    assert tables.get("inner", lambda: "rebuilt") == "inner"


def test_pickled_tables_keep_their_contents_and_get_a_fresh_lock():
    tables = DerivedTables()
    tables.get("a", lambda: [1, 2, 3])
    copy = pickle.loads(pickle.dumps(tables))
    assert copy.get("a", lambda: "rebuilt") == [1, 2, 3]
    assert copy.get("b", lambda: "built") == "built"
