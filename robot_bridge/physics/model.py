"""The robot as a MuJoCo model: the URDF with a free base on a floor, sole contacts, servos and load bodies.

Built through ``mujoco.MjSpec`` from the same URDF the gate and the planner read: fixed-joint links are kept
(``fusestatic`` off, so the sole and TCP frames stay bodies), inertia comes from the URDF alone, visuals are
dropped, a free joint is added on the root link. Only the sole boxes touch anything, and only the floor. Each
moving joint that is not a mimic joint gets a position servo (a PD law in the actuator, integrated implicitly)
limited to its effort limit; mimic joints follow their master through the equality MuJoCo makes of them. Each
hand's TCP carries a load body, massless until the twin brings an object's weight onto it.
"""

from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from ..errors import BridgeError
from .settings import SimSection, TwinSettings, sim_section

#: Sides of the robot, in the order the twin reports them.
SIDES = ("left", "right")


class TwinModelError(BridgeError, ValueError):
    """The robot cannot be built in the twin (names the file or joint)."""


@dataclass(frozen=True)
class JointServo:
    """One servo's law, for the docs and the report: tau = kp (q_cmd - q) - kd qdot (+ feed-forward)."""

    name: str
    kp: float
    kd: float
    armature: float
    effort: float
    source: str  # "spec" | "derived"


@dataclass
class TwinModel:
    """A compiled twin and the indices the simulation needs (``model`` is this twin's own copy)."""

    model: mujoco.MjModel
    joint_names: list[str]
    qpos_adr: np.ndarray  # per controller joint
    dof_adr: np.ndarray
    actuator: np.ndarray  # per controller joint
    effort: np.ndarray
    servos: list[JointServo]
    root_body: int
    sole_body: dict[str, int]
    sole_geom: dict[str, int]
    load_body: dict[str, int]
    ankle_dofs: dict[str, tuple[int, int]]  # side -> (pitch dof, roll dof) found by axis
    hip_dofs: dict[str, tuple[int, int]]
    jaw_mask: np.ndarray  # controller joints left out of tracking and torque figures (prismatic jaws)
    total_mass_kg: float


def _urdf_efforts(root: ET.Element) -> dict[str, float]:
    out = {}
    for j in root.findall("joint"):
        lim = j.find("limit")
        if lim is not None and lim.get("effort") is not None:
            out[j.get("name")] = float(lim.get("effort"))
    return out


def _with_compiler(urdf: Path) -> tuple[str, ET.Element]:
    text = urdf.read_text()
    root = ET.fromstring(text)
    for el in root.findall("mujoco"):
        root.remove(el)
    mj = ET.SubElement(root, "mujoco")
    ET.SubElement(mj, "compiler", {"fusestatic": "false", "discardvisual": "true", "inertiafromgeom": "false",
                                   "strippath": "false", "meshdir": str(urdf.parent),
                                   # massless moving links (a URDF may have them) get a negligible mass: MuJoCo needs one
                                   "boundmass": "1e-5", "boundinertia": "1e-9"})
    return ET.tostring(root, encoding="unicode"), root


def _pick(table: dict[str, float], joint: str) -> float | None:
    if joint in table:
        return float(table[joint])
    return float(table["default"]) if "default" in table else None


def _leg_dofs(model: mujoco.MjModel, sole_body: int, axis_index: int) -> tuple[int, ...]:
    """The hinge dofs on the path from the sole up, ordered nearest first, whose axis (in the sole's reference
    frame at the model's reference posture) is mostly along ``axis_index`` (1: pitch, y; 0: roll, x)."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    R_sole = data.xmat[sole_body].reshape(3, 3)
    found = []
    b = sole_body
    while b > 0:
        for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
            if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
                continue
            axis_world = data.xmat[b].reshape(3, 3) @ model.jnt_axis[j]
            local = R_sole.T @ axis_world
            if abs(local[axis_index]) > 0.9:
                found.append(int(model.jnt_dofadr[j]))
        b = int(model.body_parentid[b])
    return tuple(found)


@lru_cache(maxsize=8)
def _compiled(urdf: str, urdf_mtime: float, spec_key: str, settings_key: str,
              joints: tuple[str, ...]) -> tuple[mujoco.MjModel, tuple]:
    """Compile once per URDF, spec and settings (bounded cache); callers copy the model before changing it."""
    import json

    spec_doc = json.loads(spec_key)
    settings = TwinSettings.model_validate_json(settings_key)
    sim = sim_section(spec_doc)
    text, root = _with_compiler(Path(urdf))
    try:
        spec = mujoco.MjSpec.from_string(text)
    except Exception as exc:
        raise TwinModelError(f"MuJoCo cannot load {urdf}: {exc}") from exc
    spec.option.timestep = settings.timestep_s
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # One robot on one floor is one constraint island: discovering islands every step costs a fifth of the step and
    # changes nothing of the result.
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_ISLAND
    base = spec.worldbody.first_body()
    base.add_freejoint(name="base")
    for g in spec.geoms:
        g.contype, g.conaffinity = 0, 0
    floor = spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
    floor.contype, floor.conaffinity = 0, 1
    c = {**settings.contact.model_dump(), **sim.contact}
    for side in SIDES:
        frame = spec_doc["feet"][side]["frame"]
        body = spec.body(frame)
        boxes = [g for g in (body.geoms if body is not None else []) if g.type == mujoco.mjtGeom.mjGEOM_BOX]
        if not boxes:
            raise TwinModelError(f"{urdf}: the sole frame {frame!r} has no collision box")
        for g in boxes:
            g.name = f"sole_{side}"
            g.contype, g.conaffinity = 1, 0
            g.solref = [c["timeconst_s"], c["dampratio"]]
            g.solimp = [c["impedance"][0], c["impedance"][1], 0.001, 0.5, 2.0]
            g.friction = [c["friction"], 0.005, 0.0001]
            g.condim = 3
            # The higher priority makes the contact the sole's alone: at equal priorities MuJoCo mixes the two geoms'
            # solref and solimp and takes the larger friction, so the floor's defaults would soften the contact.
            g.priority = 1
        tcp = spec.body(spec_doc["hands"][side]["frame"])
        if tcp is None:
            raise TwinModelError(f"{urdf}: no hand frame {spec_doc['hands'][side]['frame']!r}")
        load = tcp.add_body(name=f"load_{side}")
        load.explicitinertial = True
        load.mass, load.inertia = 0.0, [0.0, 0.0, 0.0]
    for name in joints:  # gains are written into each model copy (_with_servos): they need the compiled inertia
        act = spec.add_actuator(name=f"servo_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.gaintype, act.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0], act.biasprm[1] = 1.0, -1.0
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-1.0, 1.0]
    try:
        model = spec.compile()
    except Exception as exc:
        raise TwinModelError(f"MuJoCo cannot compile {urdf}: {exc}") from exc
    for side in SIDES:
        # A load body compiles with its inertial frame on its body frame, which MuJoCo then takes as fixed and never
        # reads body_ipos again: the held object's CoM, written there at each grasp, would sit at the TCP.
        model.body_sameframe[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"load_{side}")] = \
            mujoco.mjtSameFrame.mjSAMEFRAME_NONE
    return model, (spec_doc, sim, _urdf_efforts(root))


def build_twin_model(urdf: Path, spec: dict[str, Any], joint_names: list[str], settings: TwinSettings) -> TwinModel:
    """The twin of a robot (its URDF and ``regrasp.robot/1`` spec) driving ``joint_names``, with servos."""
    import json

    model, (spec_doc, sim, efforts) = _compiled(str(urdf), urdf.stat().st_mtime, json.dumps(spec, sort_keys=True),
                                                settings.model_dump_json(), tuple(joint_names))
    model = copy.deepcopy(model)
    return _with_servos(model, spec_doc, sim, efforts, joint_names, settings)


def _with_servos(model: mujoco.MjModel, spec: dict[str, Any], sim: SimSection, urdf_efforts: dict[str, float],
                 joint_names: list[str], settings: TwinSettings) -> TwinModel:
    """Servo parameters written into this model copy: each joint's armature, its actuator's gains and range."""
    spec_efforts = {k: float(v) for k, v in (spec.get("effort_limits") or {}).items()}
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, M)
    qadr, dadr, servos = [], [], []
    for name in joint_names:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise TwinModelError(f"joint {name!r} is not a joint of the twin's model")
        qadr.append(int(model.jnt_qposadr[jid]))
        d = int(model.jnt_dofadr[jid])
        dadr.append(d)
        effort = spec_efforts.get(name, urdf_efforts.get(name))
        if effort is None or not math.isfinite(effort) or effort <= 0:
            raise TwinModelError(f"joint {name!r} has no effort limit (URDF <limit effort> or the spec's effort_limits)")
        arm = _pick(sim.armature, name)
        arm = settings.servo.armature_per_effort * effort if arm is None else arm
        kp = _pick(sim.kp, name)
        source = "spec" if kp is not None else "derived"
        kp = effort / settings.servo.stiffness_angle_rad if kp is None else kp
        kd = _pick(sim.kd, name)
        if kd is None:
            kd = 2.0 * settings.servo.damping_ratio * math.sqrt(kp * (M[d, d] + arm))
        model.dof_armature[d] = arm
        a = len(servos)
        model.actuator_gainprm[a, 0] = kp
        model.actuator_biasprm[a, :3] = [0.0, -kp, -kd]
        model.actuator_forcerange[a] = [-effort, effort]
        servos.append(JointServo(name, float(kp), float(kd), float(arm), float(effort), source))
    sole_body = {s: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, spec["feet"][s]["frame"]) for s in SIDES}
    jaw = {j for s in SIDES for j in ((spec["hands"][s].get("jaw") or {}).get("joints") or [])}
    return TwinModel(
        model=model, joint_names=list(joint_names), qpos_adr=np.array(qadr), dof_adr=np.array(dadr),
        actuator=np.arange(len(joint_names)), effort=np.array([s.effort for s in servos]), servos=servos,
        root_body=1,
        sole_body=sole_body,
        sole_geom={s: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"sole_{s}") for s in SIDES},
        load_body={s: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"load_{s}") for s in SIDES},
        ankle_dofs={s: (_leg_dofs(model, sole_body[s], 1)[0], _leg_dofs(model, sole_body[s], 0)[0]) for s in SIDES},
        hip_dofs={s: (_leg_dofs(model, sole_body[s], 1)[-1], _leg_dofs(model, sole_body[s], 0)[-1]) for s in SIDES},
        jaw_mask=np.array([n in jaw for n in joint_names]),
        total_mass_kg=float(model.body_subtreemass[1]),
    )
