"""The hash chain that makes an audit file tamper-evident.

MCAP's CRCs catch accidental damage but anyone who edits a file can recompute
them. So every message carries ``{"audit": {"seq": i, "prev": H(i-1)}}`` and the
digest of record ``i`` covers its position, channel, times and exact bytes:

    H(i) = SHA-256("regrasp.audit/1\\n" + canonical header JSON + "\\n" + message bytes)

with header ``{"seq", "topic", "schema", "log_time", "publish_time"}``. The last
digest (the *head*) is stored with the job in the database, which stays the
system of record: a file whose chain is intact but ends elsewhere was cut or
rewritten.
"""

from __future__ import annotations

import hashlib
import json

#: Format tag mixed into every digest (bump if the digest input changes).
CHAIN_FORMAT = "regrasp.audit/1"
#: ``prev`` of the first record.
GENESIS = "0" * 64


def record_digest(
    seq: int, topic: str, schema: str, log_time: int, publish_time: int, data: bytes
) -> str:
    """SHA-256 (hex) of one record; see the module docstring for the input."""
    header = json.dumps(
        {"seq": seq, "topic": topic, "schema": schema, "log_time": log_time, "publish_time": publish_time},
        sort_keys=True,
        separators=(",", ":"),
    )
    h = hashlib.sha256()
    h.update(f"{CHAIN_FORMAT}\n{header}\n".encode("utf-8"))
    h.update(data)
    return h.hexdigest()


def is_sha256_hex(text: str) -> bool:
    """True for 64 lowercase/uppercase hex digits (a chain head as users pass it)."""
    return len(text) == 64 and all(c in "0123456789abcdefABCDEF" for c in text)
