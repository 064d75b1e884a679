"""Bearer-token authentication and role checks.

Tokens are hashed (SHA-256) as soon as they are loaded; the plain tokens never
stay in memory past :meth:`TokenStore.from_settings`, and a token is looked up
by its hash. ``admin`` holds every role.
"""

from __future__ import annotations

import hashlib
import ipaddress
import json
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from .settings import ServiceSettings, TokenEntry

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
    """Token hash -> principal."""

    def __init__(self, entries: dict[str, Principal] | None = None) -> None:
        self._by_hash: dict[str, Principal] = dict(entries or {})

    @classmethod
    def from_plain(cls, tokens: dict[str, TokenEntry | dict[str, Any]]) -> "TokenStore":
        store = cls()
        store.add_plain(tokens)
        return store

    def add_plain(self, tokens: dict[str, TokenEntry | dict[str, Any]]) -> None:
        for token, entry in tokens.items():
            if len(token) < 8:
                raise ValueError(f"token of user {_user(entry)!r} is shorter than 8 characters")
            entry = entry if isinstance(entry, TokenEntry) else TokenEntry.model_validate(entry)
            self._by_hash[hash_token(token)] = Principal(entry.user, frozenset(entry.roles))

    @classmethod
    def from_settings(cls, settings: ServiceSettings) -> "TokenStore":
        store = cls.from_plain(settings.tokens)
        if settings.tokens_file is not None:
            store.add_plain(read_tokens_file(settings.tokens_file))
        return store

    def lookup(self, token: str) -> Principal | None:
        return self._by_hash.get(hash_token(token))

    def __len__(self) -> int:
        return len(self._by_hash)


def _user(entry: Any) -> str:
    return entry.user if isinstance(entry, TokenEntry) else str(entry.get("user", "?"))


def read_tokens_file(path: Path) -> dict[str, dict[str, Any]]:
    if not path.is_file():
        raise ValueError(f"tokens file {path} does not exist")
    text = path.read_text()
    data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
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
