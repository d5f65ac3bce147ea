"""Can each output address hold what compd writes to it? (config check)

The offset is written as raw = sign·units_per_um·µm / scale in the address's
encoding; ±limit_um must fit, or every write near the limit fails at run
time (Int16 at 0.0001 mm/count holds only ±3.2767 µm). The heartbeat counts
to HEARTBEAT_MODULO - 1, the status word carries every `Status` bit and the
axes word every `AxesStatus` bit.

The raw ranges are the addresses' own (`Address.encoding`, from the one
table in `drivers.encodings`; the float types by their largest finite
value). OPC UA nodes are typed by the server, known only once connected: the
driver refuses a value its node cannot hold, and repeated failures are a
write fault (`compd.core.cycle`).
"""

from __future__ import annotations

import functools
import math
import operator

from compd.core.cycle import HEARTBEAT_MODULO
from compd.core.output import AxesStatus, Status
from compd.errors import ConfigError
from drivers.addresses import Address

#: the heartbeat counts 0 .. HEARTBEAT_MODULO - 1 and wraps (`compd.core.cycle`, which
#: counts with it), so it fits an INT, WORD, int16/uint16 or PMC word
HEARTBEAT_MAX = HEARTBEAT_MODULO - 1
#: the largest status word: every `compd.core.output.Status` bit
STATUS_MAX = int(functools.reduce(operator.or_, Status))
#: the largest axes word: every `compd.core.output.AxesStatus` bit
AXES_STATUS_MAX = int(functools.reduce(operator.or_, AxesStatus))


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def check_range(key: str, addr: Address, lo: float, hi: float,
                what: str, *, per_unit: float = 1.0, unit: str = "") -> None:
    """ConfigError at `key` unless `addr` holds every value in [lo, hi]
    (engineering value = per_unit·x, raw = value / scale, integers rounded)."""
    enc = addr.encoding
    if enc is None:
        return
    kind, raw = str(getattr(addr, "type", enc.name)), enc.range
    scale = float(getattr(addr, "scale", 1.0))
    f = per_unit / scale
    ends = sorted((lo * f, hi * f))
    if math.isfinite(ends[0]) and math.isfinite(ends[1]):
        if enc.integer:  # the driver rounds to the nearest raw integer
            ends = [round(ends[0]), round(ends[1])]
        if raw[0] <= ends[0] and ends[1] <= raw[1]:
            return
    held = sorted((raw[0] / f, raw[1] / f))
    raise ConfigError(key, f"{kind} at scale {scale:g} holds {_fmt(held[0])}..{_fmt(held[1])}"
                           f"{unit} (raw {_fmt(raw[0])}..{_fmt(raw[1])}), but {what} needs "
                           f"{_fmt(lo)}..{_fmt(hi)}{unit}")


def check_outputs(outputs: dict[str, Address], *, limit_um: float,
                  units_per_um: float, sign: int, heartbeat_max: int, status_max: int) -> None:
    """Every output address against what compd writes to it (ConfigError)."""
    check_range("output.offset", outputs["offset"], -limit_um, limit_um,
                f"limit_um = {limit_um:g}", per_unit=sign * units_per_um, unit=" µm")
    if "heartbeat" in outputs:
        check_range("output.heartbeat", outputs["heartbeat"], 0, heartbeat_max,
                    "the heartbeat")
    if "status" in outputs:
        check_range("output.status", outputs["status"], 0, status_max,
                    "the status word")
    if "axes_status" in outputs:
        check_range("output.axes_status", outputs["axes_status"], 0, AXES_STATUS_MAX,
                    "the axes word")
