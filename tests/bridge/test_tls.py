"""zenoh's mutual TLS between the bridge's peers, on loopback, with certificates made here (``cryptography``).

With ``tls_root_ca``, ``tls_cert`` and ``tls_key`` set on both peers and ``tls/`` endpoints, the
dispatcher-side peer reaches the controller-side peer; a peer whose certificate another CA signed is
not let in, and what it publishes never arrives.
"""

from __future__ import annotations

import datetime
import ipaddress
import threading
import time
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from robot_bridge.settings import BridgeSettings
from robot_bridge.zenoh_session import open_session

from .conftest import free_port

KEY = "regrasp/tlstest/cmd/stop"


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def make_ca(directory: Path, name: str):
    now = datetime.datetime.now(datetime.timezone.utc)
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder().subject_name(_name(name)).issuer_name(_name(name)).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(hours=1))
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
                                         key_encipherment=False, data_encipherment=False, key_agreement=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .sign(key, hashes.SHA256()))
    path = directory / f"{name}.pem"
    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return key, cert, path


def make_peer_cert(directory: Path, name: str, ca_key, ca_cert) -> tuple[Path, Path]:
    """A certificate for localhost / 127.0.0.1 usable to listen and to connect (server and client auth)."""
    now = datetime.datetime.now(datetime.timezone.utc)
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder().subject_name(_name(name)).issuer_name(ca_cert.subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(hours=1))
            .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                        x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .sign(ca_key, hashes.SHA256()))
    cert_path, key_path = directory / f"{name}.pem", directory / f"{name}.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    return cert_path, key_path


@pytest.fixture
def pki(tmp_path):
    ca_key, ca_cert, ca_path = make_ca(tmp_path, "robot-ca")
    other_key, other_cert, other_path = make_ca(tmp_path, "other-ca")
    return {
        "ca": ca_path,
        "controller": make_peer_cert(tmp_path, "controller", ca_key, ca_cert),
        "dispatcher": make_peer_cert(tmp_path, "dispatcher", ca_key, ca_cert),
        "rogue": make_peer_cert(tmp_path, "rogue", other_key, other_cert),
        "other_ca": other_path,
    }


def _settings(ca: Path, cert_key: tuple[Path, Path], **endpoints) -> BridgeSettings:
    return BridgeSettings(robot_id="tlstest", tls_root_ca=ca, tls_cert=cert_key[0], tls_key=cert_key[1], **endpoints)


def _wait(cond, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return bool(cond())


def test_mutual_tls_lets_the_peers_of_one_ca_talk_and_keeps_others_out(pki):
    endpoint = f"tls/localhost:{free_port()}"
    controller = open_session(_settings(pki["ca"], pki["controller"], listen=[endpoint], connect=[]))
    got: list[bytes] = []
    lock = threading.Lock()

    def on_sample(sample) -> None:
        with lock:
            got.append(sample.payload.to_bytes())

    sub = controller.declare_subscriber(KEY, on_sample)
    dispatcher = open_session(_settings(pki["ca"], pki["dispatcher"], connect=[endpoint]))
    # A rogue with a certificate of its own CA (trusting that CA, so only the controller's check can stop it).
    rogue = open_session(_settings(pki["other_ca"], pki["rogue"], connect=[endpoint]))
    try:
        assert _wait(lambda: len(list(controller.info.peers_zid())) >= 1)
        assert str(dispatcher.info.zid()) in {str(z) for z in controller.info.peers_zid()}
        time.sleep(0.5)  # the rogue's handshake has had its chance
        assert str(rogue.info.zid()) not in {str(z) for z in controller.info.peers_zid()}
        rogue.put(KEY, b"from the rogue")
        assert _wait(lambda: (dispatcher.put(KEY, b"from the dispatcher"), b"from the dispatcher" in got)[1])
        time.sleep(0.2)
        assert b"from the rogue" not in got
    finally:
        sub.undeclare()
        rogue.close()
        dispatcher.close()
        controller.close()


def test_tls_settings_come_together():
    with pytest.raises(ValueError, match="tls_root_ca, tls_cert and tls_key together"):
        BridgeSettings(tls_root_ca=Path("ca.pem"))
