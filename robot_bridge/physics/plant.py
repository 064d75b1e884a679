"""The physics twin as the simulated controller's plant (``controller-sim --plant physics``).

The controller's protocol-and-safety layer commands a posture per control step; the twin plays it for that long
(1 ms physics steps) and reports the measured joints, a ``state/balance`` body and its faults. The controller
knows no plan but what the segments carry: the planned object's mass comes with them (``object_mass_kg``), and the
object a closing hand takes on weighs that much unless the command line says otherwise (a payload mismatch test);
its CoM is taken at the holding TCP. The stabilizer's reference is the commanded posture's CoM, as for
``regrasp simulate``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..plant import PlantFault
from .model import SIDES
from .twin import Twin

if TYPE_CHECKING:
    from .settings import TwinSettings


class PhysicsPlant:
    """A :class:`~robot_bridge.plant.Plant` backed by a :class:`Twin`; ``control_dt_s`` is the control period."""

    def __init__(self, twin: Twin, control_dt_s: float = 0.005, push_n: float = 0.0, push_s: float = 0.0,
                 effort_scale: float = 1.0, object_mass_kg: float | None = None):
        """Fault injection from the first job's playback: ``push_n`` N along +x on the base for ``push_s``;
        ``effort_scale`` scales every joint's effort limit (weakened joints saturate); ``object_mass_kg``, when
        given, is the mass the hands take on whatever the plan says (else the planned object's, times the
        settings' ``mass_scale``)."""
        self.twin = twin
        self._object_mass_kg = object_mass_kg
        if object_mass_kg is not None:
            twin.object_mass_kg = float(object_mass_kg)
        twin.planned_mass_kg = None  # told by each job's segments
        self.control_dt_s = control_dt_s
        self._holding = "none"
        self._push = (float(push_n), float(push_s))
        self._push_from: float | None = None
        self._effort_scale = float(effort_scale)
        self.min_cop_margin_m = math.inf

    def settle(self, q: np.ndarray, seconds: float) -> PlantFault | None:
        """Stand still in ``q`` for ``seconds`` before any command (the twin settles on its soles)."""
        fault = None
        for _ in range(int(round(seconds / self.control_dt_s))):
            fault = self.twin.control(q, "none", self.control_dt_s)
            if fault is not None:
                break
        self.twin.extremes = type(self.twin.extremes)()
        return fault

    def on_playback(self, object_mass_kg: float | None = None) -> None:
        """A job's playback starts: the payload check expects its planned object (None: not told, no check); fault
        injection starts with the first job's: the push, the weakened joints."""
        tw = self.twin
        tw.planned_mass_kg = None if object_mass_kg is None else float(object_mass_kg)
        if self._object_mass_kg is None:
            tw.object_mass_kg = (object_mass_kg or 0.0) * tw.s.mass_scale
        if self._push_from is None:
            self._push_from = self.twin.t
            if self._effort_scale != 1.0:
                tm = self.twin.tm
                tm.effort = tm.effort * self._effort_scale
                tm.model.actuator_forcerange[: len(tm.joint_names)] *= self._effort_scale

    def substeps(self, step_s: float) -> list[float]:
        return [self.control_dt_s] * max(1, int(round(step_s / self.control_dt_s)))

    def step(self, q_cmd: np.ndarray, holding: str, dt_s: float) -> PlantFault | None:
        tw = self.twin
        if holding != self._holding:
            hands = {"none": (), "left": ("left",), "right": ("right",), "both": SIDES}
            tw.set_reference(q_cmd)
            for side in hands[holding]:
                if side not in hands[self._holding]:  # a hand that closes: the object's CoM at its TCP
                    tw.grasp(side, tw.tcp_pose(side)[0])
            self._holding = holding
        if self._push_from is not None:
            on = tw.t - self._push_from < self._push[1]
            tw.d.xfrc_applied[tw.tm.root_body, 0] = self._push[0] if on else 0.0
        fault = tw.control(q_cmd, holding, dt_s)
        if tw.last is not None and math.isfinite(tw.last.cop_margin_m):
            self.min_cop_margin_m = min(self.min_cop_margin_m, tw.last.cop_margin_m)
        return fault

    def measured(self) -> np.ndarray:
        return self.twin.d.qpos[self.twin.tm.qpos_adr].copy()

    def balance(self) -> dict[str, Any] | None:
        ms = self.twin.last
        if ms is None:
            return None
        finite = bool(np.all(np.isfinite(ms.cop)))
        return {"cop": [float(v) for v in ms.cop] if finite else None,
                "cop_margin_m": ms.cop_margin_m if math.isfinite(ms.cop_margin_m) else None,
                "foot_forces_n": {s: float(ms.foot_forces_n[s]) for s in SIDES},
                "base_tilt_rad": ms.base_tilt_rad,
                "min_cop_margin_m": self.min_cop_margin_m if math.isfinite(self.min_cop_margin_m) else None,
                "support_polygon": self.twin.polygon.vertices.tolist(),
                "sim_time_s": self.twin.t}


def physics_plant(robot: str, joint_names: list[str], q0: np.ndarray, base_pose: np.ndarray,
                  in_contact: dict[str, bool], settings: TwinSettings, *, object_mass_kg: float | None = None,
                  push_n: float = 0.0, push_s: float = 0.0, effort_scale: float = 1.0,
                  control_dt_s: float = 0.005) -> PhysicsPlant:
    """The twin of ``robot`` standing settled in ``q0`` at ``base_pose``: the controller-sim's plant.

    ``push_n``, ``push_s``, ``effort_scale``: fault injection (PhysicsPlant)."""
    from ..robot_files import robot_files
    from .model import build_twin_model

    files = robot_files(robot)
    tm = build_twin_model(files.urdf, files.spec, joint_names, settings)
    plant = PhysicsPlant(Twin(tm, base_pose, q0, in_contact, settings), control_dt_s, push_n=push_n, push_s=push_s,
                         effort_scale=effort_scale, object_mass_kg=object_mass_kg)
    fault = plant.settle(np.asarray(q0, dtype=float), settings.settle_s)
    if fault is not None:
        raise ValueError(f"the twin cannot stand in this posture: {fault.reason}")
    return plant
