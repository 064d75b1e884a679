"""`regrasp serve` over TLS: certificate and key from the settings, a self-signed pair made here."""

from __future__ import annotations

import datetime as dt
import ipaddress
import ssl
from pathlib import Path
from typing import Iterator

import httpx
import pytest
from conftest import Server
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID


def self_signed(directory: Path) -> tuple[Path, Path]:
    """A P-256 key and a one-day certificate for 127.0.0.1 (PEM files)."""
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "regrasp test")])
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .sign(key, hashes.SHA256()))
    cert_path, key_path = directory / "cert.pem", directory / "key.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    key_path.chmod(0o600)
    return cert_path, key_path


@pytest.fixture(scope="module")
def tls_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    data_dir = tmp_path_factory.mktemp("tls")
    cert, key = self_signed(data_dir)
    srv = Server(data_dir, workers=0, tls_ca=cert, tls_cert_file=str(cert), tls_key_file=str(key)).start()
    try:
        yield srv
    finally:
        srv.stop()


def test_the_api_speaks_https_with_the_configured_certificate(tls_server: Server) -> None:
    assert tls_server.url.startswith("https://127.0.0.1:")
    with tls_server.client("alice") as c:
        assert c.get("/v1/me").json()["user"] == "alice"
        r = c.post("/v1/jobs", json={"kind": "plan", "request": {"scenario": "quick"}})
        assert r.status_code == 202, r.text
    pem = ssl.get_server_certificate(("127.0.0.1", tls_server.port))
    assert x509.load_pem_x509_certificate(pem.encode()).subject.rfc4514_string() == "CN=regrasp test"


def test_plain_http_and_unverified_peers_get_nothing(tls_server: Server) -> None:
    with pytest.raises(httpx.HTTPError):
        httpx.get(f"http://127.0.0.1:{tls_server.port}/healthz", timeout=5)
    with pytest.raises(httpx.HTTPError):  # the system's CAs do not know this certificate
        httpx.get(tls_server.url + "/healthz", timeout=5)


def test_a_certificate_without_its_key_is_refused_at_start(tmp_path: Path) -> None:
    cert, _ = self_signed(tmp_path)
    srv = Server(tmp_path, workers=0, tls_cert_file=str(cert))
    with pytest.raises(RuntimeError, match="tls_cert_file and tls_key_file"):
        srv.start()
    srv.stop()
