"""Chain verification, tamper detection and --head checks on real MCAP files."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from service.audit import AuditError, AuditWriter, ExitCode, verify
from service.audit.verify import MAGIC

from .conftest import write_sample


@pytest.fixture()
def sample(tmp_path: Path, hrp5p_urdf: str) -> tuple[Path, list[str]]:
    path = tmp_path / "job.mcap"
    heads = write_sample(path, hrp5p_urdf)
    return path, heads


def _message_spans(path: Path) -> list[tuple[int, int, int]]:
    """(record index, start, end) byte spans of each message's data in an uncompressed file."""
    data = path.read_bytes()
    spans = []
    with open(path, "rb") as f:
        for _schema, _channel, msg in make_reader(f).iter_messages(log_time_order=False):
            start = data.find(msg.data)
            assert start > 0
            spans.append((msg.sequence, start, start + len(msg.data)))
    return spans


def test_intact_file_verifies_and_head_matches(sample):
    path, heads = sample
    result = verify(path, heads[-1])
    assert result.exit_code == ExitCode.INTACT, result.detail
    assert result.finished and result.head == heads[-1]
    assert result.job_id == "job-42"
    # Every helper returned the head after its records; they are all distinct.
    assert len(set(heads)) == len(heads)


def test_file_reads_with_the_standard_mcap_reader(sample):
    path, _ = sample
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.name for s in summary.schemas.values()}
        topics = {c.topic for c in summary.channels.values()}
        encodings = {c.message_encoding for c in summary.channels.values()}
        for _s, _c, msg in reader.iter_messages():
            json.loads(msg.data)
    assert {"foxglove.Log", "foxglove.SceneUpdate", "foxglove.FrameTransforms", "foxglove.JointStates",
            "std_msgs/String"} <= schemas
    assert {"/robot_description", "/plan/tf", "/robot/tf", "/plan/joint_states", "/robot/joint_states",
            "/plan/markers/com", "/plan/markers/support", "/log", "/audit/events"} <= topics
    assert encodings == {"json"}


def test_head_mismatch_is_broken(sample):
    path, heads = sample
    result = verify(path, heads[-3])
    assert result.exit_code == ExitCode.BROKEN
    assert "not at the stored head" in result.detail
    assert verify(path, "ab" * 32).exit_code == ExitCode.BROKEN


def test_head_stored_before_close_is_accepted(sample):
    """close() only seals the file; the head of the last event names the same history."""
    path, heads = sample
    assert verify(path, heads[-2]).exit_code == ExitCode.INTACT


def test_bad_head_argument_is_a_clear_error(sample):
    path, _ = sample
    with pytest.raises(ValueError, match="64 hex digits"):
        verify(path, "not-a-sha")


def test_one_byte_changed_in_a_payload_is_found_with_where(sample):
    path, _ = sample
    spans = _message_spans(path)
    index, start, end = spans[len(spans) // 2]
    data = bytearray(path.read_bytes())
    data[(start + end) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    result = verify(path)
    assert result.exit_code == ExitCode.BROKEN
    assert result.where is not None and result.where.record_index == index
    assert result.where.offset is not None and result.where.log_time_ns is not None
    assert result.where.channel is not None
    assert "CRC" in result.detail


def _recompute_chunk_crcs(data: bytearray) -> None:
    """Fix every chunk CRC (an attacker who knows MCAP); leaves the chain as is."""
    pos = len(MAGIC)
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x06:  # chunk: start, end, uncompressed size, crc, compression, records
            body = pos + 9
            comp_len = struct.unpack_from("<I", data, body + 28)[0]
            rec_len_at = body + 32 + comp_len
            rec_len = struct.unpack_from("<Q", data, rec_len_at)[0]
            records = bytes(data[rec_len_at + 8 : rec_len_at + 8 + rec_len])
            struct.pack_into("<I", data, body + 24, zlib.crc32(records))
        if opcode == 0x0F:  # data end: disable the data-section CRC, as an editor would
            struct.pack_into("<I", data, pos + 9, 0)
        if opcode == 0x02:  # footer: disable the summary CRC too
            struct.pack_into("<I", data, pos + 9 + 16, 0)
            break
        pos += 9 + length


def test_edit_with_recomputed_crcs_is_caught_by_the_chain(sample):
    path, _ = sample
    spans = _message_spans(path)
    index, start, end = spans[3]
    data = bytearray(path.read_bytes())
    segment = bytes(data[start:end])
    # Change a digit in the JSON (keeps it valid JSON) as a forger would.
    digit = next(i for i, b in enumerate(segment) if chr(b).isdigit() and i > 2)
    data[start + digit] = ord("7") if segment[digit] != ord("7") else ord("3")
    _recompute_chunk_crcs(data)
    path.write_bytes(bytes(data))
    result = verify(path)
    assert result.exit_code == ExitCode.BROKEN
    # Record i's digest changes, so record i+1 no longer names it.
    assert result.where.record_index in (index, index + 1)
    assert "edited" in result.detail


def test_records_removed_and_refinished_file_is_broken(tmp_path, hrp5p_urdf):
    """A forger who rewrites a shorter file with valid CRCs lacks the closing record or the head."""
    full = tmp_path / "full.mcap"
    heads = write_sample(full, hrp5p_urdf)
    short = tmp_path / "short.mcap"
    write_sample(short, hrp5p_urdf, close=False)
    # unfinished: chain intact but does not end at the stored head
    assert verify(short).exit_code == ExitCode.UNFINISHED
    assert verify(short, heads[-1]).exit_code == ExitCode.BROKEN


def test_garbage_and_non_mcap_files(tmp_path):
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"hello world, not mcap")
    assert verify(bad).exit_code == ExitCode.BROKEN
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert verify(empty).exit_code == ExitCode.UNFINISHED


def test_writer_refuses_bad_input(tmp_path):
    w = AuditWriter(tmp_path / "a.mcap", "j", robot_name=None, urdf_text=None)
    with pytest.raises(AuditError, match="non-finite"):
        w.record("plan", {"x": float("nan")})
    with pytest.raises(AuditError, match="joint names"):
        w.joint_state(["a", "b"], [0.0])
    with pytest.raises(AuditError, match="at least 3"):
        w.support_markers([[0, 0], [1, 0]])
    w.close()
    with pytest.raises(AuditError, match="closed"):
        w.record("x", {})
    with pytest.raises(FileExistsError):
        AuditWriter(tmp_path / "a.mcap", "j", robot_name=None, urdf_text=None)
    with pytest.raises(ValueError, match="XML"):
        AuditWriter(tmp_path / "b.mcap", "j", robot_name=None, urdf_text="<robot")


def test_failed_record_does_not_break_the_chain(tmp_path):
    path = tmp_path / "a.mcap"
    w = AuditWriter(path, "j", robot_name=None, urdf_text=None)
    with pytest.raises(AuditError):
        w.record("plan", {"x": float("inf")})
    head = w.close()
    assert verify(path, head).exit_code == ExitCode.INTACT


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_single_byte_flip_in_the_file_is_detected(tmp_path_factory, hrp5p_urdf, data):
    """Property: flipping any one byte of a finished file never verifies as intact."""
    path = tmp_path_factory.mktemp("flip") / "job.mcap"
    heads = write_sample(path, hrp5p_urdf)
    raw = bytearray(path.read_bytes())
    offset = data.draw(st.integers(min_value=0, max_value=len(raw) - 1))
    bit = data.draw(st.integers(min_value=0, max_value=7))
    raw[offset] ^= 1 << bit
    path.write_bytes(bytes(raw))
    assert verify(path, heads[-1]).exit_code == ExitCode.BROKEN
    # Even without the stored head, a flip never passes as intact.
    assert verify(path).exit_code != ExitCode.INTACT


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.floats(min_value=0.05, max_value=0.999))
def test_any_truncation_is_unfinished_or_broken_never_intact(tmp_path_factory, cut):
    path = tmp_path_factory.mktemp("cut") / "job.mcap"
    heads = write_sample(path, None)
    raw = path.read_bytes()
    path.write_bytes(raw[: int(len(raw) * cut)])
    result = verify(path)
    assert result.exit_code in (ExitCode.UNFINISHED, ExitCode.BROKEN)
    if result.exit_code == ExitCode.UNFINISHED and result.records:
        assert result.head in heads or result.records >= 1


def test_edit_of_the_last_record_is_found_by_its_crc(sample):
    path, _ = sample
    spans = _message_spans(path)
    index, start, end = max(spans)
    data = bytearray(path.read_bytes())
    data[start + 5] ^= 0x02
    path.write_bytes(bytes(data))
    result = verify(path)
    assert result.exit_code == ExitCode.BROKEN
    assert result.where.record_index == index and "CRC" in result.detail


def test_zstd_compressed_file_verifies_and_detects_a_flip(tmp_path):
    from service.audit import AuditSettings

    path = tmp_path / "z.mcap"
    w = AuditWriter(path, "jz", settings=AuditSettings(compression="zstd"))
    for i in range(20):
        w.record("progress", {"i": i, "text": "x" * 200})
    head = w.close()
    assert verify(path, head).exit_code == ExitCode.INTACT
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0x04
    path.write_bytes(bytes(raw))
    assert verify(path, head).exit_code == ExitCode.BROKEN
