"""The risk card's cost: the safety gate's offline dry run of a plan, made when the plan is made.

Plans one built-in scenario (default ``upright``) and times :func:`service.jobs.risk.risk_card` on its
canonical JSON (what the worker hands it: hash, typed decode, every check) ``--repeats`` times. Prints
the plan's samples and the median and range of the card's time, with the machine's load.
Run: ``python benchmarks/bench_risk_card.py [--scenario upright] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from planner.api.catalogue import resolve_scenario  # noqa: E402
from planner.api.jobs import PlanOptions, plan_scenario  # noqa: E402
from schemas.plan import canonical_json  # noqa: E402
from service.jobs.risk import risk_card  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="upright")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    plan = plan_scenario(resolve_scenario(args.scenario), PlanOptions())
    if plan["status"] != "solved":
        print(f"{args.scenario}: the plan is {plan['status']} ({plan.get('message')}); no card to time")
        return 1
    text = canonical_json(plan)
    risk_card(plan, text)  # the first card also builds the gate's model of the robot
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        card = risk_card(plan, text)
        times.append(time.perf_counter() - t0)
    print(f"{args.scenario}: {card['gate']['samples']} samples ({plan['trajectory'][-1]['t']:.1f} s of plan, "
          f"{len(text) / 1e6:.1f} MB), gate {'passed' if card['gate']['passed'] else 'vetoed: ' + str(card['gate']['check'])}")
    print(f"  risk card: median {statistics.median(times):.2f} s, {min(times):.2f}-{max(times):.2f} s over "
          f"{args.repeats} runs (load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
