"""Certificate expiry at start: the days left on the OPC UA client certificate
and the pinned server certificate (DER or PEM), read with `cryptography`.

A certificate that expires within `WARN_DAYS` is logged as a warning
(``certificate_expiring``) when the daemon starts, and the client
expiry time of each certificate that exists goes to the
``compd_certificate_expiry_timestamp_seconds{role}`` metric: an
expired certificate stops the connection, and a shop notices a warning weeks
ahead more readily than a dead link on the day.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cryptography.x509 import Certificate

    from compd.config.loader import LoadedConfig
    from compd.faces.telemetry import Metrics

WARN_DAYS = 30.0


def expiry_timestamp(path: Path) -> float:
    """When the certificate at `path` expires, in seconds since the epoch (errors
    as `expiry_days`)."""
    return _load(path).not_valid_after_utc.timestamp()


def _load(path: Path) -> Certificate:
    from cryptography import x509

    data = path.read_bytes()
    return (x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----BEGIN")
            else x509.load_der_x509_certificate(data))


def expiry_days(path: Path, *, now: dt.datetime | None = None) -> float:
    """Days from `now` until the certificate at `path` expires (negative when
    it has). Raises ValueError when the file is not a certificate, OSError when
    it cannot be read."""
    cert = _load(path)
    when = now if now is not None else dt.datetime.now(dt.UTC)
    return (cert.not_valid_after_utc - when).total_seconds() / 86400.0


def check_certificates(cfg: LoadedConfig, metrics: Metrics, log: Any, *, wall_s: float) -> None:
    """The daemon's check at start and after a reload: each configured certificate's
    expiry to the metric, a warning within `WARN_DAYS` (`wall_s`: now, the daemon's
    clock), a warning for one that cannot be read (compensation starts anyway)."""
    sec = cfg.raw.controller.security
    if sec is None:
        return
    now = dt.datetime.fromtimestamp(wall_s, dt.UTC)
    for role, path in (("client", sec.certificate), ("server", sec.server_certificate)):
        if path is None:
            continue
        full = path if path.is_absolute() else cfg.path.parent / path
        try:
            days = expiry_days(full, now=now)
            metrics.certificate_expiry.labels(role=role).set(expiry_timestamp(full))
        except (OSError, ValueError) as exc:
            log.warning("certificate_unreadable", role=role, path=str(full), error=str(exc))
            continue
        if days <= WARN_DAYS:
            log.warning("certificate_expiring", role=role, path=str(full),
                        days_left=round(days, 2), warn_days=WARN_DAYS)
