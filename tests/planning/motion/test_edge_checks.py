"""The coarse-to-fine check of many edges (planner/motion/edge_checks.py): the same answer as checking every state,
whatever the levels, each state checked once."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.motion.edge_checks import all_valid_coarse_to_fine


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), edges=st.integers(1, 12),
       strides=st.sampled_from([(5,), (25, 5), (7, 3, 2), (1,)]))
def test_the_levels_give_the_answer_of_every_state_and_check_each_once(seed, edges, strides):
    rng = np.random.default_rng(seed)
    parts = [rng.uniform(-1, 1, (int(rng.integers(1, 80)), 2)) for _ in range(edges)]
    bad_share = rng.uniform(0.0, 0.05)
    bad = [rng.random(len(p)) < bad_share for p in parts]  # each state's verdict, looked up by its values
    verdict = {p[i].tobytes(): not b[i] for p, b in zip(parts, bad) for i in range(len(p))}
    seen: list[bytes] = []

    def validity(Q: np.ndarray):
        seen.extend(q.tobytes() for q in Q)
        ok = np.array([verdict[q.tobytes()] for q in Q])
        return ok, ok.astype(float)

    got = all_valid_coarse_to_fine(parts, validity, strides)
    assert got == [not b.any() for b in bad]
    assert len(seen) == len(set(seen))  # no state checked twice
    assert len(seen) <= sum(len(p) for p in parts)
