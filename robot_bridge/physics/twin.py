"""The twin in motion: servo commands at the control period, physics at 1 ms, the stabilizer, the load, the
measurements (CoP, foot forces, tilt) and the faults (fall, foot tilt, foot lift, torque saturation).

The stabilizer is a DCM tracker of the kind humanoid controllers run under position commands: the reference CoM
is the commanded posture's (the twin's own kinematics at the stance's base pose), its ZMP the cart-table one;
the measured divergent component of motion xi = c + c'/omega is pulled back to the reference by a desired ZMP
p_d = p_ref + (1 + k/omega)(xi - xi_ref), kept inside the support polygon, and the measured CoP is brought there
by moments added to the servo set-points: an ankle (pitch and roll) and a hip share, with an integral on the CoP
error that leaks back to zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from ..plant import PlantFault
from ..support import Polygon, convex_hull
from .model import SIDES, TwinModel
from .settings import TwinSettings

G = 9.81
#: Moment arm (m) that weighs sole moments against forces in the feed-forward's load sharing: small, so the feet
#: share the weight as a flat-footed stance does (each sole's pressure centre near its middle).
FF_MOMENT_ARM_M = 0.02


@dataclass
class Measurement:
    """What the twin measured at one control instant (world frame, SI)."""

    t: float
    cop: np.ndarray  # (2,), NaN when no sole touches
    cop_margin_m: float
    foot_forces_n: dict[str, float]
    com: np.ndarray
    base_tilt_rad: float
    foot_tilt_rad: float  # the largest of the supporting soles'
    foot_slip_m: float
    torque_ratio: float
    tracking_error_rad: float
    held_load_n: float = math.nan  # what the wrists' force/torque sensors read of the held object (N); NaN: no hand holds


@dataclass
class _Extremes:
    min_cop_margin_m: float = math.inf
    min_cop_margin_at_s: float | None = None
    max_torque_ratio: float = 0.0
    max_tracking_error_rad: float = 0.0
    foot_slip_m: float = 0.0
    foot_tilt_rad: float = 0.0
    saturated_since: dict[int, float] = field(default_factory=dict)
    payload_off_since: float | None = None
    #: the held load the payload check judged, over the planned weight: (smallest, largest)
    held_load_ratio: tuple[float, float] | None = None


def _held_at(tcp: tuple[list[float], list[float]], com_in_tcp: list[float]) -> list[float]:
    """World position of a load whose CoM is ``com_in_tcp`` in a TCP frame (position, row-major rotation)."""
    pos, rot = tcp
    return [pos[k] + rot[3 * k] * com_in_tcp[0] + rot[3 * k + 1] * com_in_tcp[1] + rot[3 * k + 2] * com_in_tcp[2]
            for k in range(3)]


def _wxyz(xyzw: np.ndarray) -> np.ndarray:
    return np.array([xyzw[3], xyzw[0], xyzw[1], xyzw[2]])


class Twin:
    """One robot in one MuJoCo world; ``control(q_cmd, holding, dt)`` advances it by ``dt`` of simulated time.

    ``object_mass_kg`` is the planned object's mass: the hands take on that times ``settings.mass_scale``, and the
    controller's payload check expects the planned mass (``planned_mass_kg``; None: the controller was not told,
    no check)."""

    def __init__(self, tm: TwinModel, base_pose: np.ndarray, q0: np.ndarray, in_contact: dict[str, bool],
                 settings: TwinSettings, object_mass_kg: float = 0.0):
        self.tm, self.s = tm, settings
        m = self.m = tm.model
        self.d = mujoco.MjData(m)
        self.ref = mujoco.MjData(m)  # the commanded posture's kinematics (the stabilizer's reference)
        self.base_pose = np.asarray(base_pose, dtype=float)
        self.in_contact = {s: bool(in_contact.get(s, True)) for s in SIDES}
        self.object_mass_kg = float(object_mass_kg) * settings.mass_scale
        self.planned_mass_kg: float | None = float(object_mass_kg)
        self.holding = "none"
        self._holding_since = 0.0
        self.load_com = {s: np.zeros(3) for s in SIDES}  # the object's CoM in each TCP's frame while held
        self.load_mass = {s: 0.0 for s in SIDES}
        self.t = 0.0
        self.fault: PlantFault | None = None
        self.extremes = _Extremes()
        self._kp = m.actuator_gainprm[: len(tm.joint_names), 0].copy()
        ctrl = {int(dof): i for i, dof in enumerate(tm.dof_adr)}
        hip = settings.stabilizer.hip_share
        # per side: ((pitch, roll) controller indices, share of the moment) for the ankle and the hip
        # (and the MuJoCo joint ids whose axes turn a moment into those joints' torques)
        self._moment_joints = {s: [(ctrl[a], ctrl[b], int(m.dof_jntid[a]), int(m.dof_jntid[b]), w)
                                   for (a, b), w in ((tm.ankle_dofs[s], 1.0 - hip), (tm.hip_dofs[s], hip))
                                   if a in ctrl and b in ctrl and w > 0] for s in SIDES}
        self._u = [0.0, 0.0]  # integrated CoP correction (m)
        # (robot CoM, left TCP, right TCP) x 3, each TCP as (position, rotation row-major): what each hand holds is
        # placed in it with today's load_com, as it is weighed with today's masses
        self._ref_hist: list[tuple[list[float], tuple[list[float], list[float]], tuple[list[float], list[float]]]] = []
        self._load_body = (tm.load_body["left"], tm.load_body["right"])
        self._tcp_body = {s: int(m.body_parentid[tm.load_body[s]]) for s in SIDES}  # each hand's TCP body
        self._dt_prev = None
        self.q_cmd = np.asarray(q0, dtype=float).copy()
        self._pose(self.d, q0)
        mujoco.mj_forward(m, self.d)
        lowest = min(self._sole_bottom(s) for s in SIDES if self.in_contact[s])
        self.d.qpos[2] -= lowest  # soles in contact exactly on the floor
        self.base_pose = self.base_pose.copy()
        self.base_pose[2] = self.d.qpos[2]
        mujoco.mj_forward(m, self.d)
        self._pose(self.ref, q0)
        mujoco.mj_kinematics(m, self.ref)
        self.sole_home = {s: self.d.xpos[tm.sole_body[s]].copy() for s in SIDES}
        self.pelvis_z0 = float(self.d.xpos[tm.root_body][2])
        self.polygon = Polygon(convex_hull(np.vstack([self._sole_corners(s) for s in SIDES if self.in_contact[s]])))
        self.last: Measurement | None = None
        self._f6 = np.zeros(6)
        self._supporting = [s for s in SIDES if self.in_contact[s]]
        self._g = np.zeros(m.nv)
        self._jac = np.zeros((6 * len(self._supporting), m.nv))
        self._wrench_scale = np.tile([1.0, 1.0, 1.0, FF_MOMENT_ARM_M, FF_MOMENT_ARM_M, FF_MOMENT_ARM_M],
                                     len(self._supporting))
        self._keep = np.flatnonzero(~tm.jaw_mask)
        self._geom_side = {tm.sole_geom[s]: s for s in SIDES}
        v = self.polygon.vertices
        e = np.roll(v, -1, axis=0) - v
        n = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.linalg.norm(e, axis=1)[:, None]
        self._normals, self._offsets = n, np.einsum("ij,ij->i", n, v)

    def _margin(self, p: np.ndarray) -> float:
        """Signed distance of a point to the support polygon's boundary, inside positive."""
        d = float((self._normals @ p - self._offsets).min())
        return d if d >= 0 else float(self.polygon.margin(p[None])[0])

    # ------------------------------------------------------------------ geometry
    def _pose(self, data: mujoco.MjData, q: np.ndarray) -> None:
        data.qpos[:3] = self.base_pose[:3]
        data.qpos[3:7] = _wxyz(self.base_pose[3:])
        data.qpos[self.tm.qpos_adr] = q

    def _sole_bottom(self, side: str) -> float:
        g = self.tm.sole_geom[side]
        R = self.d.geom_xmat[g].reshape(3, 3)
        corners = self.d.geom_xpos[g] + (np.array([[sx, sy, -1] for sx in (-1, 1) for sy in (-1, 1)])
                                         * self.m.geom_size[g]) @ R.T
        return float(corners[:, 2].min())

    def _sole_corners(self, side: str) -> np.ndarray:
        g = self.tm.sole_geom[side]
        R = self.d.geom_xmat[g].reshape(3, 3)
        local = np.array([[sx, sy, -1] for sx in (-1, 1) for sy in (-1, 1)]) * self.m.geom_size[g]
        return (self.d.geom_xpos[g] + local @ R.T)[:, :2]

    def tcp_pose(self, side: str, commanded: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(position, rotation) of a hand's TCP frame in the commanded (reference) or measured posture."""
        data = self.ref if commanded else self.d
        b = self._tcp_body[side]
        return data.xpos[b].copy(), data.xmat[b].reshape(3, 3).copy()

    def set_reference(self, q_cmd: np.ndarray) -> None:
        self._pose(self.ref, q_cmd)
        self.ref.qvel[:] = 0.0
        mujoco.mj_kinematics(self.m, self.ref)
        mujoco.mj_comPos(self.m, self.ref)

    # ------------------------------------------------------------------ load
    def grasp(self, side: str, com_world: np.ndarray) -> None:
        """The object's CoM in the world when ``side`` closes on it (commanded posture): kept in its TCP frame."""
        p, R = self.tcp_pose(side)
        self.load_com[side] = R.T @ (np.asarray(com_world, dtype=float) - p)

    def _update_load(self, holding: str, dt: float) -> None:
        share = {"none": (0.0, 0.0), "left": (1.0, 0.0), "right": (0.0, 1.0), "both": (0.5, 0.5)}[holding]
        rate = self.object_mass_kg / self.s.load_ramp_s if self.s.load_ramp_s > 0 else math.inf
        for side, w in zip(SIDES, share):
            target = w * self.object_mass_kg
            cur = self.load_mass[side]
            new = target if abs(target - cur) <= rate * dt else cur + math.copysign(rate * dt, target - cur)
            if new != cur:
                self._set_mass(side, new)

    def _set_mass(self, side: str, mass: float) -> None:
        m, b = self.m, self.tm.load_body[side]
        delta = mass - self.load_mass[side]
        self.load_mass[side] = mass
        m.body_mass[b] = mass
        m.body_ipos[b] = self.load_com[side]
        m.body_inertia[b] = np.full(3, 0.4 * mass * 0.05 ** 2)  # a 5 cm solid sphere's: the object's own inertia
        while b > 0:  # MuJoCo divides by the compiled subtree masses: keep them true
            m.body_subtreemass[b] += delta
            b = int(m.body_parentid[b])

    # ------------------------------------------------------------------ control
    def control(self, q_cmd: np.ndarray, holding: str, dt: float) -> PlantFault | None:
        """Command ``q_cmd`` with ``holding`` for ``dt`` s (whole physics steps); the first fault, once found."""
        if self.fault is not None and self.fault.kind == "fall":
            self.t += dt  # a fallen robot lies still: nothing more is simulated
            return self.fault
        self.q_cmd = np.asarray(q_cmd, dtype=float)
        if holding != self.holding:
            self.holding, self._holding_since = holding, self.t
        self._update_load(holding, dt)
        self.set_reference(self.q_cmd)
        tau = self._feedforward() + self._stabilizer(dt)
        self.d.ctrl[:] = self.q_cmd + tau / self._kp
        n = max(1, int(round(dt / self.m.opt.timestep)))
        mujoco.mj_step(self.m, self.d, nstep=n)
        self.t += n * self.m.opt.timestep
        self.last = self.measure()
        fault = self._check(self.last, n * self.m.opt.timestep)
        if fault is not None and self.fault is None:
            self.fault = fault
        return self.fault

    def _feedforward(self) -> np.ndarray:
        """Static torques of the commanded posture (robot and load under gravity), balanced by the supporting soles'
        wrenches of least 2-norm: the model-based gravity feed-forward a stiff position servo runs."""
        n = len(self.tm.joint_names)
        if not self.s.servo.gravity_feedforward:
            return np.zeros(n)
        m, r = self.m, self.ref
        g = self._g
        mujoco.mj_rne(m, r, 0, g)  # qvel = 0 in the reference: gravity only
        J = self._jac
        for k, side in enumerate(self._supporting):
            mujoco.mj_jacBody(m, r, J[6 * k:6 * k + 3], J[6 * k + 3:6 * k + 6], self.tm.sole_body[side])
        # Base rows: the soles' wrenches carry the whole weight. Least norm with the moments weighed 1/L: the soles
        # share the load by their forces (the lever rule) and apply moments only where forces cannot balance.
        scale = self._wrench_scale
        A = J[:, :6].T * scale
        wrench = scale * (A.T @ np.linalg.solve(A @ A.T, g[:6]))
        return g[self.tm.dof_adr] - J[:, self.tm.dof_adr].T @ wrench

    def _stabilizer(self, dt: float) -> np.ndarray:
        tau = np.zeros(len(self.tm.joint_names))
        # The reference CoM's motion by finite differences of the posture alone: the robot's CoM and each hand's TCP
        # are kept, and recombined with today's masses and today's load CoMs in the hands (a load's mass changing, or
        # a grasp placing it, is no CoM acceleration).
        # Plain floats, component by component: a handful of 3-vectors, where numpy's per-call cost dominates.
        r, root = self.ref, self.tm.root_body
        ml, mr = self.load_mass["left"], self.load_mass["right"]
        total = float(self.m.body_subtreemass[root])
        robot = total - (ml + mr)
        sc = r.subtree_com[root].tolist()
        xl, xr = r.xipos[self._load_body[0]].tolist(), r.xipos[self._load_body[1]].tolist()
        hist = self._ref_hist
        tcp = {s: (r.xpos[b].tolist(), r.xmat[b].tolist()) for s, b in self._tcp_body.items()}
        body = [(total * sc[k] - (ml * xl[k] + mr * xr[k])) / robot for k in range(3)]
        hist.append((body, tcp["left"], tcp["right"]))
        if len(hist) > 3:
            del hist[0]
        st = self.s.stabilizer
        last = self.last
        if not st.enabled or len(hist) < 3 or last is None or not math.isfinite(last.cop[0]):
            return tau
        in_left, in_right = self.load_com["left"].tolist(), self.load_com["right"].tolist()
        refs = []
        for body, tcp_left, tcp_right in hist:
            a, b = _held_at(tcp_left, in_left), _held_at(tcp_right, in_right)
            refs.append([(robot * body[k] + (ml * a[k] + mr * b[k])) / total for k in range(3)])
        c0, c1, c2 = refs
        dt2 = dt ** 2
        height = max(c2[2], 0.1)  # the floor is z = 0
        omega = math.sqrt(G / height)
        h_g = height / G
        gain = 1.0 + st.dcm_gain / omega
        mujoco.mj_subtreeVel(self.m, self.d)
        c = self.d.subtree_com[root].tolist()
        v = self.d.subtree_linvel[root].tolist()
        p_ref, p = [0.0, 0.0], [0.0, 0.0]
        for k in (0, 1):
            v_ref = (c2[k] - c1[k]) / dt
            a_ref = (c2[k] - 2 * c1[k] + c0[k]) / dt2
            p_ref[k] = c2[k] - h_g * a_ref
            xi_err = (c[k] - c2[k]) + (v[k] - v_ref) / omega
            p[k] = p_ref[k] + gain * xi_err
        p_d = self._inside(np.array(p)).tolist()
        cop = last.cop.tolist()
        u = self._u
        shift = [0.0, 0.0]
        for k in (0, 1):
            u[k] = u[k] + dt * (st.cop_gain * (p_d[k] - cop[k]) - u[k] / st.cop_leak_s)
            shift[k] = (p_d[k] - p_ref[k]) + u[k]
        forces = self.last.foot_forces_n
        total = forces["left"] + forces["right"]
        if total <= 0:
            return tau
        # Ground moment change that moves the CoP by `shift`: dM = F (dy, -dx); the joints supply -dM.
        moment_x, moment_y = -total * shift[1], -total * -shift[0]
        xaxis = self.d.xaxis
        for side in SIDES:
            share = forces[side] / total
            if share <= 0:
                continue
            for jp, jr, jnt_p, jnt_r, w in self._moment_joints[side]:
                ap0, ap1 = xaxis[jnt_p, :2].tolist()
                ar0, ar1 = xaxis[jnt_r, :2].tolist()
                mx, my = share * w * moment_x, share * w * moment_y
                det = ap0 * ar1 - ar0 * ap1  # [ap ar] (xy) t = moment, by Cramer's rule
                if abs(det) < 1e-9:
                    continue
                tau[jp] += (mx * ar1 - ar0 * my) / det
                tau[jr] += (ap0 * my - mx * ap1) / det
        return tau

    def _inside(self, p: np.ndarray) -> np.ndarray:
        inset = self.s.stabilizer.polygon_inset_m
        if self._margin(p) >= inset:
            return p
        centre = self.polygon.vertices.mean(axis=0)
        lo, hi = 0.0, 1.0
        for _ in range(20):
            mid = 0.5 * (lo + hi)
            if self.polygon.margin((centre + mid * (p - centre))[None])[0] >= inset:
                lo = mid
            else:
                hi = mid
        return centre + lo * (p - centre)

    # ------------------------------------------------------------------ measurement
    def measure(self) -> Measurement:
        m, d, tm = self.m, self.d, self.tm
        left = right = mx = my = 0.0
        f6 = self._f6
        ncon = d.ncon
        if ncon:
            con = d.contact
            geom_side = self._geom_side
            g1, g2 = con.geom1.tolist(), con.geom2.tolist()
            frames, pos = con.frame.tolist(), con.pos.tolist()
            for i in range(ncon):
                side = geom_side.get(g1[i]) or geom_side.get(g2[i])
                if side is None:
                    continue
                mujoco.mj_contactForce(m, d, i, f6)
                fr = frames[i]
                f0, f1, f2 = f6[:3].tolist()
                fz = abs(f0 * fr[2] + f1 * fr[5] + f2 * fr[8])  # world z of the contact force
                if side == "left":
                    left += fz
                else:
                    right += fz
                mx += fz * pos[i][0]
                my += fz * pos[i][1]
        forces = {"left": left, "right": right}
        total = left + right
        cop = np.array([mx / total, my / total]) if total > 1e-6 else np.full(2, np.nan)
        margin = self._margin(cop) if total > 1e-6 else -math.inf
        tilt = math.acos(max(-1.0, min(1.0, float(d.xmat[tm.root_body][8]))))
        foot_tilt = slip = 0.0
        for s in self._supporting:
            b = tm.sole_body[s]
            foot_tilt = max(foot_tilt, math.acos(max(-1.0, min(1.0, float(d.xmat[b][8])))))
            slip = max(slip, math.hypot(d.xpos[b][0] - self.sole_home[s][0], d.xpos[b][1] - self.sole_home[s][1]))
        keep = self._keep
        ratio = np.abs(d.actuator_force[keep]) / tm.effort[keep]
        err = np.abs(d.qpos[tm.qpos_adr[keep]] - self.q_cmd[keep])
        return Measurement(t=self.t, cop=cop, cop_margin_m=margin, foot_forces_n=forces,
                           com=d.subtree_com[tm.root_body].copy(), base_tilt_rad=tilt, foot_tilt_rad=foot_tilt,
                           foot_slip_m=slip, torque_ratio=float(ratio.max()), tracking_error_rad=float(err.max()),
                           held_load_n=self.held_load_n() if self.holding != "none" else math.nan)

    def held_load_n(self) -> float:
        """The held object's load as the wrists' force/torque sensors read it (N): the magnitude of the sum of the
        forces the hands exert on the object (each load body's interaction force with its TCP, from the last step's
        constraint solution), so a two-handed grip's squeeze cancels. Standing still it is the object's weight;
        the motion's accelerations add to it, as they do on a real sensor."""
        mujoco.mj_rnePostConstraint(self.m, self.d)
        f = sum(self.d.cfrc_int[self.tm.load_body[s], 3:] for s in SIDES)
        return float(np.linalg.norm(f))

    def _check(self, ms: Measurement, dt: float) -> PlantFault | None:
        lim, tm, d = self.s.faults, self.tm, self.d
        ex = self.extremes
        if ms.cop_margin_m < ex.min_cop_margin_m:
            ex.min_cop_margin_m, ex.min_cop_margin_at_s = ms.cop_margin_m, ms.t
        ex.max_torque_ratio = max(ex.max_torque_ratio, ms.torque_ratio)
        ex.max_tracking_error_rad = max(ex.max_tracking_error_rad, ms.tracking_error_rad)
        ex.foot_slip_m = max(ex.foot_slip_m, ms.foot_slip_m)
        ex.foot_tilt_rad = max(ex.foot_tilt_rad, ms.foot_tilt_rad)
        drop = self.pelvis_z0 - float(d.xpos[tm.root_body][2])
        if ms.base_tilt_rad > lim.fall_tilt_rad or drop > lim.fall_drop_m:
            return PlantFault("fall", f"base tilted {ms.base_tilt_rad:.3f} rad, pelvis {drop * 1000:.0f} mm lower "
                                      f"(limits {lim.fall_tilt_rad} rad, {lim.fall_drop_m * 1000:.0f} mm)", ms.t)
        for s in SIDES:
            if not self.in_contact[s]:
                continue
            lift = float(d.xpos[tm.sole_body[s]][2] - self.sole_home[s][2])
            if lift > lim.foot_lift_m:
                return PlantFault("foot_lift", f"{s} sole lifted {lift * 1000:.1f} mm (limit "
                                               f"{lim.foot_lift_m * 1000:.0f} mm)", ms.t)
        if ms.foot_tilt_rad > lim.foot_tilt_rad:
            return PlantFault("foot_tilt", f"a supporting sole tilted {ms.foot_tilt_rad:.3f} rad (limit "
                                           f"{lim.foot_tilt_rad} rad)", ms.t)
        payload = self._payload(ms, dt)
        if payload is not None:
            return payload
        sat = np.flatnonzero((np.abs(d.actuator_force[: len(tm.joint_names)]) >= tm.effort * (1 - 1e-6)) & ~tm.jaw_mask)
        for j in list(ex.saturated_since):
            if j not in sat:
                del ex.saturated_since[j]
        for j in sat:
            since = ex.saturated_since.setdefault(int(j), ms.t - dt)
            if ms.t - since >= lim.saturation_s - 1e-9:
                return PlantFault("torque_saturation", f"{tm.joint_names[j]} at its effort limit "
                                                       f"{tm.effort[j]:.0f} N*m for {lim.saturation_s * 1000:.0f} ms",
                                  ms.t)
        return None

    def _payload(self, ms: Measurement, dt: float) -> PlantFault | None:
        """The controller's payload check: while the plan has a hand holding the object (after the load ramp and
        ``payload_settle_s``), the wrists' measured held load must be the planned object's weight within
        ``payload_tolerance`` of it plus ``payload_floor_n``, or for ``payload_debounce_s`` it is a fault. The
        contract's fault kinds are closed: it is reported as ``torque_saturation`` (the arms carry torques the plan
        did not size them for), its detail saying ``payload_mismatch``."""
        lim, ex = self.s.faults, self.extremes
        if (self.planned_mass_kg is None or self.holding == "none" or not math.isfinite(ms.held_load_n)
                or self.t - self._holding_since < self.s.load_ramp_s + lim.payload_settle_s - 1e-9):
            ex.payload_off_since = None
            return None
        planned = self.planned_mass_kg * G
        if planned > 0:
            ratio = ms.held_load_n / planned
            lo, hi = ex.held_load_ratio or (ratio, ratio)
            ex.held_load_ratio = (min(lo, ratio), max(hi, ratio))
        tolerance = lim.payload_tolerance * planned + lim.payload_floor_n
        if abs(ms.held_load_n - planned) <= tolerance:
            ex.payload_off_since = None
            return None
        if ex.payload_off_since is None:
            ex.payload_off_since = ms.t - dt
        if ms.t - ex.payload_off_since < lim.payload_debounce_s - 1e-9:
            return None
        return PlantFault("torque_saturation", f"payload_mismatch: the wrists' force/torque sensors read "
                                               f"{ms.held_load_n:.1f} N of held load, the planned "
                                               f"{self.planned_mass_kg:.2f} kg object weighs {planned:.1f} N (tolerance "
                                               f"{tolerance:.1f} N) for {lim.payload_debounce_s * 1000:.0f} ms", ms.t)
