"""The architecture the tree promises: no import cycles, dependencies pointing one way
(schemas <- robot_data <- planner <- robot_bridge <- experiments <- service), no module-level state outside
an allow-list with reasons, and a service grouped by concept."""

from __future__ import annotations

import ast

from tests.architecture.import_graph import (
    PACKAGES,
    ROOT,
    cycles,
    import_graph,
    project_modules,
)
from tests.architecture.module_state import module_state

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


def _function_level_imports(tree: ast.Module) -> list[str]:
    """The modules imported inside a function or method (a dependency the module's head does not show)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for inner in ast.walk(node):
                if isinstance(inner, ast.Import):
                    found += [a.name for a in inner.names]
                elif isinstance(inner, ast.ImportFrom):
                    found.append("." * inner.level + (inner.module or ""))
    return found


def test_experiments_show_their_dependencies_at_the_top() -> None:
    """The paper's reproduction, its claims, ablations and figures: no lazy import reaching into the planner."""
    lazy = {module: found for module, path in project_modules().items() if module.split(".")[0] == "experiments"
            and (found := _function_level_imports(ast.parse(path.read_text())))}
    assert not lazy, f"function-level imports in experiments/: {lazy}"


def test_the_service_holds_no_paper_reproduction() -> None:
    """The reproduction and its figures live in experiments/; the service only calls them (``regrasp paper``
    is a command of the service's CLI)."""
    kept = [module for module in project_modules() if module.split(".")[0] == "service"
            and not module.startswith("service.cli.")
            and module.rpartition(".")[2] in {"paper", "paper_claims", "claims", "plots", "convergence_plot"}]
    assert not kept, kept
    graph = import_graph()
    assert not any(dep.split(".")[0] == "service" for m, deps in graph.items() if m.split(".")[0] == "experiments"
                   for dep in deps)


def test_lazy_import_detector_sees_one() -> None:
    tree = ast.parse("import os\ndef f():\n    from planner.regrasp import task\n    import numpy\n")
    assert _function_level_imports(tree) == ["planner.regrasp", "numpy"]


#: Module-level run-time state that is allowed, each with the reason.
ALLOWED_STATE = {
    "planner.survey.seed_map._WORKER_FN": "a forked seed worker's per-seed function, set once by its pool's "
                                          "initializer from the pool's own arguments; a parent never sets it",
}


def test_no_module_holds_run_time_state() -> None:
    offenders = []
    for module, path in project_modules().items():
        offenders += [f"{module}.{entry}" for entry in module_state(path.read_text())
                      if f"{module}.{entry.split(':')[0]}" not in ALLOWED_STATE]
    assert not offenders, ("module-level state (keep it on the model, a data object or its owner; "
                           f"bound caches): {offenders}")


def test_every_allowed_state_still_exists() -> None:
    """An allow-list entry whose state has gone is removed, so the list stays a list of real exceptions."""
    modules = project_modules()
    stale = [entry for entry in ALLOWED_STATE
             if not any(found.split(":")[0] == entry.rpartition(".")[2]
                        for found in module_state(modules[entry.rpartition(".")[0]].read_text()))]
    assert not stale, f"allowed module state that no longer exists: {stale}"


def test_the_state_detector_sees_each_kind() -> None:
    source = """
import functools, threading, weakref
from functools import lru_cache
TABLE = {"a": 1}
FILLED = {"a": 1}
CACHE: dict[int, int] = {}
SEEN = set()
WATCHED = weakref.WeakSet()
LOCAL = threading.local()
COUNT = 0
HOLDER = Holder()
NAMES = ("a", "b")

def f(x):
    global COUNT
    COUNT += 1
    FILLED["b"] = x
    HOLDER.last = x

@lru_cache(maxsize=None)
def g(x): return x

@functools.cache
def h(x): return x

@lru_cache(maxsize=8)
def bounded(x): return x
"""
    found = sorted(entry.split(":")[0] for entry in module_state(source))
    assert found == ["CACHE", "COUNT", "FILLED", "HOLDER", "LOCAL", "SEEN", "WATCHED", "g", "h"]


#: What of the planner the service and the experiments may import: its public interface and its error hierarchy.
PLANNER_PUBLIC = ("planner.api", "planner.errors")


def test_service_and_experiments_import_only_the_planners_public_interface() -> None:
    internal = sorted(
        f"{module} -> {dep}"
        for module, deps in import_graph().items()
        if module.split(".")[0] in ("service", "experiments")
        for dep in deps
        if dep.split(".")[0] == "planner" and not any(dep == p or dep.startswith(p + ".") for p in PLANNER_PUBLIC)
    )
    assert not internal, f"service/ or experiments/ import planner internals (use planner.api): {internal}"


def test_the_planners_public_interface_names_what_it_exports() -> None:
    """Each part of planner.api lists its names in ``__all__``, and every name listed is there."""
    import importlib

    for module in sorted(m for m in project_modules() if m.startswith("planner.api.")):
        loaded = importlib.import_module(module)
        missing = [name for name in loaded.__all__ if not hasattr(loaded, name)]
        assert not missing, f"{module}.__all__ names what it does not have: {missing}"
#: At most this many modules and packages at the top of service/: the rest is grouped by concept.
MAX_SERVICE_TOP_LEVEL = 14


def test_service_top_level_stays_small() -> None:
    service = ROOT / "service"
    entries = sorted([p.name for p in service.glob("*.py")]
                     + [p.name + "/" for p in service.iterdir() if (p / "__init__.py").is_file()])
    assert len(entries) <= MAX_SERVICE_TOP_LEVEL, (
        f"service/ has {len(entries)} top-level modules and packages (at most {MAX_SERVICE_TOP_LEVEL}): {entries}")


#: Each package's one exception base: every error it raises on purpose derives from it.
ERROR_BASES = {"planner": "PlannerError", "robot_bridge": "BridgeError", "service": "RegraspServiceError"}


def test_each_package_has_one_exception_base() -> None:
    from tests.architecture.error_bases import class_bases, exceptions_outside

    classes = class_bases(project_modules())
    outside = {package: exceptions_outside(package, base, classes) for package, base in ERROR_BASES.items()}
    assert not any(outside.values()), f"exception classes outside their package's base: {outside}"


def test_the_exception_base_check_sees_a_stray_error() -> None:
    from tests.architecture.error_bases import ancestors, exceptions_outside

    classes = {"PlannerError": ("planner.errors", {"Exception"}), "InputError": ("planner.errors", {"PlannerError", "ValueError"}),
               "Good": ("planner.a", {"InputError"}), "Stray": ("planner.b", {"ValueError"}), "Plain": ("planner.c", {"object"})}
    assert ancestors("Good", classes) == {"InputError", "PlannerError", "ValueError", "Exception"}
    assert exceptions_outside("planner", "PlannerError", classes) == ["planner.b.Stray"]
