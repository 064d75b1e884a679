"""The paper's own data: Tables I-IV, the real-robot tasks, and the inconsistencies we read around."""

from __future__ import annotations

from planner.api.catalogue import BUILTIN_STANCES as STANCES

__all__ = ["DRILL_TASKS", "INCONSISTENCIES", "PAPER_TABLES", "STANCES"]

#: The paper's Tables I-IV: (C, U, R) per hand configuration.
PAPER_TABLES: dict[str, dict[str, tuple[int, int, float]]] = {
    "upright": {"left-left": (10529, 15, 0.9986), "right-right": (15991, 1801, 0.8998),
                "left-right": (11189, 41, 0.9963), "right-left": (5391, 7351, 0.4231)},
    "staggered": {"left-left": (6447, 135, 0.9795), "right-right": (250, 90, 0.64),
                  "left-right": (2135, 6482, 0.2478), "right-left": (1370, 390, 0.7784)},
    "crouched": {"left-left": (12242, 0, 1.0), "right-right": (654, 0, 1.0),
                 "left-right": (6901, 0, 1.0), "right-left": (14754, 0, 1.0)},
    "one-legged": {"left-left": (2628, 0, 1.0), "right-right": (4299, 2401, 0.6416),
                   "left-right": (2558, 2444, 0.5113), "right-left": (1306, 88, 0.9368)},
}
DRILL_TASKS = ("drill-handover", "drill-upright")

INCONSISTENCIES = [
    ("The crouched object is 15 kg in the simulation set-up and 8 kg in the analysis.",
     "We follow 15 kg, the figure of the set-up paragraph that describes the run (planner/scene/scenario_data/crouched.yaml)."),
    ("The analysis paragraph headed 'staggered' (the second one) describes the one-legged results (Table IV, Fig. 5).",
     "We read it as the one-legged analysis and check its claim against our one-legged table."),
    ("'0 unstable poses recorded' stands beside U = 135 for the staggered left-hand configuration.",
     "We read '0 unstable poses' as the executed (planned) path, and U as the explored states; both are reported here separately."),
    ("'The constraints for the one-legged stance are softened' is never explained.",
     "We apply no softening: the one-legged stance uses the same rule (margin >= 30 mm) on the one-sole polygon."),
]
