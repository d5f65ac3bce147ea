"""The plant as a client of a real controller: the HIL bench's machine side.

`DriveLoop` runs the thermal plant and, through one of our protocol drivers
(`drivers.factory.open_driver`, the real client libraries), each tick

1. advances the plant by `period_s` of machine time at the program's speed;
2. reads back what the daemon wrote (the drive map's ``read`` addresses:
   ``offset``, and ``heartbeat`` / ``status`` when mapped) and applies the
   offset (× `offset_um_per_unit`) to the plant, so its
   ``error_um = growth_um - offset``; an axis's temperature-compensation
   parameters, when the map names all three, are read in the same request and
   kept as the line the controller holds (`lines`);
3. writes the plant's sensor values to the map's ``write`` addresses;
4. records the row (with `record=True`).

So the loop daemon → controller → plant → controller → daemon closes through
the controller's own memory, exactly as on a bench with a real PLC or CNC.

Offline-safe: a lost link (`ConnectionLost`, `ControllerTimeout`, a transient
refusal) never stops the plant. The machine keeps its last offset (a
controller that cannot be reached cannot have changed it for the plant
either), the row is recorded with ``link_ok = 0``, and the driver reconnects
with its own capped backoff on a later tick. A write the controller refuses
for good (`WriteRejected(permanent=True)`, `BadAddress`) means the map is
wrong for this controller and ends the run with that error.

Scheduling as `drivers.sim.machine.SimMachine`: tick k is due at
t0 + k·period_s/speedup on the loop's monotonic clock; a late tick counts in
`overruns` and missed deadlines are skipped (no catch-up burst).
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from drivers.base import Driver, Quality
from drivers.endpoint import EndpointError, parse_endpoint, redact_endpoint
from drivers.errors import BadAddress, DriverError, WriteRejected
from drivers.factory import open_driver
from drivers.protocols import PROTOCOLS
from drivers.sim import CHANNELS
from drivers.sim.drive_map import DriveMap
from drivers.sim.plant import ThermalPlant
from drivers.sim.programs import Program
from drivers.sim.runner import PlantRunner
from drivers.temp_comp import AXES, PARAMETERS, AxisCompensation, output_name

#: columns of a recorded row
DRIVE_COLUMNS: tuple[str, ...] = ("time_s", *CHANNELS, "offset_um", "heartbeat", "status",
                                  "link_ok")
#: columns of `write_drive_record`: a calibration record (`drivers.sim.csvlog`,
#: ``dz_um`` = the true growth) plus what the bench observed
RECORD_FIELDS: tuple[str, ...] = ("time_s", "spindle_rpm", "bearing", "motor", "column", "table",
                                  "ambient", "power_kw", "dz_um", "offset_um", "error_um",
                                  "heartbeat", "status", "link_ok")
_FORMATS: dict[str, str] = {"time_s": "{:.3f}", "spindle_rpm": "{:.0f}", "bearing": "{:.1f}",
                            "motor": "{:.1f}", "column": "{:.1f}", "table": "{:.1f}",
                            "ambient": "{:.1f}", "power_kw": "{:.3f}", "dz_um": "{:.3f}",
                            "offset_um": "{:.3f}", "error_um": "{:.3f}", "heartbeat": "{:.0f}",
                            "status": "{:.0f}", "link_ok": "{:.0f}"}

_log = logging.getLogger(__name__)


class DriveLoop(PlantRunner):
    """The plant driving a controller through `driver` (see the module docstring).

    The caller constructs the driver with ``channels = drive_map.read`` and
    ``outputs = drive_map.write`` (`open_drive_driver` does) and owns nothing
    else: `run()`/`stop()` connect and close it.
    """

    task_name = "sim-drive"

    def __init__(self, driver: Driver, drive_map: DriveMap, *, program: Program | None = None,
                 plant: ThermalPlant | None = None, seed: int = 0, period_s: float = 1.0,
                 speedup: float = 1.0, repeat: bool = True, record: bool = False,
                 max_rows: int | None = None) -> None:
        super().__init__(DRIVE_COLUMNS, program=program, plant=plant, seed=seed,
                         period_s=period_s, speedup=speedup, repeat=repeat, record=record,
                         max_rows=max_rows)
        self.driver = driver
        self.map = drive_map
        #: exchanges (read + write) that failed on the link, and the last reason
        self.link_errors = 0
        self.last_error: str | None = None
        self.heartbeat = math.nan
        self.status = math.nan
        #: the last row (as `DRIVE_COLUMNS`), also without `record`
        self.latest: dict[str, float] = {}
        self._read_names = tuple(drive_map.read)
        #: the axes whose three compensation parameters the map reads
        self._axes = tuple(a for a in AXES if all(output_name(a, p) in drive_map.read
                                                  for p in PARAMETERS))
        #: the line each of those axes' controller held at the last good read
        self.lines: dict[str, AxisCompensation] = {}
        self._write_names = tuple(drive_map.write)
        self._link_ok = True

    # -- one exchange ----------------------------------------------------------

    def _link_failed(self, what: str, exc: DriverError) -> None:
        self.link_errors += 1
        self.last_error = f"{what}: {exc}"
        if self._link_ok:
            _log.warning("drive_link_down", extra={"what": what, "error": str(exc)})
        self._link_ok = False

    async def _read_back(self) -> bool:
        try:
            samples = await self.driver.read(self._read_names)
        except BadAddress:
            raise
        except DriverError as exc:
            self._link_failed("read", exc)
            return False
        offset = samples.get("offset")
        if offset is not None and offset.quality is Quality.GOOD and math.isfinite(offset.value):
            self.plant.offset_um = offset.value * self.map.offset_um_per_unit
        hb, st = samples.get("heartbeat"), samples.get("status")
        self.heartbeat = hb.value if hb is not None else math.nan
        self.status = st.value if st is not None else math.nan
        for axis in self._axes:
            got = [samples[output_name(axis, p)] for p in PARAMETERS]
            if all(g.quality is Quality.GOOD and math.isfinite(g.value) for g in got):
                self.lines[axis] = AxisCompensation(*(g.value for g in got))
        return True

    async def _write_sensors(self, sensors: dict[str, float]) -> bool:
        try:
            await self.driver.write({name: sensors[name] for name in self._write_names})
        except WriteRejected as exc:
            if exc.permanent:
                raise
            self._link_failed("write", exc)
            return False
        except BadAddress:
            raise
        except DriverError as exc:
            self._link_failed("write", exc)
            return False
        return True

    async def _exchange(self) -> dict[str, float]:
        read_ok = await self._read_back()
        sensors = self.plant.sensors()
        write_ok = await self._write_sensors(sensors)
        ok = read_ok and write_ok
        if ok and not self._link_ok:
            _log.info("drive_link_up")
        self._link_ok = ok
        row = (self.plant.time_s, *(sensors[c] for c in CHANNELS), self.plant.offset_um,
               self.heartbeat, self.status, 1.0 if ok else 0.0)
        self.latest = dict(zip(DRIVE_COLUMNS, row, strict=True))
        if self.record:
            self._history.append(row)
        return sensors

    async def prime(self) -> dict[str, float]:
        """Connect (a failure is tolerated: the driver retries later) and
        exchange once without advancing the plant."""
        try:
            await self.driver.connect()
        except DriverError as exc:
            self._link_failed("connect", exc)
        self._primed = True
        return await self._exchange()

    async def tick(self) -> dict[str, float]:
        """Advance one period, read back the offset, write the sensors."""
        self.advance()
        self.ticks += 1
        return await self._exchange()

    async def _finish(self) -> None:
        """The driver is closed when the loop ends, however it ends."""
        await self.driver.close()


def write_drive_record(path: str | os.PathLike[str], rows: dict[str, np.ndarray]) -> int:
    """Write a drive run (`DriveLoop.history_arrays()`) as CSV with the header
    `RECORD_FIELDS`: the calibration record columns (``dz_um`` = true growth,
    so `compd fit` / `compd replay` read it) plus offset, residual error,
    heartbeat, status and link state. Written to a temporary name and renamed."""
    columns = {name: rows[name] for name in DRIVE_COLUMNS}
    columns["dz_um"] = rows["growth_um"]
    target = Path(path)
    tmp = target.with_name(target.name + ".part")
    fmt = ",".join(_FORMATS[c] for c in RECORD_FIELDS) + "\n"
    n = 0
    with tmp.open("w", encoding="ascii", newline="") as f:
        f.write(",".join(RECORD_FIELDS) + "\n")
        for row in zip(*(np.asarray(columns[c], dtype=np.float64).tolist()
                         for c in RECORD_FIELDS), strict=True):
            f.write(fmt.format(*row))
            n += 1
    os.replace(tmp, target)
    return n


def drive_endpoint(url: str) -> tuple[str, str]:
    """``opcua://h:p | s7://h:p | modbus://h:p | focas://h:p`` -> (protocol,
    the endpoint string the protocol's driver takes), checked as the daemon's
    config checks its endpoint (`drivers.endpoint`); the message of a refusal
    never holds a user name or password."""
    scheme, sep, rest = url.partition("://")
    scheme = scheme.lower()
    if not sep or not rest:
        raise EndpointError(f"not an endpoint: {redact_endpoint(url)!r} "
                            "(expected e.g. modbus://host:502)")
    for spec in PROTOCOLS.values():
        if scheme in (spec.name, spec.scheme):
            endpoint = f"{spec.scheme}://{rest}"
            parse_endpoint(endpoint, spec)
            return spec.name, endpoint
    raise EndpointError(f"unknown protocol in {redact_endpoint(url)!r}; "
                        f"known: {', '.join(f'{name}://' for name in PROTOCOLS)}")


def open_drive_driver(url: str, drive_map: DriveMap, **overrides: Any) -> Driver:
    """Construct (not connect) the driver a `DriveLoop` uses: it reads the
    map's ``read`` addresses and writes its ``write`` addresses. `overrides`
    replace the map's driver options (e.g. ``library_path`` on a bench)."""
    protocol, endpoint = drive_endpoint(url)
    if protocol != drive_map.protocol:
        raise ValueError(f"the endpoint is {protocol} but the drive map is for "
                         f"{drive_map.protocol}")
    options = {**drive_map.driver.as_kwargs(), **overrides}
    return open_driver(protocol, endpoint, drive_map.read, drive_map.write, **options)
