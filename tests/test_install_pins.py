"""The tested versions are what a fresh machine installs: every dependency of the project and
of its test extra is pinned in constraints.txt, and every install path uses that file."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _name(requirement: str) -> str:
    """The normalised distribution name of a PEP 508 requirement string."""
    name = re.split(r"[\s\[<>=!~;]", requirement.strip(), maxsplit=1)[0]
    return re.sub(r"[-_.]+", "-", name).lower()


def _pins() -> dict[str, str]:
    pins: dict[str, str] = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        name, sep, version = line.partition("==")
        assert sep, f"constraints.txt line {line!r} is not an exact pin"
        pins[_name(name)] = version
    return pins


def test_every_direct_and_test_dependency_is_pinned() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = list(project["dependencies"]) + list(project["optional-dependencies"]["test"])
    pins = _pins()
    missing = sorted({_name(r) for r in wanted} - set(pins))
    assert not missing, f"not pinned in constraints.txt: {missing}"


def test_pytest_is_pinned_below_9_for_schemathesis() -> None:
    major = int(_pins()["pytest"].split(".")[0])
    assert major < 9


def test_test_script_and_dockerfile_install_with_the_constraints() -> None:
    assert "-c constraints.txt" in (ROOT / "scripts" / "test.sh").read_text()
    dockerfile = (ROOT / "docker" / "Dockerfile").read_text()
    assert "constraints.txt" in dockerfile and "-c constraints.txt" in dockerfile
    assert "scripts/test.sh" in (ROOT / ".ci" / "run").read_text()
