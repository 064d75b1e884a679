"""The self-collision matrix of a robot without an SRDF, computed as MoveIt's setup assistant does.

Link pairs that never need checking are found from many random configurations (uniform in the joint limits,
seeded, so the same pairs every time):

- ``adjacent``: a link and the nearest ancestor that has geometry (they touch at their joint by design);
- ``always``: pairs in collision in at least 95 % of the samples (they cannot be told apart);
- ``nested``: pairs on one chain, at most two joints apart, in collision in at least half of the samples:
  the box fitted to a housing (a forearm, a wrist) and the box of what turns inside it overlap around the
  joints whatever their values, where the meshes themselves would not touch;
- ``never``: pairs in collision in none of the samples (checking them only costs time), except a link of one
  arm against a link of the other: random configurations seldom bring the hands together, a handover does.

The result depends only on the robot's URDF and spec, so it is kept in the cache folder under their hash and
computed once (a few seconds); a spec with an ``srdf`` uses the SRDF's matrix instead.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pinocchio as pin

#: a planner.scene.collision.CollisionWorld (not imported: that module imports this one)
CollisionWorld = Any

#: samples of the joint space, their seed, the fractions of the rules above and the chain distance of "nested"
SAMPLES = 2000
SEED = 20250
ALWAYS_FRACTION = 0.95
NESTED_FRACTION = 0.5
NESTED_MAX_JOINTS = 2
#: bump when the rules change, so matrices cached by an older version are not reused
MATRIX_VERSION = 2
_BATCH = 250

Pair = tuple[str, str]


@dataclass(frozen=True)
class CollisionMatrix:
    """Link pairs not checked for self-collision, by the reason they are not; each pair sorted, each list sorted."""

    adjacent: tuple[Pair, ...]
    always: tuple[Pair, ...]
    nested: tuple[Pair, ...]
    never: tuple[Pair, ...]
    samples: int
    seed: int

    def disabled(self) -> set[Pair]:
        return {*self.adjacent, *self.always, *self.nested, *self.never}

    def to_json(self) -> dict:
        return {"version": MATRIX_VERSION, "samples": self.samples, "seed": self.seed,
                **{k: [list(p) for p in getattr(self, k)] for k in ("adjacent", "always", "nested", "never")}}

    @classmethod
    def from_json(cls, doc: dict) -> "CollisionMatrix":
        return cls(**{k: tuple(tuple(p) for p in doc[k]) for k in ("adjacent", "always", "nested", "never")},
                   samples=int(doc["samples"]), seed=int(doc["seed"]))


def matrix_key(urdf: Path, spec_json: str) -> str:
    """The cache key: the URDF's and the spec's content and the rules' version."""
    h = hashlib.sha256(f"collision-matrix/{MATRIX_VERSION}/{SAMPLES}/{SEED}/".encode())
    h.update(Path(urdf).read_bytes())
    h.update(b"\0" + spec_json.encode())
    return h.hexdigest()


def _cache_file(name: str, key: str) -> Path:
    from planner.robot.spec_file import cache_dir

    return cache_dir() / "collision-matrices" / f"{name}-{key[:20]}.json"


def cached_matrix(world: CollisionWorld, progress: Callable[[str], None] = lambda m: None
                  ) -> tuple[CollisionMatrix, bool]:
    """The robot's computed matrix, from the cache folder or computed now and stored there; and whether it was
    cached."""
    robot = world.robot
    key = matrix_key(robot.urdf_path, robot.spec.model_dump_json())
    path = _cache_file(robot.name, key)
    if path.is_file():
        try:
            return CollisionMatrix.from_json(json.loads(path.read_text())), True
        except (OSError, ValueError, KeyError, TypeError):
            pass  # a damaged cache file: computed again below
    matrix = compute_matrix(world, progress)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(matrix.to_json()))
    tmp.replace(path)
    return matrix, False


def _chain_distance(model: pin.Model, ja: int, jb: int) -> int | None:
    """Joints between two links' parent joints when one is the other's ancestor, else None."""
    sa, sb = list(model.supports[ja]), list(model.supports[jb])
    if ja in sb:
        return len(sb) - len(sa)
    if jb in sa:
        return len(sa) - len(sb)
    return None


def _subtree_links(model: pin.Model, joint_id: int) -> set[str]:
    """Body frames moved by ``joint_id`` (carried by it or a joint below it)."""
    return {f.name for f in model.frames if f.type == pin.FrameType.BODY and joint_id in model.supports[f.parentJoint]}


def compute_matrix(world: CollisionWorld, progress: Callable[[str], None] = lambda m: None) -> CollisionMatrix:
    """Sample the joint space (seeded) and sort the robot's link pairs by the rules of the module docstring."""
    robot = world.robot
    bodies = world.bodies[: world.n_robot]
    gp = world._geometric_parent()
    adjacent = {tuple(sorted((link, parent))) for link, parent in gp.items() if parent is not None}
    ia, ib = np.triu_indices(len(bodies), 1)
    other = np.array([bodies[i].link != bodies[j].link for i, j in zip(ia, ib)], dtype=bool)
    ia, ib = ia[other], ib[other]
    # body pair -> link pair (index into la/lb)
    link_pairs = sorted({tuple(sorted((bodies[i].link, bodies[j].link))) for i, j in zip(ia, ib)})
    lp_index = {p: k for k, p in enumerate(link_pairs)}
    body_to_lp = np.array([lp_index[tuple(sorted((bodies[i].link, bodies[j].link)))] for i, j in zip(ia, ib)])
    counts = np.zeros(len(link_pairs), dtype=np.int64)
    rng = np.random.default_rng(SEED)
    base = np.array([0, 0, robot.spec.upright.pelvis_height_m, 0, 0, 0, 1.0])
    done = 0
    while done < SAMPLES:
        n = min(_BATCH, SAMPLES - done)
        Q = rng.uniform(robot.lower, robot.upper, (n, robot.nq))
        Rw, pw = world._robot_world(*world.kin.forward(base, Q))
        hits = world._pair_hits(Rw, pw, ia, ib, np.zeros(ia.size))
        per_link = np.zeros((len(link_pairs), n), dtype=bool)
        np.logical_or.at(per_link, body_to_lp, hits)
        counts += per_link.sum(axis=1)
        done += n
        progress(f"collision matrix: {done}/{SAMPLES} random configurations")
    frac = counts / SAMPLES
    model = robot.pin_model
    joint_of = {b.link: int(b.joint) for b in bodies}
    arms = [_subtree_links(model, model.getJointId(arm.chain[0])) for arm in robot.spec.arms.values()]
    always, nested, never = [], [], []
    for k, pair in enumerate(link_pairs):
        if pair in adjacent:
            continue
        across = any(pair[0] in a and pair[1] in b for a in arms for b in arms if a is not b)
        if frac[k] >= ALWAYS_FRACTION:
            always.append(pair)
        elif counts[k] == 0:
            if not across:
                never.append(pair)
        elif frac[k] >= NESTED_FRACTION:
            dist = _chain_distance(model, joint_of[pair[0]], joint_of[pair[1]])
            if dist is not None and dist <= NESTED_MAX_JOINTS:
                nested.append(pair)
    return CollisionMatrix(adjacent=tuple(sorted(adjacent)), always=tuple(always), nested=tuple(nested),
                           never=tuple(never), samples=SAMPLES, seed=SEED)
