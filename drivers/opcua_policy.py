"""The OPC UA security rules, once: what a secured link needs.

`OpcUaSecurityRules` is both the ``[controller.security]`` table of the
daemon's config (`compd.config.schema.SecuritySection` adds the keys that
say where the password comes from) and the base of the driver's
`drivers.opcua_security.OpcUaSecurity` (which adds the password itself).
pydantic only: loading a config does not import asyncua.

With a policy other than "None": `certificate` and `private_key` (the
client's application instance certificate, PEM or DER) are required, and so
is a way to trust the server: `server_certificate` (pin: the exact
certificate expected) and/or `trust_dir` (a directory of trusted server or
CA certificates). A password needs a username and is refused with policy
"None" (it would cross the wire readable). Deprecated policies (SHA-1, weak
padding) are refused by name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

Policy = Literal["None", "Basic256Sha256", "Aes128_Sha256_RsaOaep", "Aes256_Sha256_RsaPss"]
Mode = Literal["Sign", "SignAndEncrypt"]
DEPRECATED_POLICIES = frozenset({"Basic128Rsa15", "Basic256"})
#: a path given as a string (also where the model is strict)
SecurityPath = Annotated[Path, Field(strict=False)]


class OpcUaSecurityRules(BaseModel):
    """The settings and rules (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True, hide_input_in_errors=True)

    policy: Policy = "None"
    mode: Mode = "SignAndEncrypt"
    certificate: SecurityPath | None = None
    private_key: SecurityPath | None = None
    server_certificate: SecurityPath | None = None
    trust_dir: SecurityPath | None = None
    username: str | None = None

    @property
    def has_password(self) -> bool:
        """Whether a password goes with these settings (the subclasses say)."""
        return False

    @field_validator("policy", mode="before")
    @classmethod
    def _not_deprecated(cls, v: object) -> object:
        if isinstance(v, str) and v in DEPRECATED_POLICIES:
            raise ValueError(f"security policy {v} is deprecated (SHA-1 / weak padding) and "
                             "refused; use Basic256Sha256, Aes128_Sha256_RsaOaep or "
                             "Aes256_Sha256_RsaPss")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> OpcUaSecurityRules:
        if self.policy == "None":
            if self.has_password:
                raise ValueError("a password with security policy None would cross the wire "
                                 "readable; use Basic256Sha256 (or better) with SignAndEncrypt")
            return self
        if self.certificate is None or self.private_key is None:
            raise ValueError(f"policy {self.policy} needs the client certificate and "
                             "private_key files")
        if self.server_certificate is None and self.trust_dir is None:
            raise ValueError("pin the server certificate (server_certificate) or give "
                             "trust_dir: otherwise any server is trusted")
        if self.has_password and not self.username:
            raise ValueError("a password needs a username")
        return self


__all__ = ["DEPRECATED_POLICIES", "Mode", "OpcUaSecurityRules", "Policy", "SecurityPath"]
