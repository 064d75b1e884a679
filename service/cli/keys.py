"""``regrasp keys``: the dispatcher's Ed25519 key pair that signs every command to the robot (docs/robot_bridge.md).

``regrasp keys generate DIR`` writes ``DIR/dispatcher.key`` (PKCS#8 PEM, mode 0600:
the service signs with it, ``REGRASP_BRIDGE_SIGNING_KEY``) and ``DIR/dispatcher.pub``
(SubjectPublicKeyInfo PEM: the controller's trusted key, ``controller-sim --trusted-key``).
"""

from __future__ import annotations

import json

import click

from .common import fail


@click.group("keys")
def keys() -> None:
    """Make the key pair that signs the bridge's commands."""


@keys.command("generate")
@click.argument("directory", type=click.Path(file_okay=False))
@click.option("--force", is_flag=True, help="Replace an existing pair in DIRECTORY.")
def generate(directory: str, force: bool) -> None:
    """Write DIRECTORY/dispatcher.key (private, 0600) and DIRECTORY/dispatcher.pub (public)."""
    from robot_bridge.signing import generate_keys

    try:
        private, public = generate_keys(directory, overwrite=force)
    except FileExistsError as exc:
        fail(f"{exc} (--force replaces them)")
    except OSError as exc:
        fail(f"cannot write keys into {directory}: {exc.strerror or exc}")
    click.echo(json.dumps({"private_key": str(private.resolve()), "public_key": str(public.resolve())}))
