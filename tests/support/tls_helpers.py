"""Test PKI: CA and leaf certificates (ECDSA P-256) made on the fly for the zenoh TLS tests."""
from __future__ import annotations

import datetime
import ipaddress
import os
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes
from cryptography.x509.oid import NameOID

__all__ = ["make_cert", "make_pki", "write_private"]


def _name(cn: str):
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def make_cert(subject_cn: str, key, issuer_cn: str, issuer_key, *, ca: bool):
    """A certificate for ``subject_cn`` signed by ``issuer_key``; leaves valid for localhost/127.0.0.1."""
    now = datetime.datetime.now(datetime.timezone.utc)
    builder = (x509.CertificateBuilder().subject_name(_name(subject_cn)).issuer_name(_name(issuer_cn))
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now - datetime.timedelta(days=1))
               .not_valid_after(now + datetime.timedelta(days=2))
               .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
    if ca:
        builder = builder.add_extension(x509.KeyUsage(
            digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
            key_encipherment=False, data_encipherment=False, key_agreement=False,
            encipher_only=False, decipher_only=False), critical=True)
    else:
        builder = builder.add_extension(x509.SubjectAlternativeName(
            [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False)
    return builder.sign(issuer_key, hashes.SHA256())


def write_private(path: Path, data: bytes) -> str:
    """Write a private file (mode 600) and return its path as a string."""
    path.write_bytes(data)
    os.chmod(path, 0o600)
    return str(path)


def make_pki(out: Path, leaves) -> dict:
    """Two CAs (``ca``, ``other_ca``) and leaf certificates in ``out``.

    Parameters
    ----------
    out : Path
        Directory to write ``<name>.pem`` (and ``<leaf>.key``, mode 600) into.
    leaves : iterable of (stem, common_name, ca_name)

    Returns
    -------
    dict
        ``files[ca_name]`` = CA certificate path; ``files[stem]`` = ``(cert_path, key_path)``;
        ``files["dir"]`` = ``out``.
    """
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    pem = serialization.Encoding.PEM
    files: dict = {"dir": out}
    cas = {}
    for ca_name in ("ca", "other_ca"):
        key = ec.generate_private_key(ec.SECP256R1())
        cas[ca_name] = key
        (out / f"{ca_name}.pem").write_bytes(make_cert(ca_name, key, ca_name, key, ca=True).public_bytes(pem))
        files[ca_name] = str(out / f"{ca_name}.pem")
    for stem, cn, ca_name in leaves:
        key = ec.generate_private_key(ec.SECP256R1())
        (out / f"{stem}.pem").write_bytes(make_cert(cn, key, ca_name, cas[ca_name], ca=False).public_bytes(pem))
        files[stem] = (str(out / f"{stem}.pem"), write_private(out / f"{stem}.key", key.private_bytes(
            pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())))
    return files
