"""Owner ids and the owners alive in this process, as job recovery reads them."""

from __future__ import annotations

import os
import subprocess
import sys

from service.jobs.owners import LiveOwners, make_owner_id
from service.store.repo import this_host


def test_an_owner_of_this_process_is_alive_only_while_registered() -> None:
    owners = LiveOwners()
    me = make_owner_id()
    assert owners.is_dead(me)  # our pid, not registered: a runner of this process that stopped
    owners.add(me)
    assert not owners.is_dead(me) and me in owners
    owners.discard(me)
    assert owners.is_dead(me)


def test_two_registries_are_independent() -> None:
    a, b = LiveOwners(), LiveOwners()
    me = make_owner_id()
    a.add(me)
    assert not a.is_dead(me) and b.is_dead(me)


def test_an_owner_whose_process_ended_is_dead_and_another_host_is_left_to_its_lease() -> None:
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    gone = f"{this_host()}:{int(child.stdout)}:deadbeef"
    owners = LiveOwners()
    assert owners.is_dead(gone)
    assert not owners.is_dead(f"{this_host()}:{os.getppid()}:00000000")  # a live process of this host
    assert not owners.is_dead(f"another-host.example:{os.getpid()}:00000000")
