"""An independent checker of plan files (docs/contract.md section 3).

It trusts none of the planner's numbers: it reloads the URDF into pinocchio,
recomputes every CoM (the paper's equation 1), margins with shapely, the ZMP, the
feet, the object's rigidity in the holding hand, and the limits. Tests call
:func:`check_plan` on every solved plan they produce.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
import yaml
from shapely.geometry import MultiPoint, Point, Polygon

G = 9.81
MARGIN_TOL = 1e-4


@dataclass
class CheckReport:
    errors: list[str] = field(default_factory=list)
    min_margin: float = np.inf

    def fail(self, msg: str) -> None:
        if len(self.errors) < 20:
            self.errors.append(msg)


def _urdf_and_spec(robot_name: str):
    """A built-in robot's URDF (its own: the built-ins need nothing derived) and its spec file (regrasp.robot/1)."""
    import robot_data

    data = robot_data.data_dir()
    spec = yaml.safe_load((data / f"{robot_name}.yaml").read_text())
    return str(data / spec["urdf"]), spec


def _mimics(urdf: str) -> dict:
    """Mimic joints from the URDF's ``<mimic>``: name -> (master, multiplier, offset)."""
    out = {}
    for j in ET.parse(urdf).getroot().iter("joint"):
        m = j.find("mimic")
        if m is not None:
            out[j.attrib["name"]] = (m.attrib["joint"], float(m.attrib.get("multiplier", 1)), float(m.attrib.get("offset", 0)))
    return out


def _box_sizes(urdf: str, links) -> dict[str, tuple[float, float]]:
    """x and y sizes of the named links' collision boxes (the soles), in the URDF's link order."""
    out = {}
    for link in ET.parse(urdf).getroot().iter("link"):
        if link.attrib["name"] in links:
            sx, sy, _ = (float(v) for v in link.find("collision/geometry/box").attrib["size"].split())
            out[link.attrib["name"]] = (sx, sy)
    return out


def _pin_q(model: pin.Model, mimics: dict, col: dict, base_pose, q) -> np.ndarray:
    """A pinocchio configuration from a base pose and a joint vector in ``col``'s order.

    Written from the URDF's own joint list, not the planner's mapping, so a mapping error there shows.
    """
    out = pin.neutral(model)
    out[:7] = base_pose
    for jid in range(2, model.njoints):
        name = model.names[jid]
        if name in mimics:
            master, k, b = mimics[name]
            out[model.idx_qs[jid]] = k * q[col[master]] + b
        else:
            out[model.idx_qs[jid]] = q[col[name]]
    return out


def _sole_hull(soles) -> Polygon:
    """Convex hull of sole boxes, given as (placement, (size x, size y)) pairs."""
    corners = []
    for placement, (sx, sy) in soles:
        for cx, cy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
            corners.append(placement.act(np.array([cx * sx / 2, cy * sy / 2, 0.0]))[:2])
    return MultiPoint(corners).convex_hull


def _signed_margin(polygon: Polygon, x: float, y: float) -> float:
    """Distance of the point (x, y) to the polygon's edge, positive inside."""
    p = Point(float(x), float(y))
    d = polygon.exterior.distance(p)
    return d if polygon.contains(p) else -d


def _acc_limits(spec: dict, names: list[str]) -> np.ndarray:
    acc = spec["acceleration_limits"]  # regrasp.robot/1: per joint, with a default
    return np.array([acc.get(n, acc.get("default")) for n in names], dtype=float)


def _se3(pose) -> pin.SE3:
    return pin.XYZQUATToSE3(np.asarray(pose, dtype=float))


def _pose_err(a: pin.SE3, b: pin.SE3) -> tuple[float, float]:
    d = a.inverse() * b
    return float(np.linalg.norm(d.translation)), float(np.linalg.norm(pin.log3(d.rotation)))


def check_plan(plan: dict, *, sample_every: int = 1, robot_spec: str | None = None) -> CheckReport:
    """``robot_spec``: the robot's spec file (regrasp.robot/1) when it is not a built-in; its derived URDF is
    the one `regrasp robot urdf FILE` names."""
    rep = CheckReport()
    assert plan["status"] == "solved", plan.get("failure")
    if robot_spec is None:
        urdf, spec = _urdf_and_spec(plan["robot"]["name"])
    else:
        from click.testing import CliRunner

        from service.cli.main import cli

        res = CliRunner().invoke(cli, ["robot", "urdf", robot_spec])
        assert res.exit_code == 0, res.output
        urdf, spec = res.output.strip(), yaml.safe_load(open(robot_spec).read())
    model = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
    data = model.createData()
    mimics = _mimics(urdf)
    names = plan["robot"]["joint_names"]
    col = {n: i for i, n in enumerate(names)}
    base = np.asarray(plan["stance"]["base_pose"], dtype=float)
    traj = plan["trajectory"]
    dt = plan["dt_s"]
    Q = np.array([p["q"] for p in traj])
    T = np.array([p["t"] for p in traj])
    holding = [p["holding"] for p in traj]
    obj = plan["object"]
    m = obj["mass_kg"]
    com_local = np.asarray(obj["com_local"])
    M = pin.computeTotalMass(model)
    thr = plan["threshold_m"]
    feet = plan["stance"]["feet"]

    # Support polygon: hull of the sole boxes in contact.
    contact = [f for f in feet if f["in_contact"]]
    sizes = _box_sizes(urdf, {f["frame"] for f in contact})
    hull = _sole_hull((_se3(f["pose"]), sizes[f["frame"]]) for f in contact)
    plan_poly = Polygon(plan["support_polygon"])
    if hull.symmetric_difference(plan_poly).area > 1e-3 * 0.3:  # ~1 mm along the outline
        rep.fail("support_polygon differs from the hull of the soles in contact")

    def pinq(q):
        return _pin_q(model, mimics, col, base, q)

    def system_com(q, hold, objpose):
        c = pin.centerOfMass(model, data, pinq(q), False).copy()
        if hold != "none":
            oc = _se3(objpose).act(com_local)
            c = (M * c + m * oc) / (M + m)
        return c

    def margin(c):
        return _signed_margin(hull, c[0], c[1])

    lower = np.array([model.lowerPositionLimit[model.idx_qs[model.getJointId(n)]] for n in names])
    upper = np.array([model.upperPositionLimit[model.idx_qs[model.getJointId(n)]] for n in names])
    vel = np.array([model.velocityLimit[model.idx_vs[model.getJointId(n)]] for n in names])
    acc = _acc_limits(spec, names)
    if np.any(Q < lower - 1e-9) or np.any(Q > upper + 1e-9):
        i, j = np.argwhere((Q < lower - 1e-9) | (Q > upper + 1e-9))[0]
        rep.fail(f"q[{i}] {names[j]}={Q[i, j]:.4f} outside [{lower[j]:.4f}, {upper[j]:.4f}]")
    if not np.allclose(T, np.arange(len(T)) * dt, atol=1e-9):
        rep.fail("t is not i * dt_s")
    V = np.diff(Q, axis=0) / dt
    if np.any(np.abs(V) > vel * (1 + 1e-6)):
        i, j = np.argwhere(np.abs(V) > vel * (1 + 1e-6))[0]
        rep.fail(f"velocity of {names[j]} at {i}: {V[i, j]:.4f} > {vel[j]:.4f}")
    A = np.diff(Q, 2, axis=0) / dt**2
    if np.any(np.abs(A) > acc * 1.05):
        i, j = np.argwhere(np.abs(A) > acc * 1.05)[0]
        rep.fail(f"acceleration of {names[j]} at {i}: {A[i, j]:.4f} > {acc[j]:.4f}")
    if np.abs(V[0]).max() > 1e-6 or np.abs(V[-1]).max() > 1e-6:
        rep.fail("the plan does not start and end at rest")

    coms = np.zeros((len(traj), 3))
    tcp_names = {s: h["frame"] for s, h in spec["hands"].items()}
    tcp_ids = {side: model.getFrameId(f) for side, f in tcp_names.items()}
    sole_ids = {f["frame"]: model.getFrameId(f["frame"]) for f in feet}
    rel: dict = {}
    obj_prev = None
    for i, p in enumerate(traj):
        q = Q[i]
        c = system_com(q, p["holding"], p["object_pose"])
        coms[i] = c
        if np.abs(c - np.asarray(p["com"])).max() > 1e-6:
            rep.fail(f"com at {i} differs from the recomputation by {np.abs(c - np.asarray(p['com'])).max():.2e} m")
        mg = margin(c)
        rep.min_margin = min(rep.min_margin, mg)
        if abs(mg - p["margin_m"]) > 1e-6:
            rep.fail(f"margin_m at {i} differs from the recomputation ({p['margin_m']:.6f} vs {mg:.6f})")
        if thr > 0 and mg < thr - MARGIN_TOL:
            rep.fail(f"margin {mg:.4f} below threshold {thr} at point {i}")
        if thr > 0 and i + 1 < len(traj) and i % sample_every == 0:
            mid = 0.5 * (Q[i] + Q[i + 1])
            for h in {p["holding"], traj[i + 1]["holding"]}:
                # object pose at the midpoint: rigid with the hand -> interpolate through the hand
                op = p["object_pose"] if h == p["holding"] else traj[i + 1]["object_pose"]
                cm = system_com(mid, h, op)
                if margin(cm) < thr - MARGIN_TOL:
                    rep.fail(f"margin {margin(cm):.4f} below threshold between points {i} and {i + 1}")
        pin.framesForwardKinematics(model, data, pinq(q))
        if i % max(sample_every, 1) == 0:
            for f in feet:
                e, _ = _pose_err(data.oMf[sole_ids[f["frame"]]], _se3(f["pose"]))
                if e > 1e-3:
                    rep.fail(f"foot {f['frame']} moved {e * 1000:.2f} mm at point {i}")
        op = _se3(p["object_pose"])
        h = p["holding"]
        if h == "none":
            if obj_prev is not None and traj[i - 1]["holding"] == "none":
                e, a = _pose_err(obj_prev, op)
                if e > 1e-6 or a > 1e-6:
                    rep.fail(f"object moved while not held at point {i}")
            rel = {}
        else:
            for side in (("left", "right") if h == "both" else (h,)):
                r = data.oMf[tcp_ids[side]].inverse() * op
                if side in rel:
                    e, a = _pose_err(rel[side], r)
                    if e > 2e-3 or a > 0.02:
                        rep.fail(f"object not rigid in the {side} hand at point {i} ({e * 1000:.2f} mm, {a:.3f} rad)")
                else:
                    rel[side] = r
            rel = {s: v for s, v in rel.items() if s in (("left", "right") if h == "both" else (h,))}
        obj_prev = op
    # ZMP: cart-table with central differences within runs of constant holding.
    accel = np.zeros((len(traj), 2))
    accel[1:-1] = (coms[2:, :2] - 2 * coms[1:-1, :2] + coms[:-2, :2]) / dt**2
    h = np.array(holding)
    change = np.flatnonzero(h[1:] != h[:-1])
    accel[change] = 0.0
    accel[np.minimum(change + 1, len(h) - 1)] = 0.0
    zmp = coms[:, :2] - coms[:, 2:3] / G * accel
    for i in range(len(traj)):
        if margin(np.array([*zmp[i], 0.0])) < 0:
            rep.fail(f"ZMP outside the support polygon at point {i}")
            break
        if np.abs(zmp[i] - np.asarray(traj[i]["zmp"])).max() > 1e-6:
            rep.fail(f"zmp at {i} differs from the recomputation")
            break
    e, a = _pose_err(_se3(traj[0]["object_pose"]), _se3(obj["start_pose"]))
    if e > 5e-3 or a > 0.05:
        rep.fail(f"object does not start at start_pose ({e * 1000:.1f} mm, {a:.3f} rad)")
    e, a = _pose_err(_se3(traj[-1]["object_pose"]), _se3(obj["goal_pose"]))
    if e > 5e-3 or a > 0.05:
        rep.fail(f"object does not end at goal_pose ({e * 1000:.1f} mm, {a:.3f} rad)")
    if traj[-1]["holding"] != "none":
        rep.fail("the object is still held at the end")
    last = -1
    for s in plan["segments"]:
        if s["first"] < last or s["last"] < s["first"]:
            rep.fail(f"segments out of order at {s}")
        last = s["last"]
    if plan["segments"] and plan["segments"][-1]["last"] != len(traj) - 1:
        rep.fail("segments do not cover the trajectory")
    if plan.get("min_margin_m") is not None and abs(plan["min_margin_m"] - rep.min_margin) > 1e-6:
        rep.fail("min_margin_m differs from the recomputed minimum")
    _check_limits(rep, plan, model, data, pinq, spec, urdf, max(sample_every, 1))
    return rep


def _effort_limits(urdf: str, spec: dict, names: list[str]) -> dict[str, float]:
    """Every non-jaw joint's effort limit: the spec's effort_limits over the URDF's <limit effort>."""
    jaws = {j for h in spec["hands"].values() if h.get("jaw") for j in h["jaw"].get("joints", [])}
    efforts = {}
    for joint in ET.parse(urdf).getroot().iter("joint"):
        lim = joint.find("limit")
        if lim is not None and "effort" in lim.attrib:
            efforts[joint.attrib["name"]] = float(lim.attrib["effort"])
    efforts.update({k: float(v) for k, v in (spec.get("effort_limits") or {}).items()})
    return {n: efforts[n] for n in names if n not in jaws}


def _check_limits(rep: CheckReport, plan: dict, model, data, pinq, spec: dict, urdf: str, every: int) -> None:
    """effort_ratio recomputed with pinocchio's RNEA and least-squares contact wrenches; the grip by hand."""
    traj = plan["trajectory"]
    names = plan["robot"]["joint_names"]
    limits = _effort_limits(urdf, spec, names)
    limited = (plan.get("stats") or {}).get("limits", True)
    obj = plan["object"]
    m, com_local = obj["mass_kg"], np.asarray(obj["com_local"])
    contact = [f["frame"] for f in plan["stance"]["feet"] if f["in_contact"]]
    tcp = {s: h["frame"] for s, h in spec["hands"].items()}
    grip = spec.get("grip")
    v0 = np.zeros(model.nv)
    for i in range(0, len(traj), every):
        p = traj[i]
        q = pinq(np.asarray(p["q"]))
        pin.framesForwardKinematics(model, data, q)
        hands = {"none": (), "left": ("left",), "right": ("right",), "both": ("left", "right")}[p["holding"]]
        fext = [pin.Force.Zero() for _ in range(model.njoints)]
        oc = _se3(p["object_pose"]).act(com_local)
        for side in hands:
            fr = model.frames[model.getFrameId(tcp[side])]
            f = pin.Force(np.array([0.0, 0.0, -G * m / len(hands)]), np.zeros(3))
            fext[fr.parentJoint] += data.oMi[fr.parentJoint].actInv(pin.SE3(np.eye(3), oc).act(f))
        # the wrench the soles must supply: the base rows of RNEA with the object's weight and no contacts
        base = pin.rnea(model, data, q, v0, v0, fext)[:6].copy()  # in the base frame, at the base origin
        wb = data.oMi[1].act(pin.Force(base[:3], base[3:]))  # world axes, about the world origin
        A = []
        for s in contact:
            pt = data.oMf[model.getFrameId(s)].translation
            X = np.zeros((6, 6))
            X[:3, :3] = np.eye(3)
            X[3:, :3] = pin.skew(pt)
            X[3:, 3:] = np.eye(3)
            A.append(X)
        w = np.linalg.lstsq(np.hstack(A), np.r_[wb.linear, wb.angular], rcond=None)[0]
        for k, s in enumerate(contact):
            fr = model.frames[model.getFrameId(s)]
            pt = data.oMf[model.getFrameId(s)].translation
            f = pin.Force(w[6 * k:6 * k + 3], w[6 * k + 3:6 * k + 6])
            fext[fr.parentJoint] += data.oMi[fr.parentJoint].actInv(pin.SE3(np.eye(3), pt).act(f))
        tau = pin.rnea(model, data, q, v0, v0, fext)
        if np.abs(tau[:6]).max() > 1e-6:
            rep.fail(f"contact wrenches at point {i} do not balance the robot")
        ratio = max(abs(tau[model.idx_vs[model.getJointId(n)]]) / lim for n, lim in limits.items())
        if "effort_ratio" not in p:
            rep.fail(f"trajectory[{i}] has no effort_ratio")
            return
        if abs(ratio - p["effort_ratio"]) > 1e-6:
            rep.fail(f"effort_ratio at {i} differs from the recomputation ({p['effort_ratio']:.6f} vs {ratio:.6f})")
        if limited and ratio > 1.0 + 1e-6:
            rep.fail(f"a joint is over its effort limit at point {i} (ratio {ratio:.3f})")
        if limited and grip and m > 0:
            for side in hands:
                share = G * m / len(hands)
                if not spec["hands"][side].get("jaw"):
                    continue  # a rigid hand has no grip check
                T = data.oMf[model.getFrameId(tcp[side])]
                moment = np.cross(oc - T.translation, [0.0, 0.0, -share])
                about = abs(float(moment @ T.rotation[:, 1]))
                cap = 2 * grip["friction"] * grip["force_n"]
                if share > cap * (1 + 1e-6) or about > cap * grip["patch_radius_m"] * (1 + 1e-6):
                    rep.fail(f"the {side} grip slips at point {i} ({share:.1f} N, {about:.2f} N*m)")
