"""Assembly of a solved path into timed motion pieces in execution order.

A path of the regrasp graph alternates key poses and hops. Assembly lays out, node by node, the
pick (approach, close the jaw, lift), the hop's planned motion, and the place (lower, open the
jaw, retreat), each short straight move timed like the planned ones; a handover node adds its
exchange. :mod:`planner.regrasp.plan_assembly` then turns the pieces into the plan's trajectory.
"""

from __future__ import annotations

from planner.motion.timing import time_parameterize
from planner.regrasp.graph import HandoverNode, SearchResult
from planner.regrasp.motions import MotionValidator
from planner.regrasp.plan_assembly import MotionPiece
from planner.stability.evaluator import HoldSpec


def assemble_pieces(res: SearchResult, motions: MotionValidator) -> list[MotionPiece]:
    """Key-pose moves and planned motions in execution order (the builder tracks the object)."""
    t = motions.task
    out: list[MotionPiece] = []
    path = res.path
    edges = iter([e.payload for e in res.edges])  # timed pieces, one list per hop, in order
    out.extend(next(edges))  # home -> first pre-grasp
    for i, node in enumerate(path):
        if isinstance(node, HandoverNode):
            out.extend(_timed_copy(p, motions) for p in motions.handovers[node].pieces)
            out.extend(next(edges))  # handover -> taker's lift pose
            continue
        kp = motions.keyposes[node]
        side = node.hand
        prev = path[i - 1] if i > 0 else None
        nxt = path[i + 1] if i + 1 < len(path) else None
        if not carried(prev, node):
            # Pick: approach, close the jaw, lift.
            out.append(_timed_copy(MotionPiece("approach", side, t.line(kp.q_pre, kp.q_grasp_open, 2), "none", None), motions))
            out.append(_timed_copy(MotionPiece("approach", side, t.line(kp.q_grasp_open, kp.q_grasp, 2), "none", None), motions))
            out.append(_timed_copy(MotionPiece("transfer", side, t.line(kp.q_grasp, kp.q_lift, 2), side,
                                                    HoldSpec(side, kp.T_obj_tcp)), motions))
        if nxt is not None and carried(node, nxt):
            out.extend(next(edges))  # carry to the next placement or to the handover pose
            continue
        # Place: lower, open the jaw, retreat; then the regrasp transit or the way home.
        here = out[-1].waypoints[-1]
        down = motions.with_arm_of(kp.q_grasp, here, side)
        opened = down.copy()
        opened[t.jaw[side]] = t.robot.upper[t.jaw[side]]
        out.append(_timed_copy(MotionPiece("transfer", side, t.line(here, down, 2), side, HoldSpec(side, kp.T_obj_tcp)), motions))
        out.append(_timed_copy(MotionPiece("retreat", side, t.line(down, opened, 2), "none", None), motions))
        out.append(_timed_copy(MotionPiece("retreat", side, t.line(opened, motions.with_arm_of(kp.q_pre, opened, side), 2), "none", None), motions))
        out.extend(next(edges))
    return out


def carried(a, b) -> bool:
    """Whether the object stays in hand from node a to node b (transfer or handover)."""
    if a is None or b is None:
        return False
    if isinstance(a, HandoverNode) or isinstance(b, HandoverNode):
        return True
    return a.grasp == b.grasp and a.hand == b.hand and a.placement != b.placement


def _timed_copy(piece: MotionPiece, motions: MotionValidator) -> MotionPiece:
    if getattr(piece, "timed", False):
        return piece
    tp = motions.timed(MotionPiece(piece.kind, piece.hand, piece.waypoints, piece.holding, piece.hold))
    if tp is None:  # short straight pieces were validated densely already; time them kinematically
        _, Q = time_parameterize(piece.waypoints, motions.task.robot, motions.task.settings.timing)
        piece.path = piece.waypoints
        piece.waypoints = Q
        piece.timed = True  # type: ignore[attr-defined]
        return piece
    return tp
