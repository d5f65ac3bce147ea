"""The simulated OPC UA controller's security (`drivers.sim.opcua_server`):
`OpcUaSimSecurity` (certificate, key, policies, users), the user manager that
accepts exactly its user name / password pairs, and `secure`, which sets up a
server's endpoints from it (None: an unsecured endpoint, anonymous only).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.internal_server import InternalServer
from asyncua.server.server import Server
from asyncua.server.user_managers import UserManager

__all__ = ["POLICY_TYPES", "OpcUaSimSecurity", "secure", "user_manager"]

#: name -> asyncua policy types for the sim's `policies` option
POLICY_TYPES: dict[str, ua.SecurityPolicyType] = {
    "None": ua.SecurityPolicyType.NoSecurity,
    "Basic256Sha256_Sign": ua.SecurityPolicyType.Basic256Sha256_Sign,
    "Basic256Sha256_SignAndEncrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    "Aes128_Sha256_RsaOaep_Sign": ua.SecurityPolicyType.Aes128Sha256RsaOaep_Sign,
    "Aes128_Sha256_RsaOaep_SignAndEncrypt":
        ua.SecurityPolicyType.Aes128Sha256RsaOaep_SignAndEncrypt,
    "Aes256_Sha256_RsaPss_Sign": ua.SecurityPolicyType.Aes256Sha256RsaPss_Sign,
    "Aes256_Sha256_RsaPss_SignAndEncrypt":
        ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt,
}


@dataclass(frozen=True)
class OpcUaSimSecurity:
    """Security of the simulated server.

    `policies` are keys of `POLICY_TYPES`; `users` maps user name to password
    (when given, only user name tokens are accepted, no anonymous clients).
    """

    certificate: Path
    private_key: Path
    policies: Sequence[str] = ("Basic256Sha256_SignAndEncrypt",)
    users: Mapping[str, str] = field(default_factory=dict)
    application_uri: str = "urn:compd:sim:server"


class _PasswordUserManager(UserManager):
    """Accepts exactly the configured user name / password pairs."""

    def __init__(self, users: Mapping[str, str]) -> None:
        self._users = dict(users)

    def get_user(self, iserver: InternalServer, username: str | None = None,
                 password: str | None = None, certificate: Any = None) -> User | None:
        if username is not None and self._users.get(username) == password:
            return User(role=UserRole.User, name=username)
        return None


def user_manager(security: OpcUaSimSecurity | None) -> UserManager | None:
    """The server's user manager: None (asyncua's, anonymous) without users."""
    if security is None or not security.users:
        return None
    return _PasswordUserManager(security.users)


async def secure(server: Server, security: OpcUaSimSecurity | None) -> None:
    """The server's certificate, policies and identity tokens (after `init`)."""
    if security is None:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        # anonymous only: offering certificate and user-name tokens on an
        # unsecured endpoint made asyncua warn at every start
        server.set_identity_tokens([ua.AnonymousIdentityToken])
        return
    await server.set_application_uri(security.application_uri)
    await server.load_certificate(str(security.certificate))
    await server.load_private_key(str(security.private_key))
    server.set_security_policy([POLICY_TYPES[p] for p in security.policies])
    if security.users:
        server.set_identity_tokens([ua.UserNameIdentityToken])
