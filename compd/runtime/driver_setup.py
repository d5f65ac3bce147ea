"""Build the configured driver (protocol options, credentials read at run time).

The protocol's spec (`drivers.protocols`) says which ``[controller.<section>]``
table holds its options; the table turns itself into driver options, the
OPC UA security with its password read here, at run time.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from compd.config.loader import LoadedConfig, read_password
from compd.config.schema import SecuritySection
from drivers.backoff import Backoff
from drivers.base import Driver
from drivers.errors import DriverError
from drivers.factory import open_driver
from drivers.protocols import PROTOCOLS


def _security_options(sec: SecuritySection, base: Path) -> dict[str, Any]:
    from drivers.opcua_security import OpcUaSecurity

    def _abs(p: Path | None) -> Path | None:
        return None if p is None else (p if p.is_absolute() else base / p)

    password = read_password(sec, base)
    if password:
        from compd.faces.telemetry import register_secret

        register_secret(password)
    return {"security": OpcUaSecurity(
        policy=sec.policy, mode=sec.mode, certificate=_abs(sec.certificate),
        private_key=_abs(sec.private_key), server_certificate=_abs(sec.server_certificate),
        trust_dir=_abs(sec.trust_dir), username=sec.username, password=password)}


def driver_options(cfg: LoadedConfig) -> dict[str, Any]:
    """Keyword options for `open_driver` from the [controller] section."""
    ctl = cfg.raw.controller
    opts: dict[str, Any] = {
        "timeout_s": ctl.timeout_s,
        "backoff": Backoff(ctl.backoff.initial_s, ctl.backoff.cap_s),
    }
    spec = PROTOCOLS[ctl.protocol]
    section = getattr(ctl, spec.section) if spec.section is not None else None
    if isinstance(section, SecuritySection):
        opts.update(_security_options(section, cfg.path.parent))
    elif section is not None:
        opts.update(section.driver_options())
    if spec.connect_timeout:
        opts["connect_timeout_s"] = ctl.connect_timeout_s
    return opts


def build_driver(cfg: LoadedConfig) -> Driver:
    """Construct (not connect) the driver; a refusal by the driver's own checks
    (an endpoint it cannot parse, a library file that is not there) is a
    configuration error naming [controller]."""
    from compd.errors import ConfigError
    from drivers.errors import DriverError

    ctl = cfg.raw.controller
    try:
        # the probe's addresses ([adaptation]) and the controller's state are read
        # like channels
        return open_driver(ctl.protocol, ctl.endpoint,
                           {**cfg.channels, **cfg.probes, **cfg.states},
                           cfg.outputs, **driver_options(cfg))
    except (ValueError, DriverError) as exc:
        key = ("controller.endpoint" if "endpoint" in str(exc) else
               "controller.focas.library_path" if "library_path" in str(exc) else "controller")
        raise ConfigError(key, str(exc)) from None


def check_driver(cfg: LoadedConfig) -> None:
    """What `compd run` refuses before it connects, for `compd check`: the driver
    constructed exactly as run constructs it (`build_driver`), then closed
    unconnected. One validation path: check says OK only where run starts."""
    import asyncio

    driver = build_driver(cfg)
    asyncio.run(driver.close())


async def connect(driver: Driver, cfg: LoadedConfig, log: Any) -> bool:
    """Connect within ``connect_timeout_s``; a failure is logged, not raised: the
    reads fail (the cycle holds) and the driver retries with its backoff. False:
    the link is not up yet, and its coming up is for the cycle to log
    (`CycleIO.unannounced`)."""
    ctl = cfg.raw.controller
    try:
        await asyncio.wait_for(driver.connect(), ctl.connect_timeout_s)
    except (DriverError, TimeoutError, OSError) as exc:
        log.warning("controller_connect_failed", endpoint=ctl.endpoint, error=str(exc))
        return False
    log.info("controller_connected", endpoint=ctl.endpoint)
    return True
