"""``regrasp serve``: the HTTP planning service with its worker pool."""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import click

from .common import console, describe, fail, open_store_or_exit

#: Settings named by the flag that sets them, in error messages.
SETTING_FLAGS = {"host": "--host", "port": "--port", "data_dir": "--data-dir", "database_url": "--database-url",
                 "workers": "--workers", "executor": "--executor", "ray_address": "--ray-address",
                 "tls_cert_file": "--tls-cert", "tls_key_file": "--tls-key"}


def _check_tls(cert: Path, key: Path | None) -> None:
    """Load the certificate and its key as the server will, so that a wrong pair ends here in one line."""
    import ssl

    if key is None:
        fail("--tls-cert needs --tls-key (the certificate's private key)")
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    try:
        context.load_cert_chain(str(cert), str(key))
    except FileNotFoundError as exc:
        fail(f"cannot read {exc.filename}: no such file")
    except ssl.SSLError as exc:
        fail(f"--tls-key {key} is not the private key of --tls-cert {cert}, or one of them is not a PEM file "
             f"({(exc.reason or 'unreadable').lower()})")
    except OSError as exc:
        fail(f"cannot load the TLS certificate {cert} and key {key}: {exc.strerror or exc}")


def _settings_from_flags(config: Path | None, **flags: object):  # type: ignore[no-untyped-def]
    from pydantic import ValidationError

    from service.settings import load_settings

    try:
        return load_settings(config, **flags)
    except (ValidationError, ValueError) as exc:
        fail(f"invalid service settings: {describe(exc, SETTING_FLAGS)}")


@click.command()
@click.option("--host", default=None, help="Bind address (default 127.0.0.1).")
@click.option("--port", type=int, default=None, help="Port (default 8000).")
@click.option("--data-dir", type=click.Path(path_type=Path), default=None, help="Job store and audit files (default ./var).")
@click.option("--database-url", default=None, help="SQLAlchemy URL of a shared store, e.g. postgresql+psycopg://u:p@h/db.")
@click.option("--workers", type=int, default=None, help="Planning worker processes (default 2; 0 = API only).")
@click.option("--dev", is_flag=True, default=False, help="Make demo tokens (loopback only) and print them.")
@click.option("--executor", type=click.Choice(["local", "ray"]), default=None, help="Where jobs run (default local).")
@click.option("--ray-address", default=None, help="Ray cluster address (default: a local Ray instance).")
@click.option("--config", "config", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="Settings file (YAML, JSON or TOML); the environment (REGRASP_*) and flags override it.")
@click.option("--tls-cert", "tls_cert", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="PEM certificate: serve HTTPS (with --tls-key).")
@click.option("--tls-key", "tls_key", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="PEM private key of the TLS certificate.")
@click.option("--init-store", is_flag=True, default=False,
              help="Start a new store when the existing file is empty or damaged (it is moved aside, not deleted).")
@click.option("--policy", "policy", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="The site's safety policy file (regrasp.policy/1; also REGRASP_POLICY): the gate's margin floor, "
                   "mass and speed caps. Default: the built-in policy (30 mm floor).")
@click.option("--log-level", default="info", type=click.Choice(["debug", "info", "warning", "error"]))
def serve(host: str | None, port: int | None, data_dir: Path | None, database_url: str | None, workers: int | None,
          dev: bool, executor: str | None, ray_address: str | None, config: Path | None, tls_cert: Path | None,
          tls_key: Path | None, init_store: bool, log_level: str, policy: Path | None = None) -> None:
    """Run the HTTP planning service (docs/contract.md section 5) with its workers.

    Every setting also comes from a config file or the environment (REGRASP_*): see docs/service.md.
    Exit codes: 0 stopped, 2 invalid settings, 3 the job store is damaged or unreachable.
    """
    import logging

    import uvicorn

    from robot_bridge.process_tuning import freeze_startup_objects
    from service.app import create_app
    from service.api.auth import TokenStore, is_loopback, make_dev_tokens

    if (tls_cert is None) != (tls_key is None):
        fail("--tls-cert needs --tls-key (the certificate's private key)" if tls_key is None
             else "--tls-key needs --tls-cert (the certificate it belongs to)")
    settings = _settings_from_flags(config, host=host, port=port, data_dir=data_dir, database_url=database_url,
                                    workers=workers, executor=executor, ray_address=ray_address,
                                    dev=dev or None, tls_cert_file=tls_cert, tls_key_file=tls_key, policy=policy)
    if settings.tls_cert_file is not None or settings.tls_key_file is not None:
        if settings.tls_cert_file is None:
            fail("--tls-key needs --tls-cert (the certificate it belongs to)")
        _check_tls(settings.tls_cert_file, settings.tls_key_file)
    from schemas.policy import POLICY_ENV, PolicyError

    try:
        site_policy = settings.safety_policy()
    except PolicyError as exc:
        fail(str(exc))
    if settings.policy is not None:  # the workers' processes (risk card's gate dry run) read the same file
        os.environ[POLICY_ENV] = str(Path(settings.policy).resolve())
    if settings.executor == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            fail("--executor ray needs Ray: pip install 'hrp-regrasp[ray]'")
    try:
        tokens = TokenStore.from_settings(settings)
    except ValueError as exc:
        fail(f"cannot load tokens: {exc}")
    if settings.dev:
        if not is_loopback(settings.host):
            fail(f"--dev makes demo tokens and is only allowed on a loopback address, not {settings.host!r}")
        demo = make_dev_tokens()
        tokens.add_plain(demo)
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        token_file = settings.data_dir / "dev-tokens.json"
        fd = os.open(token_file, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as fh:
            json.dump({entry["user"]: {"token": tok, "roles": entry["roles"]} for tok, entry in demo.items()}, fh, indent=2)
        console.print("[bold]demo tokens[/] (loopback only; also in " + str(token_file) + "):")
        for tok, entry in demo.items():
            console.print(f"  {entry['user']:<6} {','.join(entry['roles']):<18} {tok}", highlight=False)
    if len(tokens) == 0:
        console.print("[yellow]warning:[/] no tokens configured: every API call gets 401 "
                      "(set REGRASP_TOKENS, tokens_file, or use --dev)")
    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    # The store is checked before the app opens it: a damaged file ends here with one line, not a traceback.
    open_store_or_exit(settings.resolved_database_url, init_store or settings.init_store)
    app = create_app(settings, tokens=tokens)
    freeze_startup_objects()
    scheme = "https" if settings.tls_cert_file else "http"
    console.print(f"serving on {scheme}://{settings.host}:{settings.port} (console at /, API docs at /docs), "
                  f"{settings.workers} {settings.executor} worker(s), store {settings.resolved_database_url.split('://')[0]}",
                  highlight=False)
    console.print(f"gate: {site_policy.describe()}, margin floor {site_policy.margin_floor_m * 1000:.1f} mm",
                  highlight=False)
    sys.stdout.flush()
    tls = ({"ssl_certfile": str(settings.tls_cert_file), "ssl_keyfile": str(settings.tls_key_file)}
           if settings.tls_cert_file else {})
    from service.api.connections import header_deadline_protocol

    config = uvicorn.Config(app, host=settings.host, port=settings.port, log_level=log_level,
                            access_log=log_level == "debug", timeout_keep_alive=5, h11_max_incomplete_event_size=64 * 1024,
                            http=header_deadline_protocol(settings.header_read_timeout_s), **tls)
    server = _stopping_server(config)
    server.run()
    if not server.started:
        sys.exit(3)  # uvicorn's own code for a server that could not start (the port is taken, ...)
    if server.stop_signals:
        console.print(f"stopped ({', '.join(signal.Signals(s).name for s in server.stop_signals)})", highlight=False)


def _stopping_server(config):  # type: ignore[no-untyped-def]
    """uvicorn's server, except that a SIGTERM or SIGINT is a clean stop: the service shuts down (jobs
    handed back, workers closed) and the process exits 0, where uvicorn would die by the signal again."""
    import contextlib

    import uvicorn

    class StoppingServer(uvicorn.Server):
        stop_signals: list[int] = []

        @contextlib.contextmanager
        def capture_signals(self):  # type: ignore[no-untyped-def]
            with super().capture_signals():
                yield
                # Taken before uvicorn's capture raises them again on leaving.
                self.stop_signals, self._captured_signals[:] = list(self._captured_signals), []

    return StoppingServer(config)
