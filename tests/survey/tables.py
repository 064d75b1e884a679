"""Reading rich tables back from what a console printed, for the survey tests."""

from __future__ import annotations

import re


def table_rows(text: str) -> list[list[str]]:
    """The cells of a rich table's lines (header and body)."""
    out = []
    for line in text.splitlines():
        if line.startswith(("│", "┃")):
            out.append([c.strip() for c in re.split("[│┃]", line.strip().strip("│┃"))])
    return out
