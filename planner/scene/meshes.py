"""Object meshes by registered name, and scenario dumps that stay valid wherever they are saved.

A scenario names its object mesh as ``{name: REGISTERED}`` (a mesh shipped with the planner) or
``{path: FILE}`` relative to the scenario file (docs/contract.md section 2). Loading resolves either
to a file (:func:`resolve_mesh`); dumping gives back the portable form (:func:`portable_mesh`):
the name, or the path as the file wrote it, never the absolute path of one checkout. So
``regrasp scenario show NAME`` and a plan's ``scenario`` work when saved anywhere.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from planner.errors import InputError
from schemas.scenario import MeshSource, Scenario

#: Where the registered meshes live (next to the built-in scenarios that use them).
MESH_DIR = Path(__file__).parent / "scenario_data"
MESH_SUFFIXES = (".obj", ".stl")


class UnknownMeshError(InputError):
    """A mesh name that is not registered."""


def registered_meshes() -> dict[str, Path]:
    """Registered mesh name -> its file."""
    return {p.stem: p for p in sorted(MESH_DIR.iterdir()) if p.suffix.lower() in MESH_SUFFIXES}


def mesh_file(name: str) -> Path:
    """The file of a registered mesh; an unknown name lists the registered ones."""
    meshes = registered_meshes()
    if name not in meshes:
        raise UnknownMeshError(f"unknown mesh {name!r}; registered meshes: {', '.join(meshes) or '(none)'}")
    return meshes[name]


def resolve_mesh(mesh: MeshSource | None, base_dir: Path | None) -> None:
    """Point ``mesh.path`` at its file, in place: a name through the registry, a relative path against
    ``base_dir`` (the scenario file's folder; kept as written for dumps)."""
    if mesh is None:
        return
    if mesh.name is not None:
        mesh.path = str(mesh_file(mesh.name))
        return
    assert mesh.path is not None
    if base_dir is not None and not Path(mesh.path).is_absolute():
        written = mesh.path
        mesh.path = str((base_dir / written).resolve())
        mesh._written = written


def portable_mesh(mesh: MeshSource) -> dict[str, Any]:
    """The mesh as a scenario file should say it: by name when registered, else the path as written."""
    if mesh.name is not None:
        return {"name": mesh.name, "scale": mesh.scale}
    if mesh._written is not None:
        return {"path": mesh._written, "scale": mesh.scale}
    path = Path(mesh.path or "")
    registered = registered_meshes()
    if path.is_absolute() and path.stem in registered and registered[path.stem].resolve() == path.resolve():
        return {"name": path.stem, "scale": mesh.scale}
    return {"path": mesh.path, "scale": mesh.scale}


def portable_dump(scenario: Scenario, **kwargs: Any) -> dict[str, Any]:
    """``scenario.model_dump(**kwargs)`` with the object's mesh in its portable form."""
    data = scenario.model_dump(**kwargs)
    if data.get("fitted", 0) is None:
        del data["fitted"]  # only a fitted task records it
    if scenario.object.mesh is not None:
        data["object"]["mesh"] = portable_mesh(scenario.object.mesh)
    return data


def carry_mesh_source(old: Scenario, new: Scenario) -> Scenario:
    """Keep how ``old``'s mesh was written on ``new`` (a re-validated copy of it); returns ``new``."""
    if old.object.mesh is not None and new.object.mesh is not None and old.object.mesh.path == new.object.mesh.path:
        new.object.mesh._written = old.object.mesh._written
    return new
