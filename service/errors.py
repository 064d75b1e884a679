"""The service's one error hierarchy: every error it raises on purpose derives from
:class:`RegraspServiceError` (and from the built-in its callers catch, where it did before)."""

from __future__ import annotations


class RegraspServiceError(Exception):
    """Base of every error the planning service raises on purpose."""
