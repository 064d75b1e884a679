"""The ``regrasp`` command line.

Each command lives in its own module under ``service/cli/`` and is imported only
when it runs, so ``regrasp --help`` stays fast (pinocchio, zenoh and FastAPI load
only for the commands that need them).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys

import click

#: command name -> (module under service.cli, attribute, one-line help)
COMMANDS: dict[str, tuple[str, str, str]] = {
    "demo": ("demo", "demo", "Run the main job end to end on the embedded defaults."),
    "robot": ("robot", "robot", "List robots, print a URDF path, or describe a robot."),
    "scenario": ("scenario", "scenario", "List, show or check scenarios."),
    "plan": ("plan", "plan", "Plan a regrasp task and write the plan file."),
    "survey": ("survey", "survey", "Run the task stability survey per hand configuration."),
    "schema": ("schema", "schema", "Export the JSON Schemas of the wire contract."),
    "serve": ("serve", "serve", "Run the HTTP planning service."),
    "worker": ("worker", "worker", "Run planning workers against a shared job store."),
    "gate": ("gate", "gate", "Run the safety gate offline on a plan file."),
    "simulate": ("simulate", "simulate", "Play a plan in the physics twin and report its balance."),
    "controller-sim": ("controller_sim", "controller_sim", "Run the simulated HRP-5P controller peer."),
    "audit": ("audit", "audit", "Verify or show an MCAP audit file."),
    "keys": ("keys", "keys", "Make the key pair that signs the robot bridge's commands."),
    "paper": ("paper", "paper", "Reproduce the paper's experiments and write the report."),
}


def _available(name: str) -> bool:
    module = COMMANDS[name][0]
    return importlib.util.find_spec(f"service.cli.{module}") is not None


class LazyGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return [name for name in COMMANDS if _available(name)]

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in COMMANDS or not _available(cmd_name):
            return None
        module, attr, _ = COMMANDS[cmd_name]
        return getattr(importlib.import_module(f"service.cli.{module}"), attr)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, COMMANDS[name][2]) for name in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="hrp-regrasp", prog_name="regrasp")
def cli() -> None:
    """Regrasp planning for the HRP-5P humanoid under bipedal stability constraints."""


#: Exceptions that mean "this name is not known" or "this input is unusable" (module, class): every command
#: ends on them with exit 2. The planner's input errors all derive from its InputError (planner.errors).
UNKNOWN_NAME_ERRORS: tuple[tuple[str, str], ...] = (
    ("planner.errors", "InputError"),
)
#: Exit code of a usage error (service.cli.common.EXIT_USAGE, kept here so --help imports nothing).
EXIT_USAGE = 2


def _is_unknown_name(exc: BaseException) -> bool:
    """True for the planner's errors about unknown names and unusable input (only modules already loaded can raise them)."""
    for module, name in UNKNOWN_NAME_ERRORS:
        cls = getattr(sys.modules.get(module), name, None)
        if isinstance(cls, type) and isinstance(exc, cls):
            return True
    return False


def main(argv: list[str] | None = None) -> int:
    """Run one command; an unknown name anywhere ends it with a one-line error and exit code 2 (no traceback)."""
    try:
        cli.main(args=argv, prog_name="regrasp", standalone_mode=False)
    except SystemExit as exc:
        return int(exc.code or 0)
    except click.exceptions.Exit as exc:
        return int(exc.exit_code or 0)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 1
    except click.exceptions.NoArgsIsHelpError as exc:
        exc.show()  # a group called without a command: its help
        return exc.exit_code
    except click.UsageError as exc:
        # One line: what is wrong, and where the command's help is (click's default prints three).
        where = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
        click.echo(f"error: {' '.join(exc.format_message().split())}{where}", err=True)
        return EXIT_USAGE
    except click.ClickException as exc:
        click.echo(f"error: {' '.join(exc.format_message().split())}", err=True)
        return exc.exit_code
    except Exception as exc:  # noqa: BLE001 - re-raised unless it is a usage error
        if not _is_unknown_name(exc):
            raise
        message = " ".join(str(exc).split()) or "invalid input"
        click.echo(f"error: {message}", err=True)
        return EXIT_USAGE
    return 0


if __name__ == "__main__":
    sys.exit(main())
