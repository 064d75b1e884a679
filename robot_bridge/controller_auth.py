"""The controller's authentication of commands: the dispatcher's signature and the receipt deadline.

Part of the protocol-and-safety layer (``controller_sim``). A command is opened only when it is signed by the
trusted key and its ``expires_at`` is neither past at receipt nor further ahead than the contract's longest
receipt deadline (10 s), both with the allowed clock skew (docs/robot_bridge.md, the integrator's checklist).
"""

from __future__ import annotations

import json
import math
import time
from typing import Any

from .signing import Verifier, open_signed


class CommandAuth:
    """Opens signed commands for a controller holding ``verifier`` (None: no trusted key, only stop is obeyed)."""

    def __init__(self, verifier: Verifier | None, clock_skew_s: float, max_expiry_ahead_s: float):
        self.verifier = verifier
        self.clock_skew_s = clock_skew_s
        self.max_expiry_ahead_s = max_expiry_ahead_s

    def open(self, payload: bytes) -> tuple[Any, str | None]:
        """(the parsed message or None, the problem that refuses it or None)."""
        if self.verifier is None:
            try:
                msg = json.loads(payload)
            except (ValueError, UnicodeDecodeError):
                msg = None
            return msg, "no trusted key is configured: only cmd/stop is obeyed"
        msg, problem = open_signed(payload, self.verifier)
        if problem is None and isinstance(msg, dict):
            problem = self.expiry_problem(msg, time.time())
        return msg, problem

    def expiry_problem(self, msg: dict, now: float) -> str | None:
        """Why the receipt at Unix time ``now`` is outside the message's deadline, or None."""
        expires = msg.get("expires_at")
        if not isinstance(expires, (int, float)) or isinstance(expires, bool) or not math.isfinite(expires):
            return "no expires_at"
        skew = self.clock_skew_s
        late = now - (float(expires) + skew)
        if late > 0:
            return f"expired: received {late + skew:.3f} s after its expires_at (clock skew allowance {skew:.3f} s)"
        ahead = float(expires) - now
        if ahead > self.max_expiry_ahead_s + skew:
            return (f"expires_at too far ahead: {ahead:.3f} s after its receipt, more than the "
                    f"{self.max_expiry_ahead_s:g} s allowed (clock skew allowance {skew:.3f} s)")
        return None

    def stop_auth(self, raw: Any) -> str:
        """How a stop was authenticated, for the log (a stop is obeyed whatever this says)."""
        if self.verifier is None:
            return "unverified (no trusted key)"
        if not isinstance(raw, dict):
            return "unsigned (malformed)"
        problem = self.verifier.problem(raw)
        return "signed" if problem is None else problem.split(":")[0]
