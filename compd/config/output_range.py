"""Can each output address hold what compd writes to it? (config check)

The offset is written as raw = sign·units_per_um·µm / scale in the address's
encoding; ±limit_um must fit, or every write near the limit fails at run
time (Int16 at 0.0001 mm/count holds only ±3.2767 µm). The heartbeat counts
to HEARTBEAT_MODULO - 1 and the status word carries every `Status` bit.

Encodings per protocol (raw ranges; the float types by their largest finite
value). OPC UA nodes are typed by the server, known only once connected: the
driver refuses a value its node cannot hold, and repeated failures are a
write fault (`compd.core.cycle`).
"""

from __future__ import annotations

import math

from compd.errors import ConfigError
from drivers.addresses import Address

_FLOAT32_MAX = 3.4028234663852886e38

#: the largest heartbeat (compd.core.cycle.HEARTBEAT_MODULO - 1) and status word
#: (every compd.core.output.Status bit); here because the config is the room
#: below the core (tests/compd/test_output_range.py holds them equal)
HEARTBEAT_MAX = 32767
STATUS_MAX = (1 << 15) - 1

#: (protocol, type) -> raw range of the encoding (ints: an integer encoding)
RAW_RANGES: dict[tuple[str, str], tuple[float, float]] = {
    ("modbus", "int16"): (-32768, 32767), ("modbus", "uint16"): (0, 65535),
    ("modbus", "int32"): (-(2**31), 2**31 - 1), ("modbus", "float32"): (-_FLOAT32_MAX,
                                                                       _FLOAT32_MAX),
    ("s7", "INT"): (-32768, 32767), ("s7", "WORD"): (0, 65535),
    ("s7", "DINT"): (-(2**31), 2**31 - 1), ("s7", "REAL"): (-_FLOAT32_MAX, _FLOAT32_MAX),
    ("focas", "byte"): (-128, 127), ("focas", "word"): (-32768, 32767),
    ("focas", "long"): (-(2**31), 2**31 - 1), ("focas", "float"): (-_FLOAT32_MAX,
                                                                  _FLOAT32_MAX),
    ("focas", "double"): (-math.inf, math.inf),
    ("linuxcnc", "s32"): (-(2**31), 2**31 - 1), ("linuxcnc", "u32"): (0, 2**32 - 1),
    ("linuxcnc", "float"): (-math.inf, math.inf), ("linuxcnc", "bit"): (0, 1),
}


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def check_range(key: str, protocol: str, addr: Address, lo: float, hi: float,
                what: str, *, per_unit: float = 1.0, unit: str = "") -> None:
    """ConfigError at `key` unless `addr` holds every value in [lo, hi]
    (engineering value = per_unit·x, raw = value / scale, integers rounded)."""
    kind = str(getattr(addr, "type", ""))
    raw = RAW_RANGES.get((protocol, kind))
    if raw is None:
        return
    scale = float(getattr(addr, "scale", 1.0))
    f = per_unit / scale
    ends = sorted((lo * f, hi * f))
    if math.isfinite(ends[0]) and math.isfinite(ends[1]):
        if isinstance(raw[0], int):  # the driver rounds to the nearest raw integer
            ends = [round(ends[0]), round(ends[1])]
        if raw[0] <= ends[0] and ends[1] <= raw[1]:
            return
    held = sorted((raw[0] / f, raw[1] / f))
    raise ConfigError(key, f"{kind} at scale {scale:g} holds {_fmt(held[0])}..{_fmt(held[1])}"
                           f"{unit} (raw {_fmt(raw[0])}..{_fmt(raw[1])}), but {what} needs "
                           f"{_fmt(lo)}..{_fmt(hi)}{unit}")


def check_outputs(protocol: str, outputs: dict[str, Address], *, limit_um: float,
                  units_per_um: float, sign: int, heartbeat_max: int, status_max: int) -> None:
    """Every output address against what compd writes to it (ConfigError)."""
    check_range("output.offset", protocol, outputs["offset"], -limit_um, limit_um,
                f"limit_um = {limit_um:g}", per_unit=sign * units_per_um, unit=" µm")
    if "heartbeat" in outputs:
        check_range("output.heartbeat", protocol, outputs["heartbeat"], 0, heartbeat_max,
                    "the heartbeat")
    if "status" in outputs:
        check_range("output.status", protocol, outputs["status"], 0, status_max,
                    "the status word")
