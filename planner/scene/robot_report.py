"""What ``regrasp robot check`` finds about a robot beyond its spec: the self-collision matrix, the pairs in
collision at the ready posture and at the built-in stances, and where the feet, the support polygon and the
CoM are.

The planner does not check self pairs that touch in the ready posture or in a stance's posture (they cannot
be told apart from a model's over-covering boxes there), so such pairs are listed here: a pair that truly
collides there needs a better posture or collision shapes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from planner.robot.model import RobotModel, frame_poses
from planner.scene.collision import CollisionWorld
from planner.scene.collision_matrix import CollisionMatrix, cached_matrix

BUILTIN_STANCES = ("upright", "staggered", "crouched", "one-legged")


@dataclass
class FootPrint:
    """A stance's soles (world corners, CCW), its support polygon and the robot's CoM."""

    stance: str
    soles: list[np.ndarray]
    polygon: np.ndarray
    com: np.ndarray
    margin_m: float


@dataclass
class RobotReport:
    matrix: CollisionMatrix | None
    matrix_cached: bool
    spec_pairs: int
    #: posture name ("ready" or a stance) -> link pairs in collision there that no rule of the matrix disables
    colliding: dict[str, list[tuple[str, str]]] = field(default_factory=dict)
    stance_errors: dict[str, str] = field(default_factory=dict)
    footprints: list[FootPrint] = field(default_factory=list)
    #: the ready posture's CoM minus its soles' polygon centre (x, y; m) and its soles' largest tilt (rad)
    ready_com_offset_m: np.ndarray | None = None
    ready_sole_tilt_rad: float = 0.0


def colliding_pairs(world: CollisionWorld, base: np.ndarray, q: np.ndarray, skip: set[tuple[str, str]]
                    ) -> list[tuple[str, str]]:
    """Link pairs of the robot in collision at one configuration, leaving out ``skip`` and a link with itself."""
    bodies = world.bodies[: world.n_robot]
    ia, ib = np.triu_indices(len(bodies), 1)
    keep = np.array([bodies[i].link != bodies[j].link and tuple(sorted((bodies[i].link, bodies[j].link))) not in skip
                     for i, j in zip(ia, ib)], dtype=bool)
    ia, ib = ia[keep], ib[keep]
    Rw, pw = world._robot_world(*world.kin.forward(np.asarray(base, float), np.asarray(q, float)[None, :]))
    hits = world._pair_hits(Rw, pw, ia, ib, np.zeros(ia.size))[:, 0]
    return sorted({tuple(sorted((bodies[i].link, bodies[j].link))) for i, j in zip(ia[hits], ib[hits])})


def _footprint(robot: RobotModel, stance) -> FootPrint:  # type: ignore[no-untyped-def]
    from planner.stability.stances import sole_size

    data = robot.create_data()
    soles = []
    for foot in stance.feet:
        if not foot.in_contact:
            continue
        length, width = sole_size(robot, foot.frame)
        T = frame_poses(robot, data, stance.base_pose, stance.q, [foot.frame])[0]
        corners = np.array([[sx * length / 2, sy * width / 2, 0.0] for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))])
        soles.append((corners @ T.rotation.T + T.translation)[:, :2])
    return FootPrint(stance.name, soles, np.asarray(stance.polygon.vertices), np.asarray(stance.robot_com),
                     float(stance.margin))


def robot_report(robot: RobotModel, progress: Callable[[str], None] = lambda m: None) -> RobotReport:
    """The matrix (computed and cached, unless the spec has an SRDF), the pairs in collision at the ready posture
    and the built-in stances, and each stance's feet, polygon and CoM."""
    from planner.stability.standing import posture_com_offset
    from planner.stability.stances import StanceError, solve_stance

    progress("building the collision model")
    world = CollisionWorld(robot, progress=progress)
    matrix, cached = (None, False)
    if robot.spec.self_collision_matrix == "computed":
        matrix, cached = cached_matrix(world, progress)
    skip = set(matrix.disabled()) if matrix is not None else set()
    skip |= {tuple(sorted(p)) for p in robot.spec.disabled_collisions}
    skip |= {tuple(sorted((a, b))) for a, b in world._geometric_parent().items() if b is not None}
    report = RobotReport(matrix, cached, len(robot.spec.disabled_collisions))
    base = np.array([0, 0, robot.spec.upright.pelvis_height_m, 0, 0, 0, 1.0])
    report.colliding["ready posture"] = colliding_pairs(world, base, robot.default_q(), skip)
    report.ready_com_offset_m, report.ready_sole_tilt_rad = posture_com_offset(robot, robot.default_q())
    for name in BUILTIN_STANCES:
        progress(f"stance {name}")
        try:
            stance = solve_stance(robot, name)
        except (StanceError, ValueError) as exc:
            report.stance_errors[name] = str(exc)
            continue
        report.colliding[f"stance {name}"] = colliding_pairs(world, stance.base_pose, stance.q, skip)
        report.footprints.append(_footprint(robot, stance))
    return report
