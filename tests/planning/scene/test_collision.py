"""Collision world: known free/colliding states, held object, hands, batch = singles, SAT = fcl."""

from __future__ import annotations

from collections import Counter

import fcl
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.compiled.box_kernels import obb_penetration
from planner.scene.bodies import EnvBox
from planner.scene import collision as collision_module
from planner.scene.collision import CollisionWorld
from planner.transforms import axis_angle_to_matrix, make_transform


def _q(robot, base_q, **joints):
    q = base_q.copy()
    for name, value in joints.items():
        q[robot.joint_index(name)] = value
    return q


def test_stance_postures_are_free(hrp5p, stances, table_box):
    for name, st in stances.items():
        world = CollisionWorld(hrp5p, [table_box], reference_postures=[(st.base_pose, st.q)])
        assert world.check(st.base_pose, st.q) is None, name


def test_disabled_pairs_are_neighbours_only(upright_world):
    d = upright_world.disabled
    assert ("R_HAND_LINK", "R_WRIST_Y_LINK") in d  # geometric neighbours
    assert ("L_HAND_LINK", "R_HAND_LINK") not in d  # the hands are checked against each other
    assert ("CHEST_LINK", "R_UPPER_ARM_LINK") not in d


def test_arm_into_torso_collides(hrp5p, stances, upright_world):
    st = stances["upright"]
    # shoulder roll swings the right arm across the chest
    hit = upright_world.check(st.base_pose, _q(hrp5p, st.q, RSR=0.4))
    assert hit is not None and hit.kind == "self"
    assert {"CHEST_LINK", "R_UPPER_ARM_LINK"} & {hit.body_a, hit.body_b}


def test_hand_into_table_collides(hrp5p, stances, table_box):
    st = stances["upright"]
    world = CollisionWorld(hrp5p, [table_box], reference_postures=[(st.base_pose, st.q)])
    q = _q(hrp5p, st.q, RSP=-0.6, REP=-0.3)  # right arm raised forward, TCP at table height
    hit = world.check(st.base_pose, q)
    assert hit is not None and hit.kind == "env" and hit.body_b == "env:table"


def test_held_object_vs_table_and_resting_contact(hrp5p, stances, upright_world, drill_grasps):
    """A held object pushed into the table collides; resting on it (within tolerance) does not."""
    st = stances["upright"]
    kin = upright_world.kin
    g = drill_grasps["right"].grasps[0]
    Rs, ps = kin.forward(st.base_pose, st.q[None])
    T_obj = upright_world.object_pose_held(Rs, ps, "right", g.T_obj_tcp)[0]
    # move a copy of the table so that the held object rests on it, then sinks 1 cm into it
    low = (upright_world.obj.mesh.vertices @ T_obj[:3, :3].T + T_obj[:3, 3])[:, 2].min()
    com_xy = (T_obj[:3, :3] @ upright_world.obj.com_local + T_obj[:3, 3])[:2]
    for depth, expect in ((0.0, None), (0.01, "object-env")):
        table = EnvBox("shelf", make_transform(p=[com_xy[0], com_xy[1], low - 0.01 + depth]), (0.12, 0.12, 0.02))
        world = CollisionWorld(hrp5p, [table], upright_world.obj, reference_postures=[(st.base_pose, st.q)])
        res = world.check_forward(Rs, ps, held=[("right", g.T_obj_tcp)])
        kinds = None if res.first[0] is None else res.first[0].kind
        assert kinds == expect


def test_grasping_fingers_do_not_count(hrp5p, stances, upright_world, drill_grasps):
    """Fingers at the resting object (grasp key pose) are skipped; the palm is not."""
    st = stances["upright"]
    g = drill_grasps["right"].grasps[0]
    Rs, ps = upright_world.kin.forward(st.base_pose, _q(hrp5p, st.q, RJAW=g.jaw_value * 0.5)[None])
    T_obj = upright_world.object_pose_held(Rs, ps, "right", g.T_obj_tcp)[0]
    # the fingers closed to half the width penetrate the object
    hit = upright_world.check_forward(Rs, ps, free_object_pose=T_obj).first[0]
    assert hit is not None and hit.kind == "object" and "FINGER" in hit.body_a
    assert upright_world.check_forward(Rs, ps, free_object_pose=T_obj, grasping="right").first[0] is None


def test_hand_vs_hand(hrp5p, stances, upright_world):
    """Both wrists brought to the midline in front of the chest: the hands collide."""
    st = stances["upright"]
    q = _q(hrp5p, st.q, RSP=-0.9, LSP=-0.9, RSY=0.9, LSY=-0.9, REP=-1.6, LEP=-1.6)
    hit = upright_world.check(st.base_pose, q)
    assert hit is not None and hit.kind == "self"
    assert {hit.body_a[:2], hit.body_b[:2]} == {"L_", "R_"}  # one body of each arm


def test_batch_equals_single_and_moving_subset(hrp5p, stances, table_box):
    st = stances["upright"]
    rng = np.random.default_rng(4)
    idx = np.concatenate([hrp5p.arm_indices("left"), hrp5p.arm_indices("right"), hrp5p.waist_indices()])
    Q = np.repeat(st.q[None], 60, axis=0)
    Q[:, idx] = rng.uniform(hrp5p.lower[idx], hrp5p.upper[idx], (60, idx.size)) * 0.6 + st.q[idx] * 0.4
    full = CollisionWorld(hrp5p, [table_box], reference_postures=[(st.base_pose, st.q)])
    moving = [hrp5p.joint_names[i] for i in idx]
    sub = CollisionWorld(hrp5p, [table_box], reference_postures=[(st.base_pose, st.q)], moving_joints=moving)
    assert sub.self_pair_count() < full.self_pair_count()
    batch = full.check_batch(st.base_pose, Q)
    assert 0 < batch.collides.sum() < len(Q)
    singles = np.array([full.check(st.base_pose, q) is not None for q in Q])
    assert np.array_equal(batch.collides, singles)
    assert np.array_equal(sub.check_batch(st.base_pose, Q).collides, batch.collides)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), parked_in_table=st.booleans())
def test_a_pair_still_over_a_batch_is_asked_once_and_answers_as_each_state_alone(hrp5p, stances, table_box, seed,
                                                                                   parked_in_table):
    """The right arm parked (in the table, or clear of it) while the left arm moves: the batch's hits, every pair
    of every state, are those of each state checked alone; a pair of two bodies that keep their pose over the batch
    goes to fcl once, a pair with a moving body once per state it is screened in."""
    st_ = stances["upright"]
    parked = _q(hrp5p, st_.q, RSP=-0.6, REP=-0.3)
    table = table_box
    if parked_in_table:  # a table whose top is 10 mm above the centre of the parked right wrist's sphere
        probe = CollisionWorld(hrp5p, [], reference_postures=[(st_.base_pose, st_.q)])
        Rs, ps = probe.kin.forward(st_.base_pose, parked[None])
        wrist = next(k for k, b in enumerate(probe.bodies) if b.name == "R_WRIST_Y_LINK")
        assert probe.bodies[wrist].kind != "box"  # so that its pair with the table goes to fcl
        centre = probe._all_world(Rs, ps, None, 1)[1][wrist, 0]
        table = EnvBox("table", make_transform(p=[centre[0] + 0.2, centre[1], centre[2] - 0.01]), (0.50, 1.40, 0.04))
    world = CollisionWorld(hrp5p, [table], reference_postures=[(st_.base_pose, st_.q)])
    left = hrp5p.arm_indices("left")
    rng = np.random.default_rng(seed)
    Q = np.repeat(parked[None], 10, axis=0)
    Q[:, left] = rng.uniform(hrp5p.lower[left], hrp5p.upper[left], (len(Q), left.size)) * 0.5 + st_.q[left] * 0.5
    Rs, ps = world.kin.forward(st_.base_pose, Q)
    Rw, pw = world._all_world(Rs, ps, None, len(Q))
    ia, ib, *_ = world._pairs_for((), None, False, False)
    tol = np.zeros(ia.size)
    asked: list[tuple[int, int]] = []
    real = collision_module.fcl_collide
    ids = {id(o): k for k, o in enumerate(world._fcl)}

    def counting(oa, ob, tolerance):
        asked.append((ids[id(oa)], ids[id(ob)]))
        return real(oa, ob, tolerance)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(collision_module, "fcl_collide", counting)
        together = world._pair_hits(Rw, pw, ia, ib, tol)
        in_batch = Counter(asked)
        alone = np.concatenate([world._pair_hits(Rw[:, i:i + 1], pw[:, i:i + 1], ia, ib, tol)
                                for i in range(len(Q))], axis=1)
    assert np.array_equal(together, alone)
    moves = ~np.all(np.isclose(Rw, Rw[:, :1]), axis=(1, 2, 3)) | ~np.all(np.isclose(pw, pw[:, :1]), axis=(1, 2))
    still_pairs = [(a, b) for (a, b) in in_batch if not moves[a] and not moves[b]]
    assert all(in_batch[p] == 1 for p in still_pairs)
    alone_counts = Counter(asked[sum(in_batch.values()):])
    for p, n in in_batch.items():
        if moves[p[0]] or moves[p[1]]:
            assert n == alone_counts[p]  # a moving pair: once per state, as alone
        else:
            assert alone_counts[p] >= n  # alone, each state asks it again
    if parked_in_table:  # the parked hand is in the table in every state, from one question
        table = next(k for k, b in enumerate(world.bodies) if b.name == "env:table")
        rows = [r for r in range(ia.size) if table in (ia[r], ib[r]) and together[r].all()
                and not (world._is_box[ia[r]] and world._is_box[ib[r]])]
        assert rows, "the parked hand should reach fcl against the table"
        assert any(alone_counts[(int(ia[r]), int(ib[r]))] == len(Q) and in_batch[(int(ia[r]), int(ib[r]))] == 1
                   for r in rows)


def test_object_pose_clear(hrp5p, upright_world):
    on_table = make_transform(p=[0.5, -0.2, 0.75])
    assert upright_world.object_pose_clear(on_table) is None
    sunk = make_transform(p=[0.5, -0.2, 0.70])
    assert upright_world.object_pose_clear(sunk).body_b == "env:table"


rot = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(0, 3.1)).filter(
    lambda t: np.linalg.norm(t[:3]) > 0.1
)
vec = st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.1, 0.1))
ext = st.tuples(st.floats(0.005, 0.08), st.floats(0.005, 0.08), st.floats(0.005, 0.08))


@settings(max_examples=200, deadline=None)
@given(rot, vec, ext, rot, vec, ext)
def test_sat_agrees_with_fcl(ra, ca, ea, rb, cb, eb):
    Ra, Rb = axis_angle_to_matrix(np.array(ra[:3]), ra[3]), axis_angle_to_matrix(np.array(rb[:3]), rb[3])
    d = obb_penetration(Ra[None], np.array([ca]), np.array([ea]), Rb[None], np.array([cb]), np.array([eb]))[0]
    if abs(d) < 1e-6:
        return  # touching within round-off: either answer is right
    oa = fcl.CollisionObject(fcl.Box(*(2 * np.array(ea))), fcl.Transform(Ra, np.array(ca)))
    ob = fcl.CollisionObject(fcl.Box(*(2 * np.array(eb))), fcl.Transform(Rb, np.array(cb)))
    assert (fcl.collide(oa, ob, fcl.CollisionRequest(), fcl.CollisionResult()) > 0) == (d > 0)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 9))
def test_compiled_screen_finds_exactly_the_boxes_the_sat_finds(seed, n_states):
    """The compiled screen (batch boxes, state boxes, then the SAT) keeps exactly the (pair, state)s
    whose oriented boxes penetrate deeper than their tolerance by the vectorised SAT: the screens
    drop nothing the SAT would keep."""
    from planner.compiled.box_kernels import screen_pairs

    rng = np.random.default_rng(seed)
    B = 6
    axes = rng.normal(size=(B, n_states, 3))
    angles = rng.uniform(0, np.pi, (B, n_states))
    Rw = np.array([[axis_angle_to_matrix(axes[b, s], angles[b, s]) for s in range(n_states)] for b in range(B)])
    pw = rng.uniform(-0.12, 0.12, (B, n_states, 3))
    half = rng.uniform(0.005, 0.08, (B, 3))
    ia, ib = np.triu_indices(B, 1)
    tol = rng.choice([0.0, 0.005], ia.size)
    kp, ks = screen_pairs(Rw, pw, half, ia, ib, 1e-6 - tol, tol, 1e-9)
    got = set(zip(kp.tolist(), ks.tolist()))
    assert len(got) == kp.size  # no (pair, state) twice
    for k in range(ia.size):
        a, b = ia[k], ib[k]
        d = obb_penetration(Rw[a], pw[a], np.repeat(half[a][None], n_states, 0), Rw[b], pw[b], np.repeat(half[b][None], n_states, 0))
        for s in range(n_states):
            if abs(d[s] - tol[k]) < 1e-9:
                continue  # on the tolerance within round-off: either answer is right
            assert ((k, s) in got) == (d[s] > tol[k]), (k, s, d[s], tol[k])


def test_handover_needs_both_holders(hrp5p, stances, drill_obj, drill_grasps):
    """At a handover both hands close on the object: list both holders, or the second hand's
    fingers count as colliding with the object."""
    from planner.grasping.handover import handover_poses
    from planner.motion.ik import IkSolver
    from planner.scene.hand import hand_geometry

    st = stances["upright"]
    right, left = drill_grasps["right"], drill_grasps["left"]
    world = CollisionWorld(hrp5p, [], drill_obj, reference_postures=[(st.base_pose, st.q)])
    poses = handover_poses(drill_obj, right, left, hand_geometry(hrp5p, "right"), hand_geometry(hrp5p, "left"), st.base_pose[:3])
    ik = IkSolver(hrp5p, st)
    rng = np.random.default_rng(0)
    for i, j in poses[0].pairs[::97][:10]:
        T = poses[0].T_world_obj
        res = ik.solve_both(T @ left[j].T_obj_tcp, T @ right[i].T_obj_tcp, st.q, rng)
        if res.q is None:
            continue
        q = res.q.copy()
        q[hrp5p.joint_index("RJAW")] = 0.9 * right[i].jaw_value  # squeezing
        q[hrp5p.joint_index("LJAW")] = 0.9 * left[j].jaw_value
        both = world.check(st.base_pose, q, held=[("right", right[i].T_obj_tcp), ("left", left[j].T_obj_tcp)])
        if both is not None:
            continue  # this pair's arms collide elsewhere; try another
        one = world.check(st.base_pose, q, held=[("right", right[i].T_obj_tcp)])
        assert one is not None and one.kind == "object" and one.body_a.startswith("L_FINGER")
        return
    pytest.skip("no IK solution among the sampled handover pairs")


def test_mesh_object_collides_through_its_triangles(hrp5p, stances, tmp_path):
    """A non-box mesh object (an off-centre sphere, so the OBB offset matters) collides exactly."""
    import trimesh

    from planner.scene.objects import build_object
    from schemas.scenario import ObjectDef

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    sphere.apply_translation([0.10, 0.0, 0.0])  # the mesh frame is 10 cm from the sphere centre
    sphere.export(tmp_path / "ball.stl")
    obj = build_object(ObjectDef(shape="mesh", mesh={"path": str(tmp_path / "ball.stl")}, mass_kg=0.3))
    assert not obj.primitives  # not rectilinear: a BVH in fcl
    st = stances["upright"]
    world = CollisionWorld(hrp5p, [], obj, reference_postures=[(st.base_pose, st.q)])
    Rs, ps = world.kin.forward(st.base_pose, st.q[None])
    R, p = world.kin.frame(Rs, ps, "R_HAND_LINK")
    hand = p[0]
    for offset, expect in ((0.0, True), (0.13, False)):
        T = make_transform(p=hand + np.array([-0.10, -offset, 0.0]))  # sphere centre at the hand (+ offset)
        hit = world.check_forward(Rs, ps, free_object_pose=T).first[0]
        assert (hit is not None and hit.kind == "object") == expect
