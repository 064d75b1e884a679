"""What a request may name, and the robot models the console draws.

``GET /v1/catalogue`` lists the built-in scenarios (with their own stance, threshold, hands and
seed, which a request leaves alone unless it overrides them), the stances, the hand
configurations and the robots, so the console's submit form offers only names the service
takes. ``GET /v1/robots/{name}/urdf`` serves a registered robot's URDF with every mesh reference
rewritten to ``/v1/robots/{name}/meshes/{index}``, and that route serves the mesh: by robot name
and index into the URDF's own mesh list, never a path taken from a request. ``GET /v1/meshes/{name}``
serves a registered object mesh by name.
"""

from __future__ import annotations

import functools
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Literal
from urllib.parse import unquote, urlparse

from fastapi import APIRouter, Depends
from fastapi import Path as PathParam
from fastapi.responses import Response

from schemas.common import StrictModel

from .auth import Principal
from .deps import principal, problems
from .problems import ProblemError

router = APIRouter(tags=["catalogue"])

HANDS = ("auto", "left-left", "right-right", "left-right", "right-left")
#: Mesh files a browser can draw through the console's loaders, and their media types.
MESH_TYPES = {".stl": "model/stl", ".dae": "model/vnd.collada+xml"}
RobotName = PathParam(..., min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")


class ScenarioEntry(StrictModel):
    """A built-in scenario with the values a request inherits when it does not override them."""

    name: str
    robot: str
    stance: str
    threshold_m: float
    hands: str
    seed: int
    time_limit_s: float | None
    object_shape: str
    object_mass_kg: float


class Catalogue(StrictModel):
    kinds: list[Literal["plan", "survey"]]
    scenarios: list[ScenarioEntry]
    stances: list[str]
    hands: list[str]
    robots: list[str]
    meshes: list[str]


@functools.lru_cache(maxsize=1)
def _catalogue() -> Catalogue:
    from planner.api.catalogue import BUILTIN_STANCES, builtin_names, load_builtin, registered_meshes, robot_names

    entries = []
    for name in builtin_names():
        sc = load_builtin(name)
        entries.append(ScenarioEntry(
            name=name, robot=sc.robot, stance=sc.stance if isinstance(sc.stance, str) else sc.stance.name,
            threshold_m=sc.threshold_m, hands=sc.hands, seed=sc.seed,
            time_limit_s=getattr(sc.limits, "time_s", None), object_shape=sc.object.shape,
            object_mass_kg=sc.object.mass_kg))
    return Catalogue(kinds=["plan", "survey"], scenarios=entries, stances=list(BUILTIN_STANCES), hands=list(HANDS),
                     robots=robot_names(), meshes=list(registered_meshes()))


@router.get("/v1/catalogue", response_model=Catalogue, summary="Scenarios, stances, hands and robots a request may name",
            responses=problems(401))
def catalogue(p: Principal = Depends(principal)) -> Catalogue:
    return _catalogue()


# ------------------------------------------------------------------ robot models
class RobotModelFiles:
    """A registered robot's URDF for browsers: mesh references replaced by API routes, the meshes by index."""

    def __init__(self, name: str, urdf: Path) -> None:
        self.name = name
        self.meshes: list[Path] = []
        tree = ET.parse(urdf)
        self.dropped: list[str] = []
        for link in tree.getroot().iter("link"):
            for tag in ("visual", "collision"):
                for element in list(link.findall(tag)):
                    mesh = element.find("geometry/mesh")
                    if mesh is None:
                        continue
                    path = _mesh_file(mesh.get("filename", ""), urdf.parent)
                    if tag == "collision" or path is None or path.suffix.lower() not in MESH_TYPES:
                        # Not drawn: collision meshes (the console draws visuals), and meshes it cannot load
                        # (its link is drawn without them). Their file names never reach the browser.
                        link.remove(element)
                        if tag == "visual":
                            self.dropped.append(link.get("name", "?"))
                        continue
                    mesh.set("filename", f"/v1/robots/{name}/meshes/{len(self.meshes)}{path.suffix.lower()}")
                    self.meshes.append(path)
        self.urdf_text = ET.tostring(tree.getroot(), encoding="unicode")


def _mesh_file(filename: str, base: Path) -> Path | None:
    """The file a URDF mesh reference names (relative to the URDF, absolute, or file://); None if not found."""
    if not filename:
        return None
    parsed = urlparse(filename)
    if parsed.scheme == "package":
        return None  # package:// resolution belongs to the robot's spec; such meshes are not drawn
    raw = unquote(parsed.path) if parsed.scheme == "file" else filename
    path = Path(raw) if Path(raw).is_absolute() else base / raw
    return path.resolve() if path.is_file() else None


@functools.lru_cache(maxsize=16)
def robot_model_files(name: str) -> RobotModelFiles:
    from planner.api.catalogue import UnknownRobotError, urdf_path

    try:
        return RobotModelFiles(name, urdf_path(name))
    except UnknownRobotError as exc:
        raise ProblemError(404, str(exc)) from None


@router.get("/v1/robots/{name}/urdf", summary="A registered robot's URDF, mesh references as API routes",
            response_class=Response,
            responses={200: {"content": {"application/xml": {"schema": {"type": "string"}}}, "description": "URDF"},
                       **problems(401, 404, 422)})
def robot_urdf(name: str = RobotName, p: Principal = Depends(principal)) -> Response:
    return Response(robot_model_files(name).urdf_text, media_type="application/xml")


@router.get("/v1/robots/{name}/meshes/{mesh}", summary="One mesh of a registered robot's URDF, by index",
            response_class=Response,
            responses={200: {"content": {t: {"schema": {"type": "string", "format": "binary"}} for t in MESH_TYPES.values()},
                             "description": "mesh file"}, **problems(401, 404, 422)})
def robot_mesh(name: str = RobotName,
               mesh: str = PathParam(..., max_length=16, pattern=r"^[0-9]{1,6}(\.[a-z]{3})?$",
                                     description="index in the URDF's mesh list, with the extension the URDF route gave"),
               p: Principal = Depends(principal)) -> Response:
    files = robot_model_files(name)
    index = int(re.match(r"^[0-9]+", mesh).group(0))  # type: ignore[union-attr]
    if index >= len(files.meshes):
        raise ProblemError(404, f"robot {name!r} has {len(files.meshes)} drawable mesh(es); no mesh {index}")
    path = files.meshes[index]
    return Response(path.read_bytes(), media_type=MESH_TYPES[path.suffix.lower()],
                    headers={"Cache-Control": "private, max-age=3600"})


@router.get("/v1/meshes/{name}", summary="A registered object mesh (the 3D view draws the object with it)",
            response_class=Response,
            responses={200: {"content": {"model/obj": {"schema": {"type": "string"}}, "model/stl": {"schema": {"type": "string"}}},
                             "description": "mesh file"}, **problems(401, 404, 422)})
def object_mesh(name: str = PathParam(..., min_length=1, max_length=128, pattern=r"^[A-Za-z0-9_.-]+$"),
                p: Principal = Depends(principal)) -> Response:
    from planner.api.catalogue import UnknownMeshError, mesh_file

    try:
        path = mesh_file(name)
    except UnknownMeshError as exc:
        raise ProblemError(404, str(exc)) from None
    media = "model/obj" if path.suffix.lower() == ".obj" else "model/stl"
    return Response(path.read_bytes(), media_type=media, headers={"Cache-Control": "private, max-age=3600"})
