"""Certificate expiry at start: the days left on the OPC UA client certificate
and the pinned server certificate (DER or PEM), read with `cryptography`.

A certificate that expires within `WARN_DAYS` is logged as a warning
(``certificate_expiring``) when the daemon starts, and the client
certificate's days left go to the ``compd_cert_expiry_days`` metric: an
expired certificate stops the connection, and a shop notices a warning weeks
ahead more readily than a dead link on the day.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

WARN_DAYS = 30.0


def expiry_days(path: Path, *, now: dt.datetime | None = None) -> float:
    """Days from `now` until the certificate at `path` expires (negative when
    it has). Raises ValueError when the file is not a certificate, OSError when
    it cannot be read."""
    from cryptography import x509

    data = path.read_bytes()
    cert = (x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----BEGIN")
            else x509.load_der_x509_certificate(data))
    when = now if now is not None else dt.datetime.now(dt.UTC)
    return (cert.not_valid_after_utc - when).total_seconds() / 86400.0
