"""What a service request may name: registered scenarios, stances, robots and meshes, never files.

A request to the HTTP service names things; it never names a file on the server
(docs/contract.md section 5). The command line takes scenario, stance and robot
files, and the planner's loaders follow paths, so every string a request carries
is checked here against the registered names before anything is loaded:

- at submission, by the API, which answers 422 listing the valid names;
- again in the worker (:func:`resolve_request`), which turns a named scenario into
  the scenario document it stands for and a mesh name into the registered mesh, so
  the planner never receives a request string that could become a path.

Errors quote the request's own value (shortened) and the valid names, never the
contents of any file.
"""

from __future__ import annotations

import re
from functools import lru_cache
from typing import Any

from planner.errors import InputError
from planner.scene.meshes import registered_meshes

#: A registered name: letters, digits, ``_``, ``-`` and ``.``, starting with a letter or digit.
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
#: A name ending in a dot and letters reads as a file name (``tokens.json``, ``x.yaml``) and is refused.
FILE_SUFFIX_RE = re.compile(r"\.[A-Za-z][A-Za-z0-9]*$")
#: How much of a refused value an error quotes.
QUOTE_CHARS = 60


class RequestNameError(InputError):
    """A request names something that is not registered, or names a file."""

    def __init__(self, field: str, message: str, valid: list[str] | None = None) -> None:
        super().__init__(message)
        self.field = field
        self.valid = list(valid or [])


def _quote(value: Any) -> str:
    text = str(value)
    return repr(text if len(text) <= QUOTE_CHARS else text[:QUOTE_CHARS] + "...")


def looks_like_path(value: str) -> bool:
    """True for anything that is not a plain name: separators, ``..``, a leading dot, a file suffix."""
    return (not NAME_RE.match(value)) or ".." in value or bool(FILE_SUFFIX_RE.search(value))


@lru_cache(maxsize=1)
def registered_scenarios() -> tuple[str, ...]:
    from planner.scene.scenarios import builtin_names

    return tuple(builtin_names())


def registered_stances() -> tuple[str, ...]:
    from planner.stability.stances import BUILTIN_STANCES

    return tuple(BUILTIN_STANCES)


@lru_cache(maxsize=1)
def registered_robots() -> tuple[str, ...]:
    from planner.robot.registry import robot_names

    return tuple(robot_names())


def check_name(field: str, what: str, value: Any, valid: tuple[str, ...] | list[str], *,
               require_registered: bool = True) -> None:
    """``value`` must be a plain name and (unless ``require_registered`` is off) one of ``valid``."""
    if not isinstance(value, str):
        raise RequestNameError(field, f"{field}: a {what} is given by its name (a string), not {type(value).__name__}",
                               list(valid))
    plural = what + ("es" if what.endswith("sh") else "s")
    listing = f"; valid {plural}: {', '.join(valid) or 'none'}"
    if looks_like_path(value):
        raise RequestNameError(field, f"{field}: {_quote(value)} is not a {what} name: a request names registered "
                                      f"{plural}, never a file or a path{listing}", list(valid))
    if require_registered and value not in valid:
        raise RequestNameError(field, f"{field}: unknown {what} {_quote(value)}{listing}", list(valid))


def check_inline_scenario(doc: dict[str, Any], where: str = "request.scenario") -> None:
    """The names inside an inline scenario document: its robot, its stance (if a name) and its mesh."""
    if "robot" in doc:
        check_name(f"{where}.robot", "robot", doc["robot"], registered_robots())
    stance = doc.get("stance")
    if isinstance(stance, str):
        check_name(f"{where}.stance", "stance", stance, registered_stances())
    obj = doc.get("object")
    mesh = obj.get("mesh") if isinstance(obj, dict) else None
    if isinstance(mesh, dict):
        if mesh.get("path") is not None:
            raise RequestNameError(f"{where}.object.mesh.path",
                                   f"{where}.object.mesh: a request names a registered mesh ({{name: NAME}}), never a "
                                   f"file; registered meshes: {', '.join(registered_meshes()) or 'none'}",
                                   list(registered_meshes()))
        if "name" in mesh:
            check_name(f"{where}.object.mesh.name", "mesh", mesh["name"], list(registered_meshes()))


def check_request(request: dict[str, Any], *, require_registered_scenario: bool = True) -> None:
    """Every name of a job request (scenario, stance, robot, and those of an inline scenario).

    ``require_registered_scenario`` off still refuses a scenario name that reads as a path; it
    lets a deployment's own job handlers take names of their own.
    """
    scenario = request.get("scenario")
    if isinstance(scenario, dict):
        check_inline_scenario(scenario)
    else:
        check_name("request.scenario", "scenario", scenario, registered_scenarios(),
                   require_registered=require_registered_scenario)
    if request.get("stance") is not None:
        check_name("request.stance", "stance", request["stance"], registered_stances())
    if request.get("robot") is not None:
        check_name("request.robot", "robot", request["robot"], registered_robots())


def resolve_request(request: dict[str, Any]) -> dict[str, Any]:
    """The request as the planner runs it: names checked, a named scenario replaced by its document.

    The built-in scenario is loaded from the planner's own data by its registered name, and a
    request's ``robot`` goes into the scenario, so the planner's loaders (which also take files,
    for the command line) only ever see documents and registered names.
    """
    check_request(request)
    from planner.scene.scenarios import load_builtin

    out = dict(request)
    scenario = request["scenario"]
    if isinstance(scenario, str):
        doc = load_builtin(scenario).model_dump(by_alias=True, mode="json", exclude_none=True)
    else:
        doc = dict(scenario)
    if out.pop("robot", None) is not None:
        doc["robot"] = request["robot"]
    out["scenario"] = doc
    return out
