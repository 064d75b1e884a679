"""The plant behind the simulated controller: what the robot does with the commanded posture.

The controller's protocol-and-safety layer (``controller_sim``) decides what is commanded; a plant turns each
command into the measured state it reports. ``KinematicPlant`` replays the command exactly (the robot is where it
was told to be); ``robot_bridge.physics.PhysicsPlant`` is the MuJoCo twin (docs/physics.md), which can also fault:
a fall, a foot tilting or lifting, a saturated joint torque.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


@dataclass(frozen=True)
class PlantFault:
    """Why the plant cannot go on safely: ``kind`` is fall | foot_tilt | foot_lift | torque_saturation."""

    kind: str
    detail: str
    at_s: float

    @property
    def reason(self) -> str:
        return f"{self.kind}: {self.detail} (at {self.at_s:.3f} s of simulated time)"


class Plant(Protocol):
    """What a controller's plant offers; times are the plant's own (simulated) seconds."""

    def substeps(self, step_s: float) -> list[float]:
        """How a control tick of ``step_s`` plan seconds is cut into the plant's control steps."""
        ...

    def step(self, q_cmd: np.ndarray, holding: str, dt_s: float) -> PlantFault | None:
        """Command ``q_cmd`` (controller joint order) with ``holding`` for ``dt_s``; a fault when one is found."""
        ...

    def measured(self) -> np.ndarray:
        """The measured joint positions (controller joint order)."""
        ...

    def balance(self) -> dict[str, Any] | None:
        """The ``state/balance`` message body (CONTRACT 6) without ``stamp``, or None (no contact model)."""
        ...

    def on_playback(self, object_mass_kg: float | None = None) -> None:
        """A job's playback starts (the plant's fault injection, if any, hooks onto it); ``object_mass_kg`` is the
        job's planned object mass (the segments' ``object_mass_kg``; None: not told)."""
        ...


class KinematicPlant:
    """Replays the command: the measured posture is the commanded one, nothing falls."""

    def __init__(self, q0: np.ndarray):
        self._q = np.array(q0, dtype=float)

    def substeps(self, step_s: float) -> list[float]:
        return [step_s]

    def step(self, q_cmd: np.ndarray, holding: str, dt_s: float) -> PlantFault | None:
        self._q = np.array(q_cmd, dtype=float)
        return None

    def measured(self) -> np.ndarray:
        return self._q

    def balance(self) -> dict[str, Any] | None:
        return None

    def on_playback(self, object_mass_kg: float | None = None) -> None:
        return None
