"""Certificates for the OPC UA security tests, made at test time with
`cryptography`: RSA 2048 keys, a CA, and application certificates signed by
it (or self-signed) with the URI, localhost and 127.0.0.1 as alternative names."""

from __future__ import annotations

import datetime as dt
import ipaddress
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID


def new_key() -> rsa.RSAPrivateKey:
    return rsa.generate_private_key(public_exponent=65537, key_size=2048)


def name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def make_cert(subject: str, key: rsa.RSAPrivateKey, issuer: x509.Name,
              issuer_key: rsa.RSAPrivateKey, *, days: float = 30.0, ca: bool = False,
              uri: str | None = None) -> x509.Certificate:
    now = dt.datetime.now(dt.UTC)
    builder = (x509.CertificateBuilder()
               .subject_name(name(subject)).issuer_name(issuer)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now - dt.timedelta(hours=1))
               .not_valid_after(now + dt.timedelta(days=days))
               .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
    if ca:
        builder = builder.add_extension(x509.KeyUsage(
            digital_signature=True, content_commitment=False, key_encipherment=False,
            data_encipherment=False, key_agreement=False, key_cert_sign=True, crl_sign=True,
            encipher_only=False, decipher_only=False), critical=True)
    else:
        builder = (builder
                   .add_extension(x509.KeyUsage(
                       digital_signature=True, content_commitment=True, key_encipherment=True,
                       data_encipherment=True, key_agreement=False, key_cert_sign=False,
                       crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
                   .add_extension(x509.ExtendedKeyUsage(
                       [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                       critical=False)
                   .add_extension(x509.SubjectAlternativeName([
                       x509.UniformResourceIdentifier(uri or f"urn:{subject}"),
                       x509.DNSName("localhost"),
                       x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False))
    return builder.sign(issuer_key, hashes.SHA256())


def write_cert(path: Path, cert: x509.Certificate) -> Path:
    path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    return path


def write_key(path: Path, key: rsa.RSAPrivateKey) -> Path:
    path.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                       serialization.PrivateFormat.PKCS8,
                                       serialization.NoEncryption()))
    return path


@dataclass(frozen=True)
class Pki:
    """A server's and a client's certificate and key, signed by one CA."""

    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path


def server_and_client(d: Path, *, server_uri: str, client_uri: str, days: float = 365.0,
                      client_days: float = 365.0) -> Pki:
    """A CA, a server and a client certificate (DER) with their keys (PEM) in `d`."""
    ca_key, server_key, client_key = new_key(), new_key(), new_key()
    ca = make_cert("compd test CA", ca_key, name("compd test CA"), ca_key, days=days, ca=True)
    server = make_cert("server", server_key, ca.subject, ca_key, days=days, uri=server_uri)
    client = make_cert("client", client_key, ca.subject, ca_key, days=client_days,
                       uri=client_uri)
    return Pki(write_cert(d / "server.der", server), write_key(d / "server.pem", server_key),
               write_cert(d / "client.der", client), write_key(d / "client.pem", client_key))
