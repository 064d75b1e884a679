"""Deployment files: compose.yaml validated by Docker Compose itself where it is installed,
plus structural checks of compose.yaml and the Dockerfile that need no Docker at all.

No Docker engine runs here: ``docker compose config`` only parses, interpolates and
validates the file. The test prefers the compose plugin (``docker compose``) and falls
back to the standalone ``docker-compose``; without either it skips and says so.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

DOCKER_DIR = Path(__file__).resolve().parents[1] / "docker"
COMPOSE = DOCKER_DIR / "compose.yaml"
DOCKERFILE = DOCKER_DIR / "Dockerfile"
CORE_SERVICES = {"api", "worker", "controller", "postgres"}
RAY_SERVICES = {"ray-head", "ray-worker", "worker-ray"}
COMPOSE_TIMEOUT_S = 60


def _compose_command() -> list[str] | None:
    candidates = []
    if shutil.which("docker"):
        candidates.append(["docker", "compose"])
    if shutil.which("docker-compose"):
        candidates.append(["docker-compose"])
    for cmd in candidates:
        try:
            probe = subprocess.run([*cmd, "version"], capture_output=True, text=True, timeout=COMPOSE_TIMEOUT_S)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if probe.returncode == 0:
            return cmd
    return None


def _legacy_v1() -> bool:
    out = subprocess.run(["docker-compose", "version", "--short"], capture_output=True, text=True,
                         timeout=COMPOSE_TIMEOUT_S).stdout.strip()
    return out.startswith("1.")


def _clean_env() -> dict[str, str]:
    """The caller's environment without overrides of the file's variables."""
    return {k: v for k, v in os.environ.items() if not k.startswith(("REGRASP_", "POSTGRES_", "RAY_", "COMPOSE_"))}


def _compose(*args: str) -> subprocess.CompletedProcess:
    cmd = _compose_command()
    if cmd is None:
        pytest.skip("neither the docker compose plugin nor docker-compose is installed; "
                    "install one to validate docker/compose.yaml (no Docker engine is needed)")
    return subprocess.run([*cmd, "-p", "regrasp", "-f", str(COMPOSE), *args], capture_output=True, text=True,
                          timeout=COMPOSE_TIMEOUT_S, cwd=DOCKER_DIR, env=_clean_env())


@pytest.fixture(scope="module")
def compose_doc() -> dict:
    return yaml.safe_load(COMPOSE.read_text())


def test_compose_config_is_valid():
    result = _compose("config", "-q")
    assert result.returncode == 0, result.stderr


def test_compose_services_per_profile():
    default = _compose("config", "--services")
    assert default.returncode == 0, default.stderr
    if _compose_command() == ["docker-compose"] and _legacy_v1():
        # Compose v1 lists profiled services too; v2 (the plugin) leaves them out.
        assert CORE_SERVICES <= set(default.stdout.split())
    else:
        assert set(default.stdout.split()) == CORE_SERVICES
    ray = _compose("--profile", "ray", "config", "--services")
    assert ray.returncode == 0, ray.stderr
    assert set(ray.stdout.split()) == CORE_SERVICES | RAY_SERVICES


def test_compose_structure(compose_doc):
    services = compose_doc["services"]
    assert CORE_SERVICES | RAY_SERVICES == set(services)
    assert services["api"]["command"][0] == "serve"
    assert services["worker"]["command"][0] == "worker"
    assert services["controller"]["command"][0] == "controller-sim"
    for name in RAY_SERVICES:
        assert services[name]["profiles"] == ["ray"]
    for name in CORE_SERVICES:
        assert "profiles" not in services[name]
    assert "healthz" in " ".join(services["api"]["healthcheck"]["test"])
    assert services["api"]["depends_on"]["postgres"]["condition"] == "service_healthy"
    # the API is published on loopback only by default
    assert all(str(p).startswith("127.0.0.1:") for p in services["api"]["ports"])
    # tokens come from a secret file, never inline
    assert "REGRASP_TOKENS" not in services["api"].get("environment", {})
    json.loads((DOCKER_DIR / "tokens.example.json").read_text())


def test_dockerfile_is_multistage_non_root_with_healthcheck():
    text = DOCKERFILE.read_text()
    stages = re.findall(r"^FROM\s+\S+(?:\s+AS\s+(\w+))?", text, flags=re.MULTILINE | re.IGNORECASE)
    assert len(stages) >= 2 and "runtime" in stages
    runtime = text[text.index("AS runtime"):]
    user = re.findall(r"^USER\s+(\S+)", runtime, flags=re.MULTILINE)
    assert user and not user[-1].startswith(("root", "0"))
    assert re.search(r"^HEALTHCHECK .*", runtime, flags=re.MULTILINE)
    assert "/healthz" in runtime
    assert "COPY --from=build" in runtime
    assert (DOCKER_DIR / "Dockerfile.dockerignore").is_file()


def test_dockerfile_copies_every_package_the_wheel_includes():
    """The image builds its wheel from what the build stage copies: every package of pyproject's
    `packages.find` must be copied (robot_data included, or the image has no robot models)."""
    import tomllib

    include = tomllib.loads((DOCKER_DIR.parent / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    packages = {name.rstrip("*") for name in include}
    copied = set(re.findall(r"^COPY (\w+) \./\1$", DOCKERFILE.read_text(), flags=re.MULTILINE))
    assert packages <= copied, f"not copied into the build stage: {sorted(packages - copied)}"
