"""A simulated FANUC CNC behind the stand-in FOCAS library.

There is no network here: the stand-in ``libfwlib32.so`` (compiled from
`fwlib_standin.c`) reads the controller's state from a shared-memory file
``$COMPD_FOCAS_SIM_DIR/<ip>-<port>.shm`` (default directory
``/tmp/compd-focas-sim``) that this object writes through `mmap`. `stop()`
clears the online flag (a pulled cable: EW_SOCKET); `start()` again bumps
the generation (a power cycle: handles opened before get EW_HANDLE);
`inject_busy_writes(n)` makes the next n pmc_wrpmcrng calls answer EW_BUSY.

Addresses (PMC data little-endian, as in a FANUC PMC):
    bearing D0, column D2, table D4, ambient D6: word ×0.1 °C
    spindle_rpm D8 long; power_kw D12, growth_um D16, error_um D20: float
    motor: diagnosis 403 (the stand-in keeps tenths: scale 0.1; a real CNC
    gives whole °C, configure scale 1 there)
    outputs: offset D100 long ×0.1 µm, heartbeat D104 long, status D108 word;
    adjacent, so one pmc_wrpmcrng carries {offset, heartbeat, status} and a
    ladder can latch the offset when the heartbeat changes (a consistent record)
    extras: servo_z_temp diagnosis 308 axis 3 (×0.1), spindle_load_pct cnc_rdspload 1
    encodings: D200 byte, D202 word ×0.1, D204 long ×0.001, D208 float,
    D212 double, R100 long
"""

from __future__ import annotations

import mmap
import os
import struct
import weakref
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from drivers import encodings
from drivers.addresses import (
    PMC_AREAS,
    Address,
    FocasDiagAddress,
    FocasPmcAddress,
    FocasSpindleLoadAddress,
    PmcArea,
    PmcType,
)
from drivers.focas_codec import decode_pmc, encode_pmc, pmc_size
from drivers.sim.fwlib_build import build_standin
from drivers.sim.ports import free_tcp_port

# shared-memory layout: mirrors struct sim_shm in fwlib_standin.c
MAGIC = 0x53434F46
SHM_BYTES = 115132
OFF_ONLINE, OFF_GENERATION, OFF_LATENCY, OFF_CALLS, OFF_NDIAG = 4, 8, 12, 16, 20
OFF_SPLOAD, OFF_DIAG, OFF_PMC, OFF_BUSY_WRITES = 24, 56, 440, 115128
PMC_AREA_BYTES = 8192
MAX_DIAGS = 32

FocasAddr = FocasPmcAddress | FocasDiagAddress | FocasSpindleLoadAddress


def _d(address: int, type_: PmcType, scale: float = 1.0, area: PmcArea = "D") -> FocasPmcAddress:
    return FocasPmcAddress(area=area, address=address, type=type_, scale=scale)


CHANNELS: dict[str, FocasAddr] = {
    "bearing": _d(0, "word", 0.1),
    "motor": FocasDiagAddress(kind="diag", number=403, axis=0, scale=0.1),
    "column": _d(2, "word", 0.1),
    "table": _d(4, "word", 0.1),
    "ambient": _d(6, "word", 0.1),
    "spindle_rpm": _d(8, "long"),
    "power_kw": _d(12, "float"),
    "growth_um": _d(16, "float"),
    "error_um": _d(20, "float"),
}
PROBES: dict[str, FocasAddr] = {
    "probe_value": _d(24, "float"),
    "probe_counter": _d(28, "long"),
}
EXTRAS: dict[str, FocasAddr] = {
    "servo_z_temp": FocasDiagAddress(kind="diag", number=308, axis=3, scale=0.1),
    "spindle_load_pct": FocasSpindleLoadAddress(kind="spload", spindle=1),
}
OUTPUTS: dict[str, FocasPmcAddress] = {
    "offset": _d(100, "long", 0.1),
    "heartbeat": _d(104, "long"),
    "status": _d(108, "word"),
}
#: each axis's present position (mm, PMC floats the ladder keeps current) and a plain
#: offset per axis (0.1 µm, PMC longs) for compd to write: the ladder applies it as it
#: is wherever the axis stands
POSITIONS: dict[str, FocasPmcAddress] = {
    f"{axis}_position": _d(300 + 4 * i, "float") for i, axis in enumerate(("x", "y", "z"))}
AXIS_OFFSETS: dict[str, FocasPmcAddress] = {
    f"{axis}_comp_offset": _d(320 + 4 * i, "long", 0.1)
    for i, axis in enumerate(("x", "y", "z"))}
ENCODINGS: dict[str, FocasPmcAddress] = {
    "enc_byte": _d(200, "byte"),
    "enc_word": _d(202, "word", 0.1),
    "enc_long_milli": _d(204, "long", 0.001),
    "enc_float": _d(208, "float"),
    "enc_double": _d(212, "double"),
    "enc_r_long": _d(100, "long", area="R"),
}


def _saturate(raw: float, enc: encodings.Encoding) -> int:
    """The nearest raw integer `enc` holds (an analog card saturates, never wraps)."""
    return min(max(round(raw), int(enc.lo)), int(enc.hi))


def sim_dir() -> Path:
    return Path(os.environ.get("COMPD_FOCAS_SIM_DIR") or "/tmp/compd-focas-sim")


def _close(mm: mmap.mmap, path: Path) -> None:
    mm.close()
    path.unlink(missing_ok=True)


class FocasSimController:
    """The CNC side of the stand-in FOCAS library (shared memory)."""

    protocol = "focas"

    def __init__(self, host: str = "127.0.0.1", port: int = 0, library_dir: str | None = None,
                 latency_us: int = 0, **options: Any) -> None:
        if options:
            raise TypeError(f"unknown FOCAS sim options: {sorted(options)}")
        self.host = host
        self.port = port or free_tcp_port(host)
        self.endpoint = f"focas://{host}:{self.port}"
        self.library_path = str(build_standin(Path(library_dir) if library_dir else None))
        self.channels: dict[str, Address] = dict(CHANNELS)
        self.outputs_map: dict[str, Address] = dict(OUTPUTS)
        self.extras: dict[str, Address] = dict(EXTRAS)
        self.encodings: dict[str, Address] = dict(ENCODINGS)
        self.probes: dict[str, Address] = dict(PROBES)
        self.positions: dict[str, Address] = dict(POSITIONS)
        self.axis_offsets: dict[str, Address] = dict(AXIS_OFFSETS)
        self._table: dict[str, FocasAddr] = {**CHANNELS, **EXTRAS, **OUTPUTS, **ENCODINGS,
                                             **PROBES, **POSITIONS, **AXIS_OFFSETS}
        self.shm_path = sim_dir() / f"{host}-{self.port}.shm"
        self.shm_path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.shm_path, "wb") as f:
            f.truncate(SHM_BYTES)
        with open(self.shm_path, "r+b") as f:
            self._mm = mmap.mmap(f.fileno(), SHM_BYTES)
        self._finalizer = weakref.finalize(self, _close, self._mm, self.shm_path)
        self._u32(0, MAGIC)
        diags = [a for a in self._table.values() if isinstance(a, FocasDiagAddress)]
        for i, a in enumerate(diags[:MAX_DIAGS]):
            struct.pack_into("<iii", self._mm, OFF_DIAG + 12 * i, a.number, a.axis, 0)
        self._u32(OFF_NDIAG, len(diags))
        self._diag_index = {(a.number, a.axis): i for i, a in enumerate(diags)}
        self.set_latency_us(latency_us)

    def _u32(self, off: int, value: int) -> None:
        struct.pack_into("<I", self._mm, off, value)

    def _get_u32(self, off: int) -> int:
        value: int = struct.unpack_from("<I", self._mm, off)[0]
        return value

    @property
    def online(self) -> bool:
        return bool(self._get_u32(OFF_ONLINE))

    @property
    def generation(self) -> int:
        return self._get_u32(OFF_GENERATION)

    @property
    def calls(self) -> int:
        """Data calls the library has served (reads, writes, diagnoses)."""
        return self._get_u32(OFF_CALLS)

    def set_latency_us(self, latency_us: int) -> None:
        self._u32(OFF_LATENCY, max(0, int(latency_us)))

    def inject_busy_writes(self, n: int) -> None:
        """The next `n` pmc_wrpmcrng calls answer EW_BUSY (0 clears)."""
        self._u32(OFF_BUSY_WRITES, max(0, int(n)))

    @property
    def busy_writes(self) -> int:
        """EW_BUSY answers still to give."""
        return self._get_u32(OFF_BUSY_WRITES)

    async def start(self) -> None:
        if not self.online:
            self._u32(OFF_GENERATION, (self.generation + 1) & 0xFFFFFFFF)
            self._u32(OFF_ONLINE, 1)

    async def stop(self) -> None:
        self._u32(OFF_ONLINE, 0)

    def close(self) -> None:
        """Remove the shared-memory file (also done when garbage-collected)."""
        self._finalizer()

    def _pmc_off(self, a: FocasPmcAddress) -> int:
        return OFF_PMC + PMC_AREAS[a.area] * PMC_AREA_BYTES + a.address

    def _put(self, name: str, value: float) -> None:
        a = self._table[name]
        if isinstance(a, FocasPmcAddress):
            off = self._pmc_off(a)
            self._mm[off:off + pmc_size(a)] = encode_pmc(a, value, saturate=True)
        elif isinstance(a, FocasDiagAddress):
            raw = _saturate(value / a.scale, encodings.ENCODINGS["int32"])  # read as long data
            struct.pack_into("<i", self._mm, OFF_DIAG + 12 * self._diag_index[
                (a.number, a.axis)] + 8, raw)
        else:
            raw = _saturate(value / a.scale, encodings.ENCODINGS["int16"])
            struct.pack_into("<i", self._mm, OFF_SPLOAD + 4 * (a.spindle - 1), raw)

    async def publish(self, values: Mapping[str, float]) -> None:
        unknown = sorted(set(values) - set(self._table))
        if unknown:
            raise KeyError(f"unknown FOCAS sim names: {unknown}")
        for name, value in values.items():
            self._put(name, float(value))

    async def read_back(self, name: str) -> float:
        a = self._table[name]
        if not isinstance(a, FocasPmcAddress):
            raise KeyError(f"{name} is not a PMC value")
        off = self._pmc_off(a)
        return decode_pmc(a, self._mm[off:off + pmc_size(a)])

    async def outputs(self) -> dict[str, float]:
        return {name: await self.read_back(name) for name in OUTPUTS}

    async def forget_outputs(self) -> None:
        for a in (*OUTPUTS.values(), *AXIS_OFFSETS.values()):
            off = self._pmc_off(a)
            self._mm[off:off + pmc_size(a)] = bytes(pmc_size(a))
