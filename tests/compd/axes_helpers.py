"""A Modbus config with per-axis outputs (``[output.axes.x]``, the TwinCAT layout of
the simulated Modbus controller) and its channels named for the ball-screw machine
(`drivers.sim.ballscrew_machine`): nut, screw_bearing, column, ambient; and one
cycle driven by hand over a real driver (`drive_cycle`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig
    from compd.core.cycle import Cycle
    from compd.core.plan import Plan, Row
    from drivers.base import Driver

#: the ball-screw sensors on the simulated Modbus controller's input registers
SENSOR_CHANNELS: dict[str, str] = {"nut": "motor", "screw_bearing": "bearing",
                                   "column": "column", "ambient": "ambient"}

CONFIG = """
[machine]
name = "axes"
period_s = {period_s}
time_scale = {time_scale}

[controller]
protocol = "modbus"
endpoint = "{endpoint}"
timeout_s = {timeout_s}
connect_timeout_s = 2.0
backoff = {{ initial_s = 0.02, cap_s = 0.2 }}

[channels.nut]
address = {{ kind = "input", address = 1, type = "int16", scale = 0.1 }}
unit = "degC"
range = [-20.0, 150.0]

[channels.screw_bearing]
address = {{ kind = "input", address = 0, type = "int16", scale = 0.1 }}
unit = "degC"
range = [-20.0, 150.0]

[channels.column]
address = {{ kind = "input", address = 2, type = "int16", scale = 0.1 }}
unit = "degC"
range = [-20.0, 150.0]

[channels.ambient]
address = {{ kind = "input", address = 4, type = "int16", scale = 0.1 }}
unit = "degC"
range = [-10.0, 60.0]

[model]
[[model.terms]]
name = "column"
inputs = {{ column = 1.0 }}
a = ["1"]
b = ["1"]

[output]
offset = {{ kind = "holding", address = 0, type = "float32" }}
heartbeat = {{ kind = "holding", address = 2, type = "uint16" }}
status = {{ kind = "holding", address = 3, type = "uint16" }}
axes_status = {{ kind = "holding", address = 4, type = "uint16" }}
limit_um = 100.0
slew_um_s = 1.0

[output.axes.x]
reference = {{ kind = "holding", address = 32, type = "int32", scale = 0.0001 }}
value = {{ kind = "holding", address = 34, type = "int32", scale = 0.1 }}
slope = {{ kind = "holding", address = 36, type = "int32" }}
reference_mm = 0.0
value_limit_um = {value_limit_um}
slope_limit_um_m = {slope_limit_um_m}
slew_um_s = {value_slew}
slope_slew_um_m_s = {slope_slew}

[output.axes.x.model]
reference = {{ column = {t0}, screw_bearing = {t0}, ambient = {t0} }}
[[output.axes.x.model.terms]]
name = "value"
inputs = {{ column = {kc}, screw_bearing = {kb}, ambient = {ka} }}
a = ["1"]
b = ["1"]

[output.axes.x.slope_model]
reference = {{ nut = {t0}, screw_bearing = {t0} }}
[[output.axes.x.slope_model.terms]]
name = "slope"
inputs = {{ nut = {sn}, screw_bearing = {sb} }}
a = ["1"]
b = ["1"]

[faults]
hold_s = {hold_s}

[state]
dir = "state"
checkpoint_every = 1

[recorder]
enabled = false
"""


def axes_config_text(endpoint: str = "modbus://127.0.0.1:5020", *, period_s: float = 60.0,
                     time_scale: float = 60.0, timeout_s: float | None = None,
                     t0: float = 20.0, kc: float = 3.0, kb: float = 1.5, ka: float = 0.5,
                     sn: float = 5.0, sb: float = 6.5, value_limit_um: float = 200.0,
                     slope_limit_um_m: float = 200.0, value_slew: float = 1.0,
                     slope_slew: float = 1.0, hold_s: float = 600.0) -> str:
    timeout = timeout_s if timeout_s is not None else 0.4 * period_s / time_scale
    return CONFIG.format(endpoint=endpoint, period_s=period_s, time_scale=time_scale,
                         timeout_s=timeout, t0=t0, kc=kc, kb=kb, ka=ka, sn=sn, sb=sb,
                         value_limit_um=value_limit_um, slope_limit_um_m=slope_limit_um_m,
                         value_slew=value_slew, slope_slew=slope_slew, hold_s=hold_s)


def write_axes_config(tmp_path: Path, endpoint: str = "modbus://127.0.0.1:5020",
                      **over: float) -> Path:
    p = tmp_path / "compd.toml"
    p.write_text(axes_config_text(endpoint, **over), encoding="utf-8")
    return p


async def drive_cycle(driver: Driver, cycle: Cycle, cfg: LoadedConfig,
                      t: float) -> tuple[Plan, Row]:
    """One cycle as the daemon runs it, over `driver`: the channels, the offset and
    every axis output read (a bad read-back as None), planned at `t`, written, and
    committed as written."""
    from compd.core.plan import WRITTEN
    from drivers.base import Quality

    names = [*cfg.channels, "offset", *cycle.axes.names]
    got = await driver.read(names)
    samples = {n: got[n] for n in cfg.channels}
    rb = {n: (s.value if (s := got.get(n)) is not None and s.quality is not Quality.BAD
              else None) for n in cycle.axes.names}
    plan = cycle.plan(t, samples, got["offset"].value, axes_readback=rb)
    await driver.write(plan.writes)
    return plan, cycle.commit(WRITTEN)
