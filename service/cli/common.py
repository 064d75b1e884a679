"""Helpers shared by the CLI commands: error reporting and JSON output."""

from __future__ import annotations

import json
import sys
from typing import Any, NoReturn

import click
from rich.console import Console

console = Console(stderr=False)
err_console = Console(stderr=True)

#: Exit code for usage errors (bad input that prevented work from starting), unknown names included.
EXIT_USAGE = 2
#: Exit code of ``serve``/``worker`` when the job store is damaged or cannot be opened.
EXIT_STORE = 3


def open_store_or_exit(url: str, init: bool) -> None:
    """Check the job store before anything opens it: a damaged store ends the command with one line, code 3."""
    from service.store.integrity import StoreIntegrityError, check_store

    try:
        check_store(url, init=init)
    except StoreIntegrityError as exc:
        fail(str(exc), code=EXIT_STORE)


def fail(message: str, code: int = EXIT_USAGE) -> NoReturn:
    """Print a clear error on stderr, on one line, and exit non-zero."""
    from rich.markup import escape

    line = " ".join(str(message).split())
    err_console.print(f"[bold red]error:[/] {escape(line)}", highlight=False, soft_wrap=True)
    sys.exit(code)


def describe(exc: BaseException, flags: dict[str, str] | None = None) -> str:
    """A validation error as one line for people: each field (as its flag, when ``flags`` names it), what is
    wrong and the value given; never pydantic's class names or its documentation links."""
    from pydantic import ValidationError

    if not isinstance(exc, ValidationError):
        return " ".join(str(exc).split())
    flags = flags or {}
    parts = []
    for err in exc.errors(include_url=False):
        field = ".".join(str(p) for p in err.get("loc", ()))
        label = flags.get(field, field)
        message = str(err.get("msg", "invalid")).removeprefix("Value error, ")
        message = message[:1].lower() + message[1:]
        given = err.get("input")
        shown = f" (got {given!r})" if label and isinstance(given, (int, float, str)) and not isinstance(given, bool) else ""
        parts.append(f"{label}: {message}{shown}" if label else message)
    return "; ".join(parts)


def print_json(doc: Any) -> None:
    click.echo(json.dumps(doc, indent=2, allow_nan=False))


def check_scenario_args(scenario_file: str | None, scenario_name: str | None) -> str:
    """Exactly one of a scenario file or ``--scenario NAME``; returns it."""
    if bool(scenario_file) == bool(scenario_name):
        fail("give a scenario file or --scenario NAME (one of them)")
    return scenario_file or scenario_name  # type: ignore[return-value]


def mm_to_m(flag: str, value_mm: float | None, upper_mm: float = 500.0) -> float | None:
    """A millimetre flag checked at the edge and converted to metres."""
    if value_mm is None:
        return None
    if not 0 <= value_mm <= upper_mm:
        fail(f"{flag} must be between 0 and {upper_mm:g} mm, got {value_mm}")
    return value_mm / 1000.0
