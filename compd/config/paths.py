"""Where a config's other files are, from systemd's directories or the config's own
folder: the state directory, a password file; and reading the controller's password
(from its file or its environment variable, at run time)."""

from __future__ import annotations

import os
from pathlib import Path

from compd.config.schema import SecuritySection
from compd.errors import ConfigError


def resolve_state_dir(given: Path | None, base: Path) -> Path:
    """state.dir as given (relative: to the config's folder); not given, the first
    of systemd's $STATE_DIRECTORY (StateDirectory=; writable under
    ProtectSystem=strict, where <config dir>/state is not), else <config dir>/state."""
    if given is not None:
        return given if given.is_absolute() else base / given
    systemd = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    if systemd:
        return Path(systemd)
    return base / "state"


def credential_path(given: Path, base: Path) -> Path:
    """A password file: absolute as given; relative, in systemd's
    $CREDENTIALS_DIRECTORY (LoadCredential=) when set and the file is there,
    else relative to the config's folder."""
    if given.is_absolute():
        return given
    creds = os.environ.get("CREDENTIALS_DIRECTORY")
    if creds and (Path(creds) / given).is_file():
        return Path(creds) / given
    return base / given


def read_password(security: SecuritySection, base: Path) -> str | None:
    """The OPC UA password from its file or environment variable (run time)."""
    if security.password_file is not None:
        pf = credential_path(security.password_file, base)
        try:
            return pf.read_text(encoding="utf-8").strip("\r\n")
        except OSError as exc:
            raise ConfigError("controller.security.password_file",
                              f"cannot read {pf} ({exc.strerror})") from None
    if security.password_env is not None:
        value = os.environ.get(security.password_env)
        if value is None:
            raise ConfigError("controller.security.password_env",
                              f"environment variable {security.password_env} is not set")
        return value
    return None
