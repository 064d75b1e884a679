"""Bad input at the command line: exit 2, one line saying what is wrong, no traceback, no pydantic text.

Each case runs the installed entry point's code (``service.cli.main.main``) in a child process from
this checkout, as a user would meet it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RUN = "import sys; from service.cli.main import main; sys.exit(main())"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bad-input")
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(d / "key.pem"),
                    "-out", str(d / "cert.pem"), "-days", "1", "-subj", "/CN=localhost"],
                   check=True, capture_output=True)
    (d / "schema-only.json").write_text('{"schema": "regrasp.plan/1"}\n')
    (d / "not-json.json").write_text("plan: no\n")
    (d / "list.json").write_text("[1, 2]\n")
    (d / "scenario.yaml").write_text("schema: regrasp.scenario/1\nname: x\nthreshold_m: .nan\n")
    return d


CASES = {
    "controller-sim --speed -1": ["controller-sim", "--speed", "-1"],
    "controller-sim unknown robot": ["controller-sim", "--robot", "no-such-robot"],
    "serve --port 99999": ["serve", "--port", "99999", "--data-dir", "{d}/var"],
    "serve --workers -1": ["serve", "--workers", "-1", "--data-dir", "{d}/var"],
    "serve certificate without key": ["serve", "--tls-cert", "{d}/cert.pem", "--data-dir", "{d}/var"],
    "serve key without certificate": ["serve", "--tls-key", "{d}/key.pem", "--data-dir", "{d}/var"],
    "serve --tls-key given a certificate": ["serve", "--tls-cert", "{d}/cert.pem", "--tls-key", "{d}/cert.pem",
                                            "--port", "0", "--data-dir", "{d}/var"],
    "gate check, a schema line only": ["gate", "check", "{d}/schema-only.json"],
    "gate check, not JSON": ["gate", "check", "{d}/not-json.json"],
    "gate check, a list": ["gate", "check", "{d}/list.json"],
    "gate check, no file": ["gate", "check", "{d}/missing.json"],
    "robot info, unknown robot": ["robot", "info", "no-such-robot"],
    "scenario show, unknown name": ["scenario", "show", "no-such-scenario"],
    "scenario check, NaN threshold": ["scenario", "check", "{d}/scenario.yaml"],
    "plan, unknown scenario": ["plan", "--scenario", "no-such-scenario", "--out", "{d}/p.json"],
    "plan, negative threshold": ["plan", "--scenario", "upright", "--threshold-mm", "-5", "--out", "{d}/p.json"],
    "audit show, unknown flag": ["audit", "show", "--no-such-flag"],
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_exits_2_with_one_line(case: str, files: Path) -> None:
    args = [a.replace("{d}", str(files)) for a in CASES[case]]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "80"}
    res = subprocess.run([sys.executable, "-c", RUN, *args], cwd=files, env=env, capture_output=True, text=True,
                         timeout=120)
    out = (res.stdout + res.stderr).strip()
    assert res.returncode == 2, f"{case}: exit {res.returncode}\n{out}"
    lines = [line for line in out.splitlines() if line.strip()]
    assert len(lines) == 1, f"{case}: {len(lines)} lines\n{out}"
    assert "Traceback" not in out and "pydantic" not in out and "For further information" not in out, out
    assert len(lines[0]) > len("error: ") + 10, out


@pytest.mark.parametrize("content", ["margin_floor_m: 0.03\n", "schema: regrasp.policy/1\nmargin_floor_m: -1\n", None])
def test_worker_with_a_bad_policy_file_exits_2_with_one_line(content: str | None, files: Path) -> None:
    """``REGRASP_POLICY`` naming a file without its schema, with a bad value, or no file at all."""
    policy = files / f"policy-{abs(hash(content))}.yaml"
    if content is not None:
        policy.write_text(content)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "80", "REGRASP_POLICY": str(policy)}
    res = subprocess.run([sys.executable, "-c", RUN, "worker", "--data-dir", str(files / "worker-var")], cwd=files,
                         env=env, capture_output=True, text=True, timeout=120)
    out = (res.stdout + res.stderr).strip()
    assert res.returncode == 2, f"exit {res.returncode}\n{out}"
    lines = [line for line in out.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in out and "policy" in lines[0], out
