"""Bearer-token authentication and role checks.

Tokens are hashed (SHA-256) as soon as they are loaded; the plain tokens never
stay in memory past :meth:`TokenStore.from_settings`, and a token is looked up
by its hash. ``admin`` holds every role.
"""

from __future__ import annotations

import hashlib
import ipaddress
import json
import logging
import secrets
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ..settings import ServiceSettings, TokenEntry

log = logging.getLogger("regrasp.auth")

#: Users and roles made by ``regrasp serve --dev``: a submitter, an approver-operator, a second approver, an admin.
DEV_USERS: dict[str, list[str]] = {
    "alice": ["planner"],
    "bob": ["approver", "operator"],
    "carol": ["approver"],
    "admin": ["admin"],
}


@dataclass(frozen=True)
class Principal:
    user: str
    roles: frozenset[str]

    def has(self, role: str) -> bool:
        return role in self.roles or "admin" in self.roles


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


class TokenStore:
    """Token hash -> principal.

    Tokens given directly (settings, ``--dev``) stay for the process's life; those of a tokens
    file are re-read when the file changes (checked at most every ``reload_s`` seconds, on
    lookup), so a token is added or revoked without a restart. A file that no longer parses
    keeps the previous tokens and is reported in the log.
    """

    def __init__(self, entries: dict[str, Principal] | None = None) -> None:
        self._static: dict[str, Principal] = dict(entries or {})
        self._from_file: dict[str, Principal] = {}
        self._by_hash: dict[str, Principal] = dict(self._static)
        self._file: Path | None = None
        self._file_stamp: tuple[int, int, int] | None = None
        self._reload_s = 2.0
        self._next_check = 0.0
        self._lock = threading.Lock()

    @classmethod
    def from_plain(cls, tokens: dict[str, TokenEntry | dict[str, Any]]) -> "TokenStore":
        store = cls()
        store.add_plain(tokens)
        return store

    def add_plain(self, tokens: dict[str, TokenEntry | dict[str, Any]]) -> None:
        self._static.update(_hashed(tokens))
        self._by_hash = {**self._from_file, **self._static}

    @classmethod
    def from_settings(cls, settings: ServiceSettings) -> "TokenStore":
        store = cls.from_plain(settings.tokens)
        if settings.tokens_file is not None:
            store.watch_file(settings.tokens_file, settings.tokens_reload_s)
        return store

    def watch_file(self, path: Path, reload_s: float = 2.0) -> None:
        """Load the tokens of ``path`` now (errors raise) and reload them whenever the file changes."""
        self._file, self._reload_s = path, reload_s
        stamp = _stamp(path)
        self._from_file = _hashed(read_tokens_file(path))
        self._file_stamp = stamp
        self._by_hash = {**self._from_file, **self._static}
        self._next_check = time.monotonic() + reload_s

    def _maybe_reload(self) -> None:
        now = time.monotonic()
        if self._file is None or now < self._next_check or not self._lock.acquire(blocking=False):
            return
        try:
            self._next_check = now + self._reload_s
            try:
                stamp = _stamp(self._file)
            except OSError as exc:
                if self._file_stamp is not None:
                    log.error("tokens file %s cannot be read (%s); keeping the %d tokens loaded before",
                              self._file, exc.strerror, len(self._from_file))
                    self._file_stamp = None
                return
            if stamp == self._file_stamp:
                return
            try:
                loaded = _hashed(read_tokens_file(self._file))
            except (ValueError, OSError, yaml.YAMLError) as exc:
                log.error("tokens file %s changed but is invalid (%s); keeping the %d tokens loaded before",
                          self._file, str(exc).splitlines()[0][:200], len(self._from_file))
                self._file_stamp = stamp
                return
            self._from_file, self._file_stamp = loaded, stamp
            self._by_hash = {**self._from_file, **self._static}
            log.warning("tokens file %s reloaded: %d tokens", self._file, len(loaded))
        finally:
            self._lock.release()

    def lookup(self, token: str) -> Principal | None:
        self._maybe_reload()
        return self._by_hash.get(hash_token(token))

    def __len__(self) -> int:
        return len(self._by_hash)


def _stamp(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_mtime_ns, st.st_size, st.st_ino


def _hashed(tokens: dict[str, TokenEntry | dict[str, Any]]) -> dict[str, Principal]:
    out: dict[str, Principal] = {}
    for token, entry in tokens.items():
        if len(token) < 8:
            raise ValueError(f"token of user {_user(entry)!r} is shorter than 8 characters")
        entry = entry if isinstance(entry, TokenEntry) else TokenEntry.model_validate(entry)
        out[hash_token(token)] = Principal(entry.user, frozenset(entry.roles))
    return out


def _user(entry: Any) -> str:
    return entry.user if isinstance(entry, TokenEntry) else str(entry.get("user", "?"))


def read_tokens_file(path: Path) -> dict[str, dict[str, Any]]:
    if not path.is_file():
        raise ValueError(f"tokens file {path} does not exist")
    text = path.read_text()
    try:
        data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError):
        raise ValueError(f"tokens file {path} is not valid {'JSON' if path.suffix == '.json' else 'YAML'}") from None
    if not isinstance(data, dict):
        raise ValueError(f"tokens file {path} must map TOKEN -> {{user, roles}}")
    return data


def make_dev_tokens() -> dict[str, dict[str, Any]]:
    """Fresh random tokens for the demo users (printed by ``regrasp serve --dev``)."""
    return {f"dev-{user}-{secrets.token_urlsafe(12)}": {"user": user, "roles": roles} for user, roles in DEV_USERS.items()}


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
