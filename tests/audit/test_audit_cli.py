"""``regrasp audit verify|show`` exit codes and output."""

from __future__ import annotations

import subprocess
import sys

from click.testing import CliRunner

from service.cli.main import cli

from .conftest import write_sample


def _run(*args: str):
    return CliRunner().invoke(cli, ["audit", *args])


def test_verify_exit_codes(tmp_path, hrp5p_urdf):
    done = tmp_path / "done.mcap"
    heads = write_sample(done, hrp5p_urdf)
    ok = _run("verify", str(done), "--head", heads[-1])
    assert ok.exit_code == 0, ok.output
    assert "INTACT" in ok.output

    wrong = _run("verify", str(done), "--head", heads[-3])
    assert wrong.exit_code == 1 and "BROKEN" in wrong.output and "where" in wrong.output

    open_file = tmp_path / "open.mcap"
    write_sample(open_file, hrp5p_urdf, close=False)
    unfinished = _run("verify", str(open_file))
    assert unfinished.exit_code == 2 and "UNFINISHED" in unfinished.output

    raw = bytearray(done.read_bytes())
    raw[len(raw) // 3] ^= 0x10
    done.write_bytes(bytes(raw))
    broken = _run("verify", str(done), "--json")
    assert broken.exit_code == 1 and '"status": "broken"' in broken.output


def test_verify_bad_arguments_are_clear(tmp_path, hrp5p_urdf):
    missing = _run("verify", str(tmp_path / "nope.mcap"))
    assert missing.exit_code == 3 and "does not exist" in missing.output  # 2 means "intact but unfinished"
    path = tmp_path / "a.mcap"
    write_sample(path, None)
    bad_head = _run("verify", str(path), "--head", "xyz")
    assert bad_head.exit_code == 3 and "64 hex digits" in bad_head.output


def test_show_prints_a_timeline(tmp_path, hrp5p_urdf):
    path = tmp_path / "a.mcap"
    write_sample(path, hrp5p_urdf)
    out = _run("show", str(path))
    assert out.exit_code == 0, out.output
    assert "state -> queued" in out.output and "actor: alice" in out.output
    assert "state queued -> planning" in out.output
    assert "robot description" in out.output
    assert "/plan/joint_states" in out.output and "INTACT" in out.output


def test_console_script_runs(tmp_path):
    path = tmp_path / "a.mcap"
    heads = write_sample(path, None)
    proc = subprocess.run(
        [sys.executable, "-m", "service.cli.main", "audit", "verify", str(path), "--head", heads[-1]],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_verify_calls_a_complete_file_with_a_damaged_length_field_broken(tmp_path, hrp5p_urdf):
    """A flipped bit in the first chunk's length field: exit 1 (broken), never 2 (unfinished)."""
    import struct

    path = tmp_path / "job.mcap"
    write_sample(path, hrp5p_urdf, compression="zstd")
    raw = bytearray(path.read_bytes())
    pos = 8
    while raw[pos] != 0x06:  # the first chunk record
        pos += 9 + struct.unpack_from("<Q", raw, pos + 1)[0]
    raw[pos + 1 + 4] ^= 0x01  # bit 32 of its length: it now runs past the end of the file
    path.write_bytes(bytes(raw))
    out = _run("verify", str(path))
    assert out.exit_code == 1 and "BROKEN" in out.output and "length" in out.output, out.output


def test_layout_prints_the_shipped_foxglove_layout(tmp_path):
    import json

    out = _run("layout")
    assert out.exit_code == 0
    layout = json.loads(out.output)
    assert "3D!robot" in layout["configById"] and layout["layout"]["first"] == "3D!robot"
    target = tmp_path / "layout.json"
    written = _run("layout", "--out", str(target))
    assert written.exit_code == 0 and json.loads(target.read_text()) == layout


def test_show_speaks_words_and_counts_from_the_earliest_event(tmp_path):
    """No Python dicts in the timeline, and no negative offsets when an event's time precedes the first record's."""
    from service.audit import AuditSettings, AuditWriter

    path = tmp_path / "words.mcap"
    w = AuditWriter(path, "job-7", robot_name="hrp5p", settings=AuditSettings(compression="none"),
                    clock_ns=lambda: 1_700_000_000_000_000_000)
    w.record("progress", {"message": "left-left: search iteration 3", "failures": {"collision": 1, "ik": 2}})
    w.record("approval", {"approved_by": "bob", "plan_sha256": "ab" * 32}, log_time_ns=1_699_999_999_895_000_000)
    w.record("plan", {"status": "solved", "hands": "left-left", "min_margin_m": 0.0634})
    w.close()
    out = _run("show", str(path))
    assert out.exit_code == 0, out.output
    events = [line for line in out.output.splitlines() if line.startswith("20")]
    assert events and not any("{" in line or "'" in line for line in events), out.output
    assert "+ -" not in out.output and "+-" not in out.output and "s  #" in out.output
    assert "failures (collision 1, ik 2)" in out.output
    assert "plan solved, hands left-left, min margin 63.4 mm" in out.output
    approval = next(line for line in events if "approval" in line)
    assert "+    0.000s" in approval  # the earliest event is offset 0; the rest count from it
