"""Ed25519 signatures of the bridge's commands (every ``cmd/*`` message).

A command is a JSON object. Its signature, ``"sig"`` (standard base64), is made by
the dispatcher's private key over the UTF-8 bytes of the object *without* ``sig``
in canonical form: ``json.dumps(msg, sort_keys=True, separators=(",", ":"),
allow_nan=False)`` (ASCII-escaped; floats in Python's shortest round-trip form,
as the plan hash uses). The receiver parses the message, takes ``sig`` out,
rebuilds the canonical bytes and verifies them with the trusted public key, so
the bytes on the wire need not be canonical themselves.

Keys are PEM files: the private key PKCS#8 (written with mode 0600), the public
key SubjectPublicKeyInfo (``regrasp keys generate DIR``).
"""

from __future__ import annotations

import base64
import binascii
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)
from pydantic_core import from_json

from robot_bridge.errors import BridgeError

#: File names written by :func:`generate_keys` (``regrasp keys generate DIR``).
PRIVATE_KEY_FILE = "dispatcher.key"
PUBLIC_KEY_FILE = "dispatcher.pub"
#: Field of a command that holds its signature.
SIG_FIELD = "sig"


class KeyFileError(BridgeError, ValueError):
    """A key file that is missing, unreadable or not an Ed25519 key of the expected kind."""


def canonical_bytes(msg: dict[str, Any]) -> bytes:
    """The bytes a signature covers: the message without ``sig``, canonical JSON, UTF-8."""
    body = {k: v for k, v in msg.items() if k != SIG_FIELD}
    return json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


@dataclass(frozen=True)
class Signer:
    """Signs commands with the dispatcher's private key."""

    key: Ed25519PrivateKey

    @classmethod
    def from_file(cls, path: str | os.PathLike[str]) -> "Signer":
        return cls(load_private_key(path))

    def signature(self, canonical: bytes) -> str:
        """The base64 signature of already-canonical bytes."""
        return base64.b64encode(self.key.sign(canonical)).decode("ascii")

    def sign(self, msg: dict[str, Any]) -> dict[str, Any]:
        """A copy of ``msg`` with its ``sig``."""
        return {**msg, SIG_FIELD: self.signature(canonical_bytes(msg))}

    def encode(self, msg: dict[str, Any]) -> bytes:
        """The signed message as the bytes published: the canonical body with ``sig`` added as its last field.

        One serialisation: the signed bytes are the body, and the wire form appends ``,"sig":"..."`` to them."""
        body = canonical_bytes(msg)
        return body[:-1] + b',"sig":"' + self.signature(body).encode("ascii") + b'"}'

    def public_key(self) -> "Verifier":
        return Verifier(self.key.public_key())


@dataclass(frozen=True)
class Verifier:
    """Checks commands against the dispatcher's public key (the controller's trusted key)."""

    key: Ed25519PublicKey

    @classmethod
    def from_file(cls, path: str | os.PathLike[str]) -> "Verifier":
        return cls(load_public_key(path))

    def problem(self, msg: dict[str, Any]) -> str | None:
        """Why ``msg`` is not signed by the trusted key, or None when its signature is good."""
        sig = msg.get(SIG_FIELD)
        if sig is None:
            return "unsigned: the message carries no sig"
        if not isinstance(sig, str):
            return "bad signature: sig is not a base64 string"
        try:
            raw = base64.b64decode(sig, validate=True)
        except (binascii.Error, ValueError):
            return "bad signature: sig is not valid base64"
        if len(raw) != 64:
            return f"bad signature: an Ed25519 signature has 64 bytes, sig has {len(raw)}"
        try:
            body = canonical_bytes(msg)
        except ValueError as exc:  # NaN or Inf: never canonical
            return f"bad signature: the message has no canonical form ({exc})"
        try:
            self.key.verify(raw, body)
        except InvalidSignature:
            return "bad signature: it does not verify with the trusted key"
        return None


def open_signed(payload: bytes, verifier: "Verifier") -> tuple[Any, str | None]:
    """Parse a received command and check its signature: ``(message, None)`` when it verifies, else
    ``(message or None, why)``.

    Fast path: a sender that writes the canonical body with ``,"sig":"..."}`` appended (as
    :meth:`Signer.encode` does) has its signature checked over exactly the body bytes, which are then the
    bytes parsed, with no second serialisation. Any other layout takes the general path (parse, rebuild
    the canonical form without ``sig``, verify)."""
    tail = payload.rfind(b',"sig":"')
    if tail > 0 and payload.endswith(b'"}'):
        body = payload[:tail] + b"}"
        try:
            raw = base64.b64decode(payload[tail + 8:-2], validate=True)
            if len(raw) == 64:
                verifier.key.verify(raw, body)
                msg = from_json(body)  # pydantic-core's parser: ~5x json.loads on a segment's 2,000 floats
                if isinstance(msg, dict) and SIG_FIELD not in msg:
                    return msg, None
        except (binascii.Error, ValueError, InvalidSignature, UnicodeDecodeError):
            pass
    try:
        msg = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return None, "malformed: not JSON"
    if not isinstance(msg, dict):
        return None, "malformed: not a JSON object"
    return msg, verifier.problem(msg)


def load_private_key(path: str | os.PathLike[str]) -> Ed25519PrivateKey:
    """The Ed25519 private key of a PKCS#8 PEM file (unencrypted)."""
    data = _read(path, "private key")
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError) as exc:
        raise KeyFileError(f"{path}: not an unencrypted PEM private key ({exc})") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise KeyFileError(f"{path}: a {type(key).__name__}, not an Ed25519 private key")
    return key


def load_public_key(path: str | os.PathLike[str]) -> Ed25519PublicKey:
    """The Ed25519 public key of a SubjectPublicKeyInfo PEM file."""
    data = _read(path, "public key")
    try:
        key = serialization.load_pem_public_key(data)
    except (ValueError, TypeError) as exc:
        raise KeyFileError(f"{path}: not a PEM public key ({exc})") from None
    if not isinstance(key, Ed25519PublicKey):
        raise KeyFileError(f"{path}: a {type(key).__name__}, not an Ed25519 public key")
    return key


def _read(path: str | os.PathLike[str], what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise KeyFileError(f"cannot read the {what} {path}: {exc.strerror or exc}") from None


def generate_keys(directory: str | os.PathLike[str], overwrite: bool = False) -> tuple[Path, Path]:
    """Write a new key pair into ``directory``: ``dispatcher.key`` (PKCS#8 PEM, mode 0600) and
    ``dispatcher.pub`` (SubjectPublicKeyInfo PEM). Refuses to replace existing files unless ``overwrite``."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    private, public = out / PRIVATE_KEY_FILE, out / PUBLIC_KEY_FILE
    if not overwrite:
        existing = [str(p) for p in (private, public) if p.exists()]
        if existing:
            raise FileExistsError(f"{', '.join(existing)} already exist; remove them or overwrite on purpose")
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    pub = key.public_key().public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
    if private.exists():
        private.unlink()
    # Created 0600 from the start: the private key is never readable by others, not even for a moment.
    fd = os.open(private, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    os.chmod(private, 0o600)
    public.write_bytes(pub)
    return private, public
