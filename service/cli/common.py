"""Helpers shared by the CLI commands: error reporting and JSON output."""

from __future__ import annotations

import json
import sys
from typing import Any, NoReturn

import click
from rich.console import Console

console = Console(stderr=False)
err_console = Console(stderr=True)

#: Exit code for usage errors (bad input that prevented work from starting).
EXIT_USAGE = 2


def fail(message: str, code: int = EXIT_USAGE) -> NoReturn:
    """Print a clear error on stderr and exit non-zero."""
    err_console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    sys.exit(code)


def print_json(doc: Any) -> None:
    click.echo(json.dumps(doc, indent=2, allow_nan=False))
