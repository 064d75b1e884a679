"""The robot-model routes the 3D view loads: a URDF by robot name, its meshes by index, never a path."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
import trimesh

from service.api import catalogue
from service.api.catalogue import RobotModelFiles

from .conftest import serve

TOKEN = "robot-model-token"


def _urdf(tmp_path: Path) -> Path:
    meshes = tmp_path / "meshes"
    meshes.mkdir(parents=True)
    trimesh.creation.box((0.1, 0.2, 0.3)).export(meshes / "torso.stl")
    trimesh.creation.box((0.1, 0.1, 0.1)).export(meshes / "head.obj")
    (tmp_path / "arm.stl").write_bytes((meshes / "torso.stl").read_bytes())
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(f"""<robot name="meshbot">
  <link name="base"><visual><geometry><mesh filename="meshes/torso.stl"/></geometry></visual>
    <collision><geometry><mesh filename="meshes/torso.stl"/></geometry></collision></link>
  <link name="arm"><visual><geometry><mesh filename="file://{tmp_path / 'arm.stl'}"/></geometry></visual></link>
  <link name="head"><visual><geometry><mesh filename="meshes/head.obj"/></geometry></visual></link>
  <link name="hand"><visual><geometry><mesh filename="package://somewhere/hand.stl"/></geometry></visual></link>
  <link name="foot"><visual><geometry><box size="0.2 0.1 0.05"/></geometry></visual></link>
  <joint name="j" type="fixed"><parent link="base"/><child link="arm"/></joint>
</robot>""")
    return urdf


def test_mesh_references_become_routes_and_the_rest_is_left_out(tmp_path):
    files = RobotModelFiles("meshbot", _urdf(tmp_path))
    assert [p.name for p in files.meshes] == ["torso.stl", "arm.stl"]
    assert 'filename="/v1/robots/meshbot/meshes/0.stl"' in files.urdf_text
    assert 'filename="/v1/robots/meshbot/meshes/1.stl"' in files.urdf_text
    assert str(tmp_path) not in files.urdf_text and "package://" not in files.urdf_text and "head.obj" not in files.urdf_text
    assert sorted(files.dropped) == ["hand", "head"]
    assert "<box" in files.urdf_text  # primitives stay


@pytest.fixture()
def server(tmp_path, monkeypatch):
    from service.app import create_app
    from service.execution.bridge import NoBridge
    from service.settings import ServiceSettings

    built = RobotModelFiles("meshbot", _urdf(tmp_path / "robot"))
    real = catalogue.robot_model_files

    def lookup(name: str) -> RobotModelFiles:
        return built if name == "meshbot" else real(name)

    monkeypatch.setattr(catalogue, "robot_model_files", lookup)
    settings = ServiceSettings(data_dir=tmp_path / "data", workers=1, tokens={TOKEN: {"user": "v", "roles": []}},
                               preload_robot=False)
    with serve(create_app(settings, run_workers=False, bridge=NoBridge())) as url:
        yield url, built


def test_the_routes_serve_the_urdf_and_its_meshes_by_name_and_index(server, tmp_path):
    url, built = server
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=10) as c:
        r = c.get("/v1/robots/meshbot/urdf")
        assert r.status_code == 200 and r.text == built.urdf_text
        mesh = c.get("/v1/robots/meshbot/meshes/1.stl")
        assert mesh.status_code == 200 and mesh.content == built.meshes[1].read_bytes()
        assert mesh.headers["content-type"] == "model/stl"
        assert c.get("/v1/robots/meshbot/meshes/2.stl").status_code == 404
        for bad in ("/v1/robots/meshbot/meshes/..%2F..%2Fetc%2Fpasswd", "/v1/robots/meshbot/meshes/0.stl%00"):
            assert c.get(bad).status_code in (404, 422)
        assert c.get("/v1/robots/hrp5p/urdf").status_code == 200  # a built-in: primitives only
        missing = c.get("/v1/robots/nobot/urdf")
        from planner.robot.registry import robot_names

        assert missing.status_code == 404 and f"valid robots: {', '.join(robot_names())}" in missing.json()["detail"]
        assert c.get("/v1/meshes/carrier_px").text.lstrip().startswith(("v ", "#", "o ", "g "))
        assert c.get("/v1/meshes/teapot").status_code == 404
    assert httpx.get(url + "/v1/robots/hrp5p/urdf").status_code == 401  # a token is needed
