"""Which exception classes a package defines, and whether each derives from the package's base, read
from the source with :mod:`ast` (a class is followed through its bases by name, across the project)."""

from __future__ import annotations

import ast
import builtins
from pathlib import Path

#: The built-in exception names (Exception, ValueError, ...).
BUILTIN_EXCEPTIONS = frozenset(n for n, v in vars(builtins).items() if isinstance(v, type) and issubclass(v, BaseException))


def class_bases(modules: dict[str, Path]) -> dict[str, tuple[str, set[str]]]:
    """Every top-level class of ``modules``: name -> (its module, the names of its bases)."""
    out: dict[str, tuple[str, set[str]]] = {}
    for module, path in modules.items():
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ClassDef):
                names = {b.attr if isinstance(b, ast.Attribute) else getattr(b, "id", "") for b in node.bases}
                out.setdefault(node.name, (module, names))
    return out


def ancestors(name: str, classes: dict[str, tuple[str, set[str]]]) -> set[str]:
    """The names of every class ``name`` derives from, itself excluded."""
    seen: set[str] = set()
    todo = list(classes.get(name, ("", set()))[1])
    while todo:
        base = todo.pop()
        if base not in seen:
            seen.add(base)
            todo += classes.get(base, ("", set()))[1]
    return seen


def exceptions_outside(package: str, base: str, classes: dict[str, tuple[str, set[str]]]) -> list[str]:
    """The exception classes defined in ``package`` that do not derive from ``base``."""
    return sorted(f"{module}.{name}" for name, (module, _) in classes.items()
                  if module.split(".")[0] == package and name != base
                  and ancestors(name, classes) & (BUILTIN_EXCEPTIONS | {base})
                  and base not in ancestors(name, classes))
