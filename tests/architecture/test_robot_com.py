"""One home for the robot's CoM in the planner: planner/stability (and the compiled kernels it calls).

The gate's and the plan checker's copies live outside the planner on purpose (independent channels)
and are not looked at here."""

from __future__ import annotations

import ast

from tests.architecture.import_graph import project_modules

#: Where the planner may compute the robot's CoM: the stability package and the compiled kernels it calls.
HOMES = ("planner.stability", "planner.compiled")
#: pinocchio's CoM functions and the compiled kernel of the batched CoM.
COM_CALLS = {"centerOfMass", "jacobianCenterOfMass", "getComFromCrba", "jacobianSubtreeCenterOfMass", "weighted_sum"}


def _mentions_mass(node: ast.AST) -> bool:
    for sub in ast.walk(node):
        name = (sub.id if isinstance(sub, ast.Name) else sub.attr if isinstance(sub, ast.Attribute)
                else sub.value if isinstance(sub, ast.Constant) and isinstance(sub.value, str) else "")
        if "mass" in name.lower():
            return True
    return False


def com_computations(source: str) -> list[str]:
    """Lines of ``source`` that compute a CoM: a call of pinocchio's CoM functions or of the compiled
    CoM kernel, a division by a mass (a hand-written mass-weighted mean), or numpy's average weighted
    by masses."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
            if name in COM_CALLS:
                found.append(f"line {node.lineno}: {name}()")
            elif name == "average" and any(k.arg == "weights" and _mentions_mass(k.value) for k in node.keywords):
                found.append(f"line {node.lineno}: average weighted by masses")
        elif isinstance(node, (ast.BinOp, ast.AugAssign)) and isinstance(node.op, ast.Div):
            if _mentions_mass(node.right if isinstance(node, ast.BinOp) else node.value):
                found.append(f"line {node.lineno}: division by a mass")
    return found


def test_the_robot_com_is_computed_only_in_planner_stability() -> None:
    offenders = [
        f"{module} {where}"
        for module, path in project_modules().items()
        if module.startswith("planner.") and not module.startswith(HOMES)
        for where in com_computations(path.read_text())
    ]
    assert not offenders, f"robot CoM computed outside planner/stability: {offenders}"


def test_the_detector_sees_each_kind_of_com_computation() -> None:
    source = (
        "import pinocchio as pin\n"
        "c = pin.centerOfMass(model, data, q, False)\n"
        "J = pin.jacobianCenterOfMass(model, data)\n"
        "c = weighted_sum(R, p, slots, mass, lever, m0, total)\n"
        "c = sum(m * x for m, x in bodies) / robot.total_mass\n"
        "lever = moment / s['mass']\n"
        "c = np.average(points, axis=0, weights=link_masses)\n"
        "share = 0.5 * width / height\n"
    )
    assert [w.split(":")[0] for w in com_computations(source)] == [f"line {k}" for k in range(2, 8)]
