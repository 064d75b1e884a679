"""The cells of `regrasp plan`'s summary table, read back for the plan tests."""

from __future__ import annotations

from service.cli.plan import summary_table


def summary_cells(plan: dict) -> dict[str, str]:
    """Label -> value of the summary table printed for one plan."""
    table = summary_table([("plan", plan)])
    labels, values = table.columns[0]._cells, table.columns[1]._cells
    return dict(zip(labels, values))
