"""``[telemetry]`` and ``[faces]``: what compd serves beside the cycle (/metrics, the
status page, its own OPC UA server) and the logs."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from compd.config.section import LaxPath, ListenHost, Section


class TelemetrySection(Section):
    metrics_port: Annotated[int, Field(ge=1, le=65535)] | None = None
    #: the address /metrics listens on: loopback by default; "0.0.0.0" or "::" in a
    #: container whose port is published, or for a Prometheus on another host
    metrics_host: ListenHost = "127.0.0.1"
    #: the HTTP server's bounds (/metrics and [faces.http]): open connections at most
    #: (beyond: the one waiting longest for a request is closed), seconds for a whole
    #: request head, seconds a kept-alive connection may sit idle
    metrics_max_connections: Annotated[int, Field(ge=1, le=1000)] = 64
    metrics_header_timeout_s: Annotated[float, Field(gt=0.0, le=300.0,
                                                     allow_inf_nan=False)] = 5.0
    metrics_idle_timeout_s: Annotated[float, Field(gt=0.0, le=3600.0,
                                                   allow_inf_nan=False)] = 30.0
    #: the least level of the protocol libraries' own loggers (asyncua, snap7,
    #: pymodbus); "default": WARNING, pymodbus CRITICAL (it logs every failed
    #: frame as an ERROR hex dump that our read_failed/write_failed already tell)
    library_log_level: Literal["default", "debug", "info", "warning", "error",
                               "critical"] = "default"
    log_format: Literal["auto", "json", "console"] = "auto"
    log_level: Literal["debug", "info", "warning", "error"] = "info"


class HttpFaceSection(Section):
    """``[faces.http]``: the operator status page (``/`` and ``/status.json``) served
    beside ``/metrics`` (``[telemetry] metrics_port`` and ``metrics_host``)."""

    enabled: bool = False
    #: hours of offset and model output the page plots (from the recorder)
    history_h: Annotated[float, Field(gt=0.0, le=168.0, allow_inf_nan=False)] = 4.0
    #: how often the page fetches /status.json (real seconds)
    refresh_s: Annotated[float, Field(ge=1.0, le=3600.0, allow_inf_nan=False)] = 5.0


class OpcUaFaceSection(Section):
    """``[faces.opcua]``: compd's own OPC UA server (`compd.faces.opcua_face`):
    read-only for every client; SetHold only for `operator`."""

    enabled: bool = False
    host: ListenHost = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 4841
    policy: Literal["Basic256Sha256", "Aes128_Sha256_RsaOaep", "Aes256_Sha256_RsaPss",
                    "None"] = "Basic256Sha256"
    #: the server's application instance certificate and key (PEM or DER)
    certificate: LaxPath | None = None
    private_key: LaxPath | None = None
    #: must be true for policy "None", and only on a loopback host
    insecure: bool = False
    #: clients may read without a user name (with policy None: always)
    anonymous_read: bool = False
    #: the one user who may call SetHold (and read)
    operator: Annotated[str, Field(min_length=1)] | None = None
    #: the operator's password: a file (relative: $CREDENTIALS_DIRECTORY or the
    #: config's folder), never the config itself
    operator_password_file: LaxPath | None = None
    #: TCP connections served at once (fewer when RLIMIT_NOFILE leaves less); one
    #: more is closed at once
    max_connections: Annotated[int, Field(ge=1, le=1000)] = 32
    #: sessions at once; one more is refused (BadTooManySessions)
    max_sessions: Annotated[int, Field(ge=1, le=1000)] = 16
    #: sessions anonymous readers never take (with an operator): the operator's
    reserved_sessions: Annotated[int, Field(ge=1, le=1000)] = 1
    #: a connection without a session this long after it was accepted is closed
    handshake_timeout_s: Annotated[float, Field(gt=0.0, le=300.0, allow_inf_nan=False)] = 10.0

    @model_validator(mode="before")
    @classmethod
    def _no_inline_password(cls, data: Any) -> Any:
        if isinstance(data, dict) and any("password" in k and not k.endswith("_file")
                                          for k in data):
            raise ValueError("a password is never written in the config: use "
                             "operator_password_file")
        return data

    @model_validator(mode="after")
    def _secure_by_default(self) -> OpcUaFaceSection:
        if not self.enabled:
            return self
        if self.policy == "None":
            if not self.insecure:
                raise ValueError("policy None sends everything readable and unauthenticated: "
                                 "set insecure = true to accept that (loopback only)")
            if not _loopback(self.host):
                raise ValueError(f"policy None is only for a loopback host, not {self.host!r}: "
                                 "use Basic256Sha256 with a certificate")
        elif self.certificate is None or self.private_key is None:
            raise ValueError(f"policy {self.policy} needs certificate and private_key "
                             "(the server's application instance certificate)")
        if (self.operator is None) != (self.operator_password_file is None):
            raise ValueError("operator and operator_password_file go together")
        if self.policy == "None" and self.operator is not None:
            raise ValueError("an operator password with policy None would cross the wire "
                             "readable: use a secure policy for SetHold")
        # the face's anonymous share (compd.faces.opcua_limits.Guard.anonymous_limit)
        share = min(self.max_sessions - self.reserved_sessions, self.max_connections // 2)
        if self.anonymous_read and self.operator is not None and share < 1:
            raise ValueError(
                f"reserved_sessions = {self.reserved_sessions} with max_sessions = "
                f"{self.max_sessions} and max_connections = {self.max_connections} leaves "
                "anonymous readers no session (they take at most max_sessions - "
                "reserved_sessions, and half the connections): raise the limits, or turn "
                "anonymous_read off")
        return self


def _loopback(host: str) -> bool:
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class FacesSection(Section):
    """``[faces]``: what compd shows the shop floor besides logs and metrics."""

    http: HttpFaceSection = HttpFaceSection()
    opcua: OpcUaFaceSection = OpcUaFaceSection()
