"""No written address may share controller memory with another (config check).

Every address the config names is collected with whether compd writes it
(the outputs: offset, heartbeat, status word) or only reads it (the
channels, the probe's value and counter, the controller's state: machine_on,
estop), and the rule of
`drivers.footprint.first_clash` applies: a written address overlaps nothing
else (a float32 offset at holding registers 0–1 and the heartbeat at holding
register 1 would have the heartbeat overwrite half the offset every cycle);
reads may coincide only when they read the same value (one sensor under two
channel names), never part of another value or the same cells as another type.
Spans are the addresses' own (`Address.uses()`): Modbus registers by the
type's width, S7 DB and PMC bytes by the type's size, OPC UA nodes by node id,
LinuxCNC HAL signals by name and compd's own HAL pins by name (a pin address
uses both: two outputs on one signal, or one pin name twice, are refused).

`check_shared_controllers`: the machines of one `compd run DIR` that name one
controller (protocol, host and port alike; a twin-spindle machine run as two
configs) are checked as one config, so that one machine's offset cannot be
another's heartbeat. Two spellings of one host (a name and its address) are
not recognised as one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

from compd.errors import ConfigError
from drivers.addresses import Address
from drivers.endpoint import endpoint_of
from drivers.footprint import Use, first_clash

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig


def _uses(outputs: Mapping[str, Address], channels: Mapping[str, Address],
          probes: Mapping[str, Address], states: Mapping[str, Address],
          where: str = "") -> list[Use]:
    return [*(u for n, a in outputs.items() for u in a.uses(f"{where}output.{n}", written=True)),
            *(u for n, a in channels.items()
              for u in a.uses(f"{where}channels.{n}.address", written=False)),
            *(u for n, a in probes.items()
              for u in a.uses(f"{where}adaptation.{n}", written=False)),
            *(u for n, a in states.items() for u in a.uses(f"{where}output.{n}", written=False))]


def check_overlaps(outputs: Mapping[str, Address], channels: Mapping[str, Address],
                   probes: Mapping[str, Address],
                   states: Mapping[str, Address] | None = None) -> None:
    """ConfigError naming both keys and the cells they share, at the later key
    (`states`: the controller's state, [output] machine_on and estop, read)."""
    clash = first_clash(_uses(outputs, channels, probes, states or {}))
    if clash is not None:
        raise ConfigError(clash.second.key, clash.reason())


def check_shared_controllers(configs: Sequence[LoadedConfig]) -> None:
    """ConfigError naming both files' keys when machines of one controller overlap."""
    by_controller: dict[tuple[str, str, int], list[LoadedConfig]] = {}
    for cfg in configs:
        ctl = cfg.raw.controller
        ep = endpoint_of(ctl.protocol, ctl.endpoint)
        by_controller.setdefault((ctl.protocol, ep.host.lower(), ep.port), []).append(cfg)
    for (_, host, port), group in sorted(by_controller.items()):
        if len(group) < 2:
            continue
        clash = first_clash([use for cfg in group for use in _uses(
            cfg.outputs, cfg.channels, cfg.probes, cfg.states, where=f"{cfg.path}: ")])
        if clash is not None:
            raise ConfigError("", f"{clash.second.key} {clash.reason()}, and both files "
                              f"name the controller at {host}:{port}")
