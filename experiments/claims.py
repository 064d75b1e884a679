"""The paper's claims, judged strictly on survey rows (docs/contract.md section 4b).

A claim that names an ordering ("left-left above the other three") is ``reproduced`` only when
every pair it names is ordered the same way by R and the two 95 % intervals do not overlap: the
higher row's lower bound above the lower row's upper bound. Overlapping intervals are a tie, and
a tie does not reproduce an ordering. A row without a ratio (no plan) fails every claim on it.
"""

from __future__ import annotations

import statistics
from typing import Any

from experiments.tables import STANCES

#: The paper's claims: id -> text.
CLAIM_TEXT: dict[str, str] = {
    "upright-left-hand-most-stable": "Upright: the left-hand configurations (left-left, left-right) are more stable than "
                                     "right-right and right-left.",
    "upright-right-left-least-stable": "Upright: right-left is the least stable configuration.",
    "upright-left-no-removal": "Upright: planning with the left hand first (left-left and left-right) removed no node "
                               "for the CoM margin.",
    "staggered-left-left-most-stable": "Staggered: left-left is the most stable configuration.",
    "staggered-right-hand-endings-least-stable": "Staggered: the configurations ending with the right hand (left-right, "
                                                 "right-right) are less stable than left-left and right-left.",
    "crouched-all-stable": "Crouched: R = 1 for every configuration (every interval's lower bound >= 0.99).",
    "one-legged-left-left-most-stable": "One-legged: left-left is the most stable configuration.",
    "one-legged-right-hand-endings-less-stable": "One-legged: right-right and left-right are less stable than left-left "
                                                 "and right-left.",
    "threshold-changes-motion": "Fig. 1: where the unconstrained (0 mm) plan comes closer than the threshold, the "
                                "constrained plan differs and keeps the threshold.",
    "crouched-most-stable-stance": "The upright task surveyed in each stance: crouched has the highest mean R.",
}

#: Ordering claims: id -> (stance, rows that must be higher, rows that must be lower).
ORDERINGS: dict[str, tuple[str, tuple[str, ...], tuple[str, ...]]] = {
    "upright-left-hand-most-stable": ("upright", ("left-left", "left-right"), ("right-right", "right-left")),
    "upright-right-left-least-stable": ("upright", ("left-left", "right-right", "left-right"), ("right-left",)),
    "staggered-left-left-most-stable": ("staggered", ("left-left",), ("right-right", "left-right", "right-left")),
    "staggered-right-hand-endings-least-stable": ("staggered", ("left-left", "right-left"), ("left-right", "right-right")),
    "one-legged-left-left-most-stable": ("one-legged", ("left-left",), ("right-right", "left-right", "right-left")),
    "one-legged-right-hand-endings-less-stable": ("one-legged", ("left-left", "right-left"), ("right-right", "left-right")),
}

#: The configurations ``upright-left-no-removal`` names: the left hand first, as the paper states it.
NO_REMOVAL_HANDS = ("left-left", "left-right")
#: Lower bound every crouched row must reach.
ALL_STABLE_BOUND = 0.99


def _by_hands(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {r["hands"]: r for r in rows}


def _fmt(row: dict[str, Any] | None) -> str:
    if row is None or row.get("ratio") is None:
        return "n/a"
    ci = row.get("ratio_ci95")
    return f"{row['ratio']:.4f}" + (f" [{ci[0]:.4f}, {ci[1]:.4f}]" if ci else "")


def above(hi: dict[str, Any] | None, lo: dict[str, Any] | None) -> tuple[bool, str]:
    """Whether row ``hi`` is above row ``lo`` with intervals that do not overlap, and why not."""
    for r in (hi, lo):
        if r is None or r.get("ratio") is None:
            return False, f"{(r or {}).get('hands', '?')} has no ratio ({(r or {}).get('reason') or 'not surveyed'})"
        if not r.get("ratio_ci95"):
            return False, f"{r['hands']} has no interval"
    if hi["ratio"] <= lo["ratio"]:
        return False, f"{hi['hands']} {_fmt(hi)} is not above {lo['hands']} {_fmt(lo)}"
    if hi["ratio_ci95"][0] <= lo["ratio_ci95"][1]:
        return False, f"{hi['hands']} {_fmt(hi)} and {lo['hands']} {_fmt(lo)} overlap (a tie)"
    return True, ""


def judge_ordering(rows: list[dict[str, Any]], higher: tuple[str, ...], lower: tuple[str, ...]) -> tuple[bool, str]:
    """Every row of ``higher`` above every row of ``lower``, strictly (non-overlapping intervals)."""
    by = _by_hands(rows)
    fails = []
    for a in higher:
        for b in lower:
            ok, why = above(by.get(a), by.get(b))
            if not ok:
                fails.append(why)
    listing = "; ".join(f"{h} {_fmt(by.get(h))}" for h in (*higher, *lower))
    if fails:
        return False, f"R [95 %]: {listing}. Fails: " + "; ".join(dict.fromkeys(fails))
    return True, f"R [95 %]: {listing}; every pair ordered with non-overlapping intervals"


def judge_all_stable(rows: list[dict[str, Any]], bound: float = ALL_STABLE_BOUND) -> tuple[bool, str]:
    """Every row has a ratio whose interval's lower bound is at least ``bound``."""
    bad = [r for r in rows if r.get("ratio") is None or not r.get("ratio_ci95") or r["ratio_ci95"][0] < bound]
    listing = "; ".join(f"{r['hands']} {_fmt(r)}" for r in rows)
    if bad:
        return False, f"R [95 %]: {listing}. Below {bound}: {', '.join(r['hands'] for r in bad)}"
    return True, f"R [95 %]: {listing}; every lower bound >= {bound}"


def mean_interval(rows: list[dict[str, Any]]) -> tuple[float, float, float] | None:
    """Mean R over the rows with a ratio, and the means of their bounds (a conservative band)."""
    rated = [r for r in rows if r.get("ratio") is not None and r.get("ratio_ci95")]
    if not rated:
        return None
    return (statistics.fmean(r["ratio"] for r in rated), statistics.fmean(r["ratio_ci95"][0] for r in rated),
            statistics.fmean(r["ratio_ci95"][1] for r in rated))


def judge_best_stance(by_stance: dict[str, list[dict[str, Any]]], best: str = "crouched") -> tuple[bool, str]:
    """``best`` has the highest mean R, its band's lower end above every other stance's upper end."""
    means = {s: mean_interval(rows) for s, rows in by_stance.items()}
    listing = "; ".join(f"{s} " + ("n/a" if m is None else f"{m[0]:.4f} [{m[1]:.4f}, {m[2]:.4f}]") for s, m in means.items())
    top = means.get(best)
    if top is None:
        return False, f"mean R [mean bounds]: {listing}. {best} has no ratio"
    fails = [s for s, m in means.items() if s != best and m is not None and not (top[0] > m[0] and top[1] > m[2])]
    if fails:
        return False, f"mean R [mean bounds]: {listing}. Not above with separate bands: {', '.join(fails)}"
    return True, f"mean R [mean bounds]: {listing}"


def judge_threshold_motion(plans: dict[str, dict[str, Any]]) -> tuple[bool, str]:
    """Some stance's 0 mm plan comes closer than the threshold, and every such stance's constrained plan
    differs from it and keeps the threshold."""
    breaking = {s: p for s, p in plans.items() if p.get("unconstrained_breaks_threshold")}
    if not breaking:
        return False, "no stance's 0 mm plan comes closer than the threshold: " + "; ".join(
            f"{s}: 0 mm min margin {_mm(p['unconstrained'].get('min_margin_m'))}, threshold {_mm(p['constrained'].get('threshold_m'))}"
            for s, p in plans.items())
    bad = [s for s, p in breaking.items() if not (p.get("plans_differ") and p["constrained"].get("status") == "solved"
                                                   and p["constrained"]["min_margin_m"] >= p["constrained"]["threshold_m"] - 1e-4)]
    text = "; ".join(f"{s}: 0 mm {_mm(p['unconstrained'].get('min_margin_m'))}, constrained "
                     f"{_mm(p['constrained'].get('min_margin_m'))} ({p['constrained'].get('status')})" for s, p in breaking.items())
    return (not bad), text + (f". The constrained plan fails it in: {', '.join(bad)}" if bad else "")


def judge_no_removal(plans: dict[str, dict[str, Any]]) -> tuple[bool, str]:
    """Every named plan (hands -> plan summary: left-left and left-right) solved with no node removed for the
    CoM margin (their failures by cause)."""
    fails, text = [], []
    for hands, plan in plans.items():
        if plan.get("status") != "solved":
            fails.append(hands)
            text.append(f"the {hands} plan is {plan.get('status')} ({plan.get('failure')})")
            continue
        removed = int((plan.get("failures") or {}).get("com_margin", 0))
        if removed:
            fails.append(hands)
        text.append(f"{hands} plan: {removed} nodes removed for the CoM margin (failures by cause: {plan.get('failures')})")
    return not fails, "; ".join(text)


def _mm(v: float | None) -> str:
    return "n/a" if v is None else f"{v * 1000:.1f} mm"


def evaluate_claims(res: Any) -> list[dict[str, Any]]:
    """Each claim's strict verdict on this run's tables, plans and comparison (no cause runs yet)."""
    out = []
    for cid, text in CLAIM_TEXT.items():
        if cid in ORDERINGS:
            stance, hi, lo = ORDERINGS[cid]
            ok, ev = judge_ordering(res.tables[stance]["rows"], hi, lo)
        elif cid == "crouched-all-stable":
            ok, ev = judge_all_stable(res.tables["crouched"]["rows"])
        elif cid == "upright-left-no-removal":
            ok, ev = judge_no_removal({h: res.plans[f"upright-{h}"]["constrained"] for h in NO_REMOVAL_HANDS})
        elif cid == "threshold-changes-motion":
            ok, ev = judge_threshold_motion({s: res.plans[s] for s in STANCES})
        else:
            ok, ev = judge_best_stance({s: c["rows"] for s, c in res.comparison.items()})
        out.append({"id": cid, "text": text, "verdict": "reproduced" if ok else "not reproduced", "evidence": ev,
                    "cause": None, "cause_run": None, "other_cause_runs": []})
    return out
