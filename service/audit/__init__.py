"""MCAP audit trail: one hash-chained file per job, readable in Foxglove.

- :class:`AuditWriter` writes the file as the job runs and returns the chain head
  after every call (store it with the job).
- :func:`verify` checks framing, CRCs and the chain (exit codes of docs/audit.md).
- :func:`timeline` renders a readable timeline (``regrasp audit show``).
"""

from .chain import GENESIS, record_digest
from .encoding import RawJson
from .timeline import timeline
from .verify import AuditRecord, ExitCode, VerifyResult, Where, verify
from .writer import AuditError, AuditSettings, AuditWriter, shrink_polygon

__all__ = [
    "AuditError",
    "AuditRecord",
    "AuditSettings",
    "AuditWriter",
    "ExitCode",
    "GENESIS",
    "RawJson",
    "VerifyResult",
    "Where",
    "record_digest",
    "shrink_polygon",
    "timeline",
    "verify",
]
