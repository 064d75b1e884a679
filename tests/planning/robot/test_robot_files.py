"""Bad robot files get one clear line naming the link or joint (exit 2); massless links, point masses and mimic
joints are fine, and a joint beyond a hand is that hand's, whatever limits it has."""

from __future__ import annotations

import re

import pytest
from click.testing import CliRunner

from planner.robot.spec_file import derive
from service.cli.main import cli

from .small_humanoid import write_small_humanoid


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("REGRASP_CACHE_DIR", str(tmp_path / "cache"))


def _edit_urdf(spec_path, edit) -> None:
    urdf = spec_path.parent / "small_humanoid.urdf"
    urdf.write_text(edit(urdf.read_text()))


def _set_mass(link: str, value: str):
    return lambda text: re.sub(rf'(<link name="{link}"><inertial><origin [^>]*/><mass value=")[^"]*(")',
                               rf"\g<1>{value}\g<2>", text)


def _check(spec_path):
    return CliRunner().invoke(cli, ["robot", "check", str(spec_path), "--quiet"])


@pytest.mark.parametrize("value", ["nan", "-1.5", "1e400", "inf"])
def test_a_bad_mass_exits_2_naming_the_link(tmp_path, value):
    spec_path = write_small_humanoid(tmp_path / "robot")
    _edit_urdf(spec_path, _set_mass("l_arm3", value))
    res = _check(spec_path)
    assert res.exit_code == 2, res.output
    assert "link 'l_arm3' has mass" in res.output and "finite and >= 0" in res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1, res.output


def test_an_inertia_that_is_not_positive_definite_exits_2_naming_the_link(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot")
    # a negative principal moment on the chest (14 kg)
    _edit_urdf(spec_path, lambda t: re.sub(r'(<link name="chest">.*?<inertia ixx=")[^"]*', r"\g<1>-0.5", t, count=1))
    res = _check(spec_path)
    assert res.exit_code == 2 and "link 'chest' has mass 14 kg but its inertia is not positive definite" in res.output, \
        res.output


def _with_mesh(text: str, link: str, filename: str) -> str:
    """The URDF with ``link``'s collision box replaced by a mesh file."""
    return re.sub(rf'(<link name="{link}">.*?<geometry>)<box [^>]*/>', rf'\g<1><mesh filename="{filename}"/>', text,
                  count=1, flags=re.S)


def test_a_bogus_stl_exits_2_naming_the_link_and_the_mesh(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot")
    # a binary STL whose header claims 2^31 triangles, with none in the file
    (spec_path.parent / "forearm.stl").write_bytes(b"\0" * 80 + (2 ** 31).to_bytes(4, "little"))
    _edit_urdf(spec_path, lambda t: _with_mesh(t, "l_arm4", "forearm.stl"))
    res = _check(spec_path)
    assert res.exit_code == 2, res.output
    assert "link 'l_arm4' mesh 'forearm.stl'" in res.output and "claims 2147483648 triangles" in res.output, res.output


def test_a_readable_stl_is_fitted(tmp_path):
    """The same link with a true binary STL (one triangle) passes: the check refuses only what cannot be read."""
    import numpy as np

    spec_path = write_small_humanoid(tmp_path / "robot")
    tri = np.zeros(12, dtype="<f4")
    tri[3:] = [0, 0, 0, 0.05, 0, 0, 0, 0.05, -0.2]
    (spec_path.parent / "forearm.stl").write_bytes(b"\0" * 80 + (1).to_bytes(4, "little") + tri.tobytes() + b"\0\0")
    _edit_urdf(spec_path, lambda t: _with_mesh(t, "l_arm4", "forearm.stl"))
    assert any("1 boxes fitted" in n for n in derive(spec_path).notes)


def test_massless_links_point_masses_and_mimic_joints_are_accepted(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot")
    extra = ('<link name="imu_frame"/>'
             '<joint name="imu_fixed" type="fixed"><parent link="chest"/><child link="imu_frame"/></joint>'
             '<link name="cam_frame"><inertial><mass value="0"/><inertia ixx="0" iyy="0" izz="0" ixy="0" ixz="0" '
             'iyz="0"/></inertial></link>'
             '<joint name="cam_fixed" type="fixed"><parent link="head"/><child link="cam_frame"/></joint>'
             '<link name="cam_optical"><inertial><mass value="0.01"/><inertia ixx="0" iyy="0" izz="0" ixy="0" '
             'ixz="0" iyz="0"/></inertial></link>'
             '<joint name="cam_optical_fixed" type="fixed"><parent link="head"/><child link="cam_optical"/></joint>')
    _edit_urdf(spec_path, lambda t: t.replace("</robot>", extra + "</robot>"))
    res = _check(spec_path)
    assert res.exit_code == 0, res.output
    assert "2 massless link(s)" in res.output and "1 point mass(es)" in res.output
    d = derive(spec_path)
    assert "l_jaw_mimic" not in d.spec.neck + d.spec.hand_joints  # a mimic follows its master: no class, no limit


def _finger(side: str, effort: str) -> str:
    """A non-mimic finger joint on the hand's last link (``effort=""``: the URDF gives it none)."""
    lim = f'<limit lower="0" upper="1" velocity="1"{effort}/>'
    return (f'<link name="{side}_thumb"><inertial><mass value="0.02"/><inertia ixx="1e-6" iyy="1e-6" izz="1e-6" '
            f'ixy="0" ixz="0" iyz="0"/></inertial></link>'
            f'<joint name="{side}_thumb_joint" type="revolute"><parent link="{side}_arm6"/><child link="{side}_thumb"/>'
            f'<axis xyz="1 0 0"/>{lim}</joint>')


def test_a_finger_without_an_effort_limit_is_named_and_once_given_one_it_is_a_hand_joint(tmp_path):
    spec_path = write_small_humanoid(tmp_path / "robot")
    _edit_urdf(spec_path, lambda t: t.replace("</robot>", _finger("l", ' effort="0"') + _finger("r", "") + "</robot>"))
    res = _check(spec_path)
    assert res.exit_code == 2 and "effort_limits.l_thumb_joint: the URDF's joint 'l_thumb_joint' has no effort limit" \
        in res.output, res.output
    spec_path = write_small_humanoid(tmp_path / "robot",
                                     lambda s: s["effort_limits"].update(l_thumb_joint=0.5, r_thumb_joint=0.5))
    _edit_urdf(spec_path, lambda t: t.replace("</robot>", _finger("l", ' effort="0"') + _finger("r", "") + "</robot>"))
    d = derive(spec_path)
    assert d.spec.hand_joints == ["l_thumb_joint", "r_thumb_joint"] and d.spec.neck == ["neck_y"]
    assert "hand joints: l_thumb_joint, r_thumb_joint" in _check(spec_path).output
