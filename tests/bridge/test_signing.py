"""The commands' Ed25519 signatures and the key files (``robot_bridge.signing``, ``regrasp keys generate``)."""

from __future__ import annotations

import json
import os
import stat

import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_bridge.dispatcher import SignedSegment, split_segments
from robot_bridge.signing import (
    KeyFileError,
    Signer,
    Verifier,
    canonical_bytes,
    generate_keys,
    load_private_key,
    load_public_key,
    open_signed,
)

from .plans import build_plan


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    private, public = generate_keys(tmp_path_factory.mktemp("pair"))
    return Signer.from_file(private), Verifier.from_file(public)


def test_keys_generate_writes_a_private_key_only_its_owner_reads_and_refuses_to_overwrite(tmp_path):
    from service.cli.main import cli

    runner = CliRunner()
    out = runner.invoke(cli, ["keys", "generate", str(tmp_path / "k")])
    assert out.exit_code == 0, out.output
    paths = json.loads(out.output)
    private, public = paths["private_key"], paths["public_key"]
    assert private.endswith("dispatcher.key") and public.endswith("dispatcher.pub")
    assert stat.S_IMODE(os.stat(private).st_mode) == 0o600
    assert open(private).read().startswith("-----BEGIN PRIVATE KEY-----")  # PKCS#8
    assert open(public).read().startswith("-----BEGIN PUBLIC KEY-----")  # SubjectPublicKeyInfo
    load_private_key(private), load_public_key(public)
    again = runner.invoke(cli, ["keys", "generate", str(tmp_path / "k")])
    assert again.exit_code != 0 and "already exist" in again.output
    assert runner.invoke(cli, ["keys", "generate", str(tmp_path / "k"), "--force"]).exit_code == 0


def test_key_files_of_the_wrong_kind_are_named(tmp_path, pair):
    private, public = generate_keys(tmp_path)
    with pytest.raises(KeyFileError, match="not an unencrypted PEM private key"):
        load_private_key(public)
    with pytest.raises(KeyFileError, match="cannot read"):
        load_public_key(tmp_path / "missing.pub")


def test_the_signature_covers_the_canonical_form_without_sig(pair):
    signer, verifier = pair
    msg = {"job_id": "j", "seq": 3, "t": 1.5, "expires_at": 2.0}
    signed = signer.sign(msg)
    assert verifier.problem(signed) is None
    # key order and whitespace on the wire do not matter; the canonical form does
    reordered = json.loads(json.dumps(dict(reversed(list(signed.items()))), indent=2))
    assert verifier.problem(reordered) is None
    assert canonical_bytes(signed) == canonical_bytes(msg) == b'{"expires_at":2.0,"job_id":"j","seq":3,"t":1.5}'
    assert "unsigned" in verifier.problem(msg)
    assert "not valid base64" in verifier.problem({**msg, "sig": "%%%"})
    assert "does not verify" in verifier.problem({**signed, "seq": 4})


@settings(max_examples=40, deadline=None)
@given(position=st.integers(min_value=0), flip=st.integers(min_value=1, max_value=255))
def test_any_changed_byte_of_a_signed_segment_is_refused(pair, position, flip):
    signer, verifier = pair
    plan = _plan()
    seg = split_segments(plan, "job", "0" * 64, 7, 0.25)[1]
    wire = bytearray(SignedSegment(seg).wire(signer, 1e9))
    original, problem = open_signed(bytes(wire), verifier)
    assert problem is None and original["seq"] == 8 and original["points"] == seg.points
    i = position % len(wire)
    wire[i] = (wire[i] + flip) % 256
    msg, problem = open_signed(bytes(wire), verifier)
    # Refused, or (a change JSON reads the same, such as 1e-05 -> 1E-05) exactly the signed message.
    assert problem is not None or {k: v for k, v in msg.items() if k != "sig"} == original


_PLAN: list[dict] = []


def _plan() -> dict:
    if not _PLAN:
        _PLAN.append(build_plan({"RSP": -0.2}, duration_s=0.5))
    return _PLAN[0]


def test_a_segment_is_signed_as_its_canonical_form_with_its_expiry(pair):
    signer, verifier = pair
    seg = split_segments(_plan(), "job", "0" * 64, 1, 0.25)[0]
    wire = SignedSegment(seg).wire(signer, 1234.5)
    doc = json.loads(wire)
    assert doc["expires_at"] == 1234.5 and verifier.problem(doc) is None
    body = seg.model_dump(mode="json", exclude={"sig"}) | {"expires_at": 1234.5}
    assert canonical_bytes(doc) == canonical_bytes(body)
