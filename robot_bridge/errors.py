"""The robot bridge's one error hierarchy: every error it raises on purpose derives from :class:`BridgeError`
(and from the built-in its callers catch, ``ValueError`` or ``RuntimeError``, where it did before)."""

from __future__ import annotations


class BridgeError(Exception):
    """Base of every error the robot bridge raises on purpose."""
