"""The site's safety policy (``regrasp.policy/1``): limits that belong to the site and the robot, not to a request.

The gate enforces the policy offline (``regrasp gate check``) and at dispatch: a plan made for a margin below
``margin_floor_m`` was not planned for this site, and every sample is checked against the larger of the plan's
threshold and the floor. The floor can be lowered only by editing the policy file; no request field reaches it.
Every gate verdict records the policy's SHA-256 (of its canonical JSON) so the audit shows which rules judged it.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError

POLICY_SCHEMA = "regrasp.policy/1"
#: The environment variable naming the policy file for ``regrasp serve`` and ``regrasp gate check``.
POLICY_ENV = "REGRASP_POLICY"
#: The built-in floor: 30 mm between the system CoM's projection and the support polygon's edge.
DEFAULT_MARGIN_FLOOR_M = 0.03


class PolicyError(ValueError):
    """A policy file that cannot be read or does not validate; the message says which field and why."""


class SafetyPolicy(BaseModel):
    """What every plan must meet at this site, whatever its request asked for."""

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True, allow_inf_nan=False)

    schema_: Literal["regrasp.policy/1"] = Field(POLICY_SCHEMA, alias="schema")
    margin_floor_m: float = Field(DEFAULT_MARGIN_FLOOR_M, ge=0.0, le=0.5,
                                  description="the lowest CoM margin (m) any dispatched sample may have")
    max_object_mass_kg: float | None = Field(None, gt=0.0, description="heaviest held object a plan may carry")
    max_speed_scale: float = Field(1.0, gt=0.0, le=1.0, description="cap on a plan's timing.speed_scale")
    require_physics_pass: bool = Field(False, description="dispatch only plans whose physics dry run stood")
    min_cop_margin_m: float | None = Field(None, ge=0.0, le=0.5,
                                           description="the dry run's floor on the centre-of-pressure margin (m)")

    #: Where the policy came from ("the built-in policy", or its file), for messages; not part of its hash.
    _source: str = PrivateAttr("built-in")

    @property
    def source(self) -> str:
        return self._source

    def with_source(self, source: str) -> "SafetyPolicy":
        """This policy, said to come from ``source`` (a file name) in messages."""
        copy = self.model_copy()
        copy._source = source
        return copy

    def describe(self) -> str:
        """How a message names the policy: its source and the start of its SHA-256."""
        where = "built-in safety policy" if self.source == "built-in" else f"safety policy of {self.source}"
        return f"{where} (sha256 {self.sha256()[:12]})"

    def document(self) -> dict:
        """The policy as its file's JSON object (with ``schema``)."""
        return self.model_dump(by_alias=True)

    def sha256(self) -> str:
        """SHA-256 of the policy's canonical JSON: the identity recorded with every gate verdict."""
        text = json.dumps(self.document(), sort_keys=True, separators=(",", ":"), allow_nan=False)
        return hashlib.sha256(text.encode("utf-8")).hexdigest()

    def effective_threshold_m(self, plan_threshold_m: float) -> float:
        """The margin every sample is checked against: the larger of the plan's threshold and the floor."""
        return max(float(plan_threshold_m), self.margin_floor_m)

    def below_floor(self, plan_threshold_m: float) -> bool:
        """Whether a plan made at ``plan_threshold_m`` was planned below this site's floor (a comparison only)."""
        return float(plan_threshold_m) < self.margin_floor_m - 1e-12


def policy_from(path: str | Path | None) -> SafetyPolicy:
    """The policy in ``path``, or the built-in one when no file is named."""
    return default_policy() if path is None or str(path) == "" else load_policy(path)


def default_policy() -> SafetyPolicy:
    """The built-in policy: a 30 mm floor, no mass cap, full speed allowed, no physics dry run required."""
    return SafetyPolicy()


def load_policy(path: str | Path) -> SafetyPolicy:
    """The policy in the JSON or YAML file ``path``; :class:`PolicyError` names what is wrong."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise PolicyError(f"cannot read the policy file {p}: {e.strerror or e}") from None
    try:
        import yaml

        data = yaml.safe_load(text)
    except Exception as e:  # noqa: BLE001 - any parse error is the file's fault, said in one line
        raise PolicyError(f"the policy file {p} is not valid YAML or JSON: {str(e).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise PolicyError(f"the policy file {p} must hold one object with schema {POLICY_SCHEMA!r}")
    if data.get("schema") != POLICY_SCHEMA:
        raise PolicyError(f"the policy file {p} has schema {data.get('schema')!r}; expected {POLICY_SCHEMA!r}")
    try:
        return SafetyPolicy.model_validate(data).with_source(p.name)
    except ValidationError as e:
        first = e.errors()[0]
        where = ".".join(str(x) for x in first["loc"]) or "(file)"
        raise PolicyError(f"the policy file {p}: {where}: {first['msg']}") from None
