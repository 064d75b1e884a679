"""The architecture the tree promises: no import cycles, dependencies pointing one way
(schemas <- robot_data <- planner <- robot_bridge <- service), and no module-level
containers that hold scratch data."""

from __future__ import annotations

import ast

from tests.architecture.import_graph import (
    PACKAGES,
    cycles,
    import_graph,
    project_modules,
)

#: Package order: a package may import those before it, never those after it.
LAYERS = {name: rank for rank, name in enumerate(PACKAGES)}


def test_there_is_no_import_cycle() -> None:
    found = cycles(import_graph())
    assert not found, f"import cycles (every import counts, lazy ones included): {found}"


def test_cycle_finder_finds_a_cycle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]


def test_dependencies_point_one_way() -> None:
    upward = sorted(
        f"{module} -> {dep}"
        for module, deps in import_graph().items()
        for dep in deps
        if LAYERS[dep.split(".")[0]] > LAYERS[module.split(".")[0]]
    )
    assert not upward, f"imports against the layer order {list(PACKAGES)}: {upward}"


def test_robot_data_is_data_only() -> None:
    graph = import_graph()
    assert not any(deps for module, deps in graph.items() if module.split(".")[0] == "robot_data")


def _mutable_module_globals(tree: ast.Module) -> list[str]:
    """Names bound at module level to an empty (so: to-be-filled) dict, list, set or defaultdict."""
    found = []
    for node in tree.body:
        if isinstance(node, ast.Assign):
            targets, value = node.targets, node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            targets, value = [node.target], node.value
        else:
            continue
        empty_literal = isinstance(value, (ast.Dict, ast.List, ast.Set)) and not (
            getattr(value, "keys", None) or getattr(value, "elts", None)
        )
        empty_call = (
            isinstance(value, ast.Call)
            and isinstance(value.func, ast.Name)
            and value.func.id in {"dict", "list", "set", "defaultdict", "OrderedDict", "WeakValueDictionary"}
        )
        if empty_literal or empty_call:
            found += [t.id for t in targets if isinstance(t, ast.Name)]
    return found


#: Module-level containers that are not scratch data, each with the reason.
ALLOWED_GLOBALS = {
    "planner.survey.seed_map._FORK_STATE": "what a forked seed worker inherits from its parent: filled just before "
                                            "the pool forks, read-only in the workers, cleared after",
}


def test_no_module_global_holds_scratch_data() -> None:
    offenders = []
    for module, path in project_modules().items():
        if module.split(".")[0] not in ("planner", "robot_bridge", "schemas", "robot_data", "service"):
            continue
        offenders += [f"{module}.{name}" for name in _mutable_module_globals(ast.parse(path.read_text()))
                      if f"{module}.{name}" not in ALLOWED_GLOBALS]
    assert not offenders, f"module-level containers filled at run time (keep them on the model or a data object): {offenders}"


def test_scratch_global_detector_sees_one() -> None:
    tree = ast.parse("CACHE: dict[int, int] = {}\nTABLE = {'a': 1}\nSEEN = set()\n")
    assert _mutable_module_globals(tree) == ["CACHE", "SEEN"]
