"""``regrasp audit verify|show|layout``: check and read MCAP audit files (docs/audit.md, docs/contract.md section 7), print their Foxglove layout."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from .common import fail, print_json


@click.group("audit")
def audit() -> None:
    """Verify or show an MCAP audit file, or print its Foxglove layout."""


#: Exit code when a file could not be verified at all (missing, unreadable, bad --head): 0, 1 and 2
#: are the verdicts of docs/audit.md, and a script must never read "not checked" as one of them.
EXIT_NOT_VERIFIED = 3


def _existing(path: str) -> Path:
    p = Path(path)
    if not p.is_file():
        fail(f"audit file {path} does not exist or is not a file", code=EXIT_NOT_VERIFIED)
    return p


@audit.command("verify")
@click.argument("file")
@click.option("--head", "head", metavar="SHA", default=None,
              help="The chain head stored with the job; a chain that does not end there is broken.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def verify_cmd(file: str, head: str | None, as_json: bool) -> None:
    """Check the chain and the MCAP CRCs of FILE.

    Exit 0 intact, 1 broken or edited (says where), 2 intact but unfinished, 3 not verified
    (missing or unreadable file, malformed --head).
    """
    from service.audit import verify

    path = _existing(file)
    try:
        result = verify(path, head)
    except ValueError as exc:
        fail(str(exc), code=EXIT_NOT_VERIFIED)
    except OSError as exc:
        fail(f"cannot read {file}: {exc.strerror or exc}", code=EXIT_NOT_VERIFIED)
    if as_json:
        print_json(result.to_json())
    else:
        click.echo(f"{result.status.upper()}: {file}")
        click.echo(f"  {result.detail}")
        if result.where is not None:
            click.echo(f"  where: {result.where.describe()}")
        if result.job_id:
            click.echo(f"  job: {result.job_id}")
        click.echo(f"  verified records: {result.records}")
        if result.head:
            click.echo(f"  last good head: {result.head}")
    sys.exit(result.exit_code)


@audit.command("show")
@click.argument("file")
@click.option("--all", "show_all", is_flag=True, help="List every record, not only events.")
@click.option("--head", "head", metavar="SHA", default=None, help="Also check the chain ends at SHA.")
def show_cmd(file: str, show_all: bool, head: str | None) -> None:
    """Print a readable timeline of FILE (events, state changes, verdicts), then its verdict."""
    from service.audit import timeline

    path = _existing(file)
    try:
        lines, result = timeline(path, show_all=show_all, head=head)
    except ValueError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"cannot read {file}: {exc.strerror or exc}")
    click.echo(f"audit file {file}  job {result.job_id or '?'}")
    for line in lines:
        click.echo(line)
    click.echo("")
    where = f" ({result.where.describe()})" if result.where is not None else ""
    click.echo(f"{result.status.upper()}: {result.detail}{where}")
    sys.exit(result.exit_code)


@audit.command("layout")
@click.option("--out", "out", metavar="FILE", default=None, help="Write the layout to FILE instead of printing it.")
def layout_cmd(out: str | None) -> None:
    """Print the Foxglove layout for audit files (every file also carries it as an attachment).

    Import it in Foxglove with Layouts -> Import from file.
    """
    from service.audit.layout import layout_bytes

    data = layout_bytes()
    if out is None:
        click.echo(data.decode("utf-8"), nl=False)
        return
    try:
        Path(out).write_bytes(data)
    except OSError as exc:
        fail(f"cannot write {out}: {exc.strerror or exc}")
    click.echo(f"wrote {out}")
