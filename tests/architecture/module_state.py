"""Module-level state, read from the source with :mod:`ast`: what a module keeps between calls
outside any owner object.

A module may hold constants (a table, a tuple of names) and a bounded cache. It may not hold
state that changes at run time: a container filled or changed after import, a name rebound
through ``global``, an object whose attributes are set from a function, an instance of a type
whose whole job is to accumulate (a weak set, a queue, a counter, a thread-local), or an
unbounded cache.
"""

from __future__ import annotations

import ast

#: Calls that build a container or an accumulator.
CONTAINER_CALLS = frozenset({
    "dict", "list", "set", "defaultdict", "OrderedDict", "Counter", "deque", "bytearray",
})
ACCUMULATOR_CALLS = frozenset({
    "WeakSet", "WeakValueDictionary", "WeakKeyDictionary", "local", "count", "Queue", "SimpleQueue",
    "LifoQueue", "PriorityQueue", "ChainMap",
})
#: Methods that change a container in place.
MUTATING_METHODS = frozenset({
    "append", "extend", "insert", "update", "setdefault", "pop", "popitem", "clear", "add", "discard",
    "remove", "sort", "reverse", "appendleft", "extendleft", "popleft", "put", "put_nowait", "__setitem__",
    "__delitem__",
})
_CONTAINER_NODES = (ast.Dict, ast.List, ast.Set, ast.DictComp, ast.ListComp, ast.SetComp)


def _call_name(node: ast.AST) -> str | None:
    if isinstance(node, ast.Call):
        func = node.func
        if isinstance(func, ast.Name):
            return func.id
        if isinstance(func, ast.Attribute):
            return func.attr
    return None


def _module_bindings(tree: ast.Module) -> dict[str, ast.expr]:
    """Names bound at module level by a plain or annotated assignment, with their value."""
    out: dict[str, ast.expr] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign):
            targets, value = node.targets, node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            targets, value = [node.target], node.value
        else:
            continue
        for t in targets:
            if isinstance(t, ast.Name):
                out[t.id] = value
    return out


def _root_name(node: ast.AST) -> str | None:
    """``X`` of ``X``, ``X[k]``, ``X.a.b``."""
    while isinstance(node, (ast.Subscript, ast.Attribute)):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def _changed_names(tree: ast.Module) -> dict[str, str]:
    """Names whose value something in the module changes in place, each with how."""
    out: dict[str, str] = {}
    for node in ast.walk(tree):
        targets: list[ast.AST] = []
        if isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
        elif isinstance(node, ast.Delete):
            targets = node.targets
        for t in targets:
            if isinstance(t, (ast.Subscript, ast.Attribute)) and (name := _root_name(t)):
                out.setdefault(name, f"assigned into (line {node.lineno})")
            if isinstance(node, ast.AugAssign) and isinstance(t, ast.Name):
                out.setdefault(t.id, f"augmented (line {node.lineno})")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in MUTATING_METHODS:
            if name := _root_name(node.func.value):
                out.setdefault(name, f".{node.func.attr}() (line {node.lineno})")
    return out


def _unbounded_cache(decorator: ast.expr) -> bool:
    """``@cache``, ``@functools.cache`` or ``@lru_cache(maxsize=None)`` (a bare ``@lru_cache`` keeps 128)."""
    name = decorator.attr if isinstance(decorator, ast.Attribute) else getattr(decorator, "id", None)
    if name == "cache":
        return True
    if _call_name(decorator) == "lru_cache":
        call = decorator
        assert isinstance(call, ast.Call)
        size = call.args[0] if call.args else next((k.value for k in call.keywords if k.arg == "maxsize"), None)
        return isinstance(size, ast.Constant) and size.value is None
    return False


def module_state(source: str) -> list[str]:
    """Each piece of module-level run-time state in ``source``: ``"NAME: why"``."""
    tree = ast.parse(source)
    found: list[str] = []
    bindings = _module_bindings(tree)
    changed = _changed_names(tree)
    for name, value in bindings.items():
        call = _call_name(value)
        if call in ACCUMULATOR_CALLS:
            found.append(f"{name}: a module-level {call}()")
        elif isinstance(value, (ast.Dict, ast.List, ast.Set)) and not (
            getattr(value, "keys", None) or getattr(value, "elts", None)
        ) or (call in CONTAINER_CALLS and not (value.args or value.keywords)):  # type: ignore[union-attr]
            found.append(f"{name}: an empty container, to be filled at run time")
        elif name in changed:
            found.append(f"{name}: changed in place, {changed[name]}")
    for node in ast.walk(tree):
        if isinstance(node, ast.Global):
            found += [f"{n}: rebound through `global` (line {node.lineno})" for n in node.names]
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            found += [f"{node.name}: an unbounded cache (line {node.lineno})"
                      for d in node.decorator_list if _unbounded_cache(d)]
    first: dict[str, str] = {}
    for entry in found:
        first.setdefault(entry.split(":")[0], entry)
    return list(first.values())
