"""Build the configured driver (protocol options, credentials read at run time)."""

from __future__ import annotations

from typing import Any

from compd.config.loader import LoadedConfig, read_password
from drivers.backoff import Backoff
from drivers.base import Driver
from drivers.factory import open_driver


def driver_options(cfg: LoadedConfig) -> dict[str, Any]:
    """Keyword options for `open_driver` from the [controller] section."""
    ctl = cfg.raw.controller
    opts: dict[str, Any] = {
        "timeout_s": ctl.timeout_s,
        "backoff": Backoff(ctl.backoff.initial_s, ctl.backoff.cap_s),
    }
    base = cfg.path.parent
    if ctl.protocol == "opcua" and ctl.security is not None:
        from drivers.opcua_security import OpcUaSecurity

        sec = ctl.security

        def _abs(p: Any) -> Any:
            return None if p is None else (p if p.is_absolute() else base / p)

        password = read_password(sec, base)
        if password:
            from compd.faces.telemetry import register_secret

            register_secret(password)
        opts["security"] = OpcUaSecurity(
            policy=sec.policy, mode=sec.mode, certificate=_abs(sec.certificate),
            private_key=_abs(sec.private_key), server_certificate=_abs(sec.server_certificate),
            trust_store=_abs(sec.trust_dir), username=sec.username,
            password=password)
        opts["connect_timeout_s"] = ctl.connect_timeout_s
    elif ctl.protocol == "s7" and ctl.s7 is not None:
        opts.update(rack=ctl.s7.rack, slot=ctl.s7.slot)
    elif ctl.protocol == "focas" and ctl.focas is not None:
        opts.update(library_path=str(ctl.focas.library_path),
                    library_sha256=ctl.focas.library_sha256)
    return opts


def build_driver(cfg: LoadedConfig) -> Driver:
    """Construct (not connect) the driver; a refusal by the driver's own checks
    (an endpoint it cannot parse, a library file that is not there) is a
    configuration error naming [controller]."""
    from compd.errors import ConfigError
    from drivers.errors import DriverError

    ctl = cfg.raw.controller
    try:
        return open_driver(ctl.protocol, ctl.endpoint, cfg.channels, cfg.outputs,
                           **driver_options(cfg))
    except (ValueError, DriverError) as exc:
        key = "controller.endpoint" if "endpoint" in str(exc) else "controller"
        raise ConfigError(key, str(exc)) from None
