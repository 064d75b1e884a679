"""``regrasp schema export DIR``."""

from __future__ import annotations

from pathlib import Path

import click


@click.group()
def schema() -> None:
    """JSON Schemas of the wire contract."""


@schema.command("export")
@click.argument("directory", type=click.Path(file_okay=False))
def export(directory: str) -> None:
    """Write the JSON Schema files of the plan, survey, scenario, jobs and bridge messages to DIRECTORY."""
    from schemas.export import export_schemas

    for path in export_schemas(Path(directory)):
        click.echo(str(path))
