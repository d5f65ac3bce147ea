"""OPC UA security for the driver: the settings with their secrets (the
rules are `drivers.opcua_policy`'s) and the connect-time checks asyncua
leaves to its caller.

asyncua's client trusts whatever certificate the server presents. Here the
server certificate is checked BEFORE anything secret is sent: the endpoints
are fetched over an unsecured discovery channel (GetEndpoints is allowed
without security), the certificate of the endpoint with our policy and mode
is compared with the pinned file or checked against a trust-store directory,
and only then is the secure channel opened with exactly that certificate
(asyncua then refuses a CreateSession answer signed with any other).

The password is a `SecretStr`: it never appears in a repr, a log line or an
exception message (validation errors are built with hidden input).
"""

from __future__ import annotations

import hashlib
import logging
from datetime import UTC, datetime
from pathlib import Path

from asyncua import ua
from asyncua.client.client import Client
from asyncua.crypto import security_policies
from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import NameOID
from pydantic import AliasChoices, Field, SecretStr

from drivers.errors import ConnectionLost
from drivers.opcua_policy import OpcUaSecurityRules, SecurityPath

_POLICY_CLASSES: dict[str, type[security_policies.SecurityPolicy]] = {
    "Basic256Sha256": security_policies.SecurityPolicyBasic256Sha256,
    "Aes128_Sha256_RsaOaep": security_policies.SecurityPolicyAes128Sha256RsaOaep,
    "Aes256_Sha256_RsaPss": security_policies.SecurityPolicyAes256Sha256RsaPss,
}


class SecurityRejected(ConnectionLost):
    """The secure connection was refused: untrusted server certificate, no
    matching endpoint, or the server rejected our identity. Retrying without a
    configuration change will not help."""


class OpcUaSecurity(OpcUaSecurityRules):
    """How the OPC UA driver secures its link: the rules of
    `drivers.opcua_policy` (the same as the daemon's ``[controller.security]``)
    with the secrets themselves. `trust_store` is accepted for `trust_dir`.
    """

    private_key_password: SecretStr | None = None
    trust_dir: SecurityPath | None = Field(
        default=None, validation_alias=AliasChoices("trust_dir", "trust_store"))
    password: SecretStr | None = None
    #: our ApplicationUri; default: the URI in the client certificate's SAN
    application_uri: str | None = None

    @property
    def has_password(self) -> bool:
        return self.password is not None

    @property
    def trust_store(self) -> Path | None:
        """The trust directory (`trust_dir`), under the driver's older name."""
        return self.trust_dir


def fingerprint(der: bytes) -> str:
    """SHA-256 fingerprint, colon-separated hex (what operators compare)."""
    digest = hashlib.sha256(der).hexdigest().upper()
    return ":".join(digest[i:i + 2] for i in range(0, len(digest), 2))


def _subject(cert: x509.Certificate) -> str:
    cns = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(cns[0].value) if cns else cert.subject.rfc4514_string()


def _first_cert(der: bytes) -> bytes:
    """The leading certificate of a DER chain (servers may send their chain)."""
    length = int.from_bytes(der[2:4], "big") + 4
    return der[:length]


def _load_cert_file(path: Path) -> x509.Certificate:
    data = path.read_bytes()
    if b"-----BEGIN" in data:
        return x509.load_pem_x509_certificate(data)
    return x509.load_der_x509_certificate(data)


def _trusted_by_store(cert: x509.Certificate, store_dir: Path) -> bool:
    """Directly trusted (same certificate in the store) or issued by a CA
    certificate in the store (one level, signature and validity checked)."""
    now = datetime.now(UTC)
    if not cert.not_valid_before_utc <= now <= cert.not_valid_after_utc:
        return False
    der = cert.public_bytes(Encoding.DER)
    for path in sorted(store_dir.iterdir()):
        if path.suffix.lower() not in {".der", ".pem", ".crt", ".cer"}:
            continue
        trusted = _load_cert_file(path)
        if trusted.public_bytes(Encoding.DER) == der:
            return True
        if trusted.subject != cert.issuer:
            continue
        try:
            basic = trusted.extensions.get_extension_for_class(x509.BasicConstraints).value
        except x509.ExtensionNotFound:
            continue
        if not basic.ca:
            continue
        try:
            cert.verify_directly_issued_by(trusted)
        except (ValueError, TypeError, InvalidSignature):
            continue
        return True
    return False


def check_server_certificate(der: bytes, security: OpcUaSecurity) -> None:
    """Raise `SecurityRejected` unless the server certificate `der` is the
    pinned one or trusted by the trust store."""
    der = _first_cert(der)
    cert = x509.load_der_x509_certificate(der)
    who = f"{_subject(cert)} (SHA-256 {fingerprint(der)})"
    if security.server_certificate is not None:
        pinned = _load_cert_file(security.server_certificate).public_bytes(
            Encoding.DER)
        if pinned == der:
            return
        if security.trust_dir is None:
            raise SecurityRejected(
                f"server certificate {who} is not the pinned certificate "
                f"{security.server_certificate} (SHA-256 {fingerprint(pinned)})")
    if security.trust_dir is not None and _trusted_by_store(cert, security.trust_dir):
        return
    raise SecurityRejected(f"server certificate {who} is not trusted by "
                           f"{security.server_certificate or security.trust_dir}")


def _application_uri(security: OpcUaSecurity) -> str | None:
    if security.application_uri:
        return security.application_uri
    if security.certificate is None:
        return None
    cert = _load_cert_file(security.certificate)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None


class _RedactActivateSession(logging.Filter):
    """asyncua logs every request at DEBUG ("Sending: %s"); an
    ActivateSessionRequest carries the password (readable inside the
    encrypted channel). Replace that argument before it is formatted."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if isinstance(args, tuple) and any(
                isinstance(a, ua.ActivateSessionRequest) for a in args):
            record.args = tuple("<ActivateSessionRequest, redacted>"
                                if isinstance(a, ua.ActivateSessionRequest) else a
                                for a in args)
        return True


_REDACTOR = _RedactActivateSession()
#: the asyncua logger that prints whole requests
_REQUEST_LOGGER = "asyncua.client.ua_client.UASocketProtocol"


def _redact_requests_in_logs() -> None:
    logger = logging.getLogger(_REQUEST_LOGGER)
    if _REDACTOR not in logger.filters:
        logger.addFilter(_REDACTOR)


async def apply_security(client: Client, security: OpcUaSecurity) -> None:
    """Configure `client` (not yet connected) for `security`; for a secured
    policy this fetches the endpoints and checks the server certificate."""
    if security.password is not None:
        _redact_requests_in_logs()
    if security.username:
        client.set_user(security.username)
    if security.password is not None:
        client.set_password(security.password.get_secret_value())
    if security.policy == "None":
        return
    app_uri = _application_uri(security)
    if app_uri:
        client.application_uri = app_uri
    policy = _POLICY_CLASSES[security.policy]
    mode = getattr(ua.MessageSecurityMode, security.mode)
    endpoints = await client.connect_and_get_server_endpoints()
    matching = [ep for ep in endpoints
                if ep.SecurityPolicyUri == policy.URI and ep.SecurityMode == mode]
    if not matching:
        offered = sorted({f"{ep.SecurityPolicyUri.rsplit('#', 1)[-1]}/{ep.SecurityMode.name}"
                          for ep in endpoints})
        raise SecurityRejected(f"the server offers no endpoint {security.policy}/"
                               f"{security.mode}; it offers {offered}")
    server_der = matching[0].ServerCertificate
    if not server_der:
        raise SecurityRejected(f"the {security.policy} endpoint presents no certificate")
    check_server_certificate(server_der, security)
    if security.certificate is None or security.private_key is None:  # model guarantees
        raise SecurityRejected("client certificate and private key are required")
    key_password = (security.private_key_password.get_secret_value()
                    if security.private_key_password is not None else None)
    await client.set_security(policy, str(security.certificate), str(security.private_key),
                              key_password, _first_cert(server_der), mode)
