"""No written address may share controller memory with another (config check).

Every address the config names is collected with whether compd writes it
(the outputs: offset, heartbeat, status word) or only reads it (the
channels, the probe's value and counter), and the rule of
`drivers.footprint.first_clash` applies: a written address overlaps nothing
else (a float32 offset at holding registers 0–1 and the heartbeat at holding
register 1 would have the heartbeat overwrite half the offset every cycle);
reads may coincide only when they read the same value (one sensor under two
channel names), never part of another value or the same cells as another type.
Spans are the addresses' own (`Address.footprint()`): Modbus registers by the
type's width, S7 DB and PMC bytes by the type's size, OPC UA nodes by node id.
"""

from __future__ import annotations

from collections.abc import Mapping

from compd.errors import ConfigError
from drivers.addresses import Address
from drivers.footprint import first_clash


def check_overlaps(outputs: Mapping[str, Address], channels: Mapping[str, Address],
                   probes: Mapping[str, Address]) -> None:
    """ConfigError naming both keys and the cells they share, at the later key."""
    uses = [*(a.use(f"output.{n}", written=True) for n, a in outputs.items()),
            *(a.use(f"channels.{n}.address", written=False) for n, a in channels.items()),
            *(a.use(f"adaptation.{n}", written=False) for n, a in probes.items())]
    clash = first_clash(uses)
    if clash is not None:
        raise ConfigError(clash.second.key, clash.reason())
