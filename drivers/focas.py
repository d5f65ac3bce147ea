"""FANUC FOCAS driver: ctypes over libfwlib32.so (`drivers.focas_abi`).

- The library is loaded from an absolute path only (a relative path would be
  resolved against whatever directory the daemon runs in); with
  `library_sha256` the file is hashed before it is loaded and refused on a
  mismatch.
- `cnc_startupprocess` runs once per process and library; `cnc_exitprocess`
  at interpreter exit.
- Every library call runs on the driver's one worker thread: a FOCAS handle
  is not thread-safe.
- A read makes one pmc_rdpmcrng per PMC area (a byte range covering all its
  values), one cnc_rdspload for all spindle loads and one cnc_diagnoss per
  diagnosis. A write makes one pmc_wrpmcrng per run of byte-adjacent outputs:
  lay out {offset, heartbeat, status} adjacently (as the simulator does) and
  the three go in one request, so the ladder can latch the offset only when
  the heartbeat changes, never a half-written record.
- The offset goes out as a PMC long in µm / scale (FANUC's thermal-growth
  input takes an absolute amount; jumps are the output stage's business).
- EW_SOCKET/EW_HANDLE free the handle; the next call after the backoff delay
  opens a new one (a power-cycled CNC invalidates old handles): the
  lifecycle every driver shares, `drivers.link.WorkerLink`.
- Diagnoses are read as long data (length 4 + 4); a byte-typed diagnosis on
  a real CNC would need cnc_rddiaginfo first (not done).
"""

from __future__ import annotations

import atexit
import ctypes
import hashlib
import math
import os
import threading
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import TypeVar

from drivers import focas_abi as abi
from drivers.addresses import (
    PMC_AREAS,
    PMC_TYPES,
    FocasDiagAddress,
    FocasPmcAddress,
    FocasSpindleLoadAddress,
)
from drivers.backoff import Backoff
from drivers.base import Quality, Sample, select_addresses
from drivers.endpoint import endpoint_of
from drivers.errors import BadAddress, ConnectionLost
from drivers.focas_codec import PmcRange, decode_pmc, encode_pmc, read_ranges, write_runs
from drivers.io_thread import IoThread
from drivers.link import LinkedDriver, WorkerLink
from drivers.plans import PlanCache

T = TypeVar("T")
FocasAddress = FocasPmcAddress | FocasDiagAddress | FocasSpindleLoadAddress
_BYTE = PMC_TYPES["byte"][0]


class LibraryRefusedError(ValueError):
    """The FOCAS library path or file is not acceptable."""


def parse_endpoint(endpoint: str) -> tuple[str, int]:
    """``focas://host[:port]`` -> (host, port); port 8193 by default
    (`drivers.endpoint`: the checks every caller shares)."""
    ep = endpoint_of("focas", endpoint)
    return ep.host, ep.port


def sha256_file(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


_libs: dict[str, ctypes.CDLL] = {}
_libs_lock = threading.Lock()


def _load(path: str, sha256: str | None) -> ctypes.CDLL:
    """Load once per process (and start the FOCAS process context once)."""
    with _libs_lock:
        lib = _libs.get(path)
        if lib is not None:
            return lib
        if sha256 is not None and sha256_file(path) != sha256.lower():
            raise LibraryRefusedError(f"{path}: sha256 does not match the pinned value")
        lib = abi.load(path)
        lib.cnc_startupprocess(0, b"/dev/null")
        atexit.register(lib.cnc_exitprocess)
        _libs[path] = lib
        return lib


@dataclass(frozen=True, slots=True)
class _ReadPlan:
    """How to read one set of names (computed once per set)."""

    wanted: dict[str, FocasAddress]
    ranges: tuple[PmcRange, ...]
    diags: tuple[tuple[str, FocasDiagAddress], ...]
    sploads: tuple[tuple[str, FocasSpindleLoadAddress], ...]


class FocasDriver(LinkedDriver):
    """Async driver for one FANUC CNC through the FOCAS library."""

    protocol = "focas"

    def __init__(self, endpoint: str, channels: Mapping[str, FocasAddress],
                 outputs: Mapping[str, FocasAddress], *, timeout_s: float = 0.5,
                 backoff: Backoff | None = None, library_path: str,
                 library_sha256: str | None = None) -> None:
        if timeout_s <= 0:
            raise ValueError("timeout_s must be positive")
        if not os.path.isabs(library_path):
            raise LibraryRefusedError(f"library_path must be absolute, got {library_path!r}")
        if not os.path.isfile(library_path):
            raise LibraryRefusedError(f"library_path {library_path!r} is not a file")
        if library_sha256 is not None and sha256_file(library_path) != library_sha256.lower():
            raise LibraryRefusedError(f"{library_path}: sha256 does not match the pinned value")
        self._outputs: dict[str, FocasPmcAddress] = {}
        for name, a in outputs.items():
            if not isinstance(a, FocasPmcAddress):
                raise TypeError(f"output {name}: only PMC addresses are writable")
            self._outputs[name] = a
        self.endpoint = endpoint
        self._ip, self._port = parse_endpoint(endpoint)
        self._channels = dict(channels)
        self._all: dict[str, FocasAddress] = {**self._channels, **self._outputs}
        self._timeout_s = timeout_s
        self._library_path = library_path
        self._library_sha256 = library_sha256
        self._lib: ctypes.CDLL | None = None
        self._handle: int | None = None  # touched only on the worker thread
        self._link: WorkerLink[int] = WorkerLink(
            endpoint, backoff or Backoff(), timeout_s, io=IoThread("focas-io"),
            open_sync=self._open_sync, drop_sync=self._free_sync, drop_on=(ConnectionLost,))
        self._read_plan = PlanCache(self._build_read_plan)
        self._write_plan = PlanCache(self._build_write_plan)

    @property
    def io_thread(self) -> IoThread:
        return self._link.io

    # ---- worker-thread side -------------------------------------------------

    def _free_sync(self) -> None:
        handle, self._handle = self._handle, None
        if handle is not None and self._lib is not None:
            self._lib.cnc_freelibhndl(handle)

    def _open_sync(self) -> int:
        """A new handle (EW_* refusals raise the matching `DriverError`)."""
        self._free_sync()
        if self._lib is None:
            self._lib = _load(self._library_path, self._library_sha256)
        handle = ctypes.c_uint16(0)
        rc = self._lib.cnc_allclibhndl3(self._ip.encode(), self._port,
                                        max(1, math.ceil(self._timeout_s)), ctypes.byref(handle))
        if rc != abi.EW_OK:
            raise abi.error_for(rc, f"cnc_allclibhndl3 {self.endpoint}")
        self._handle = handle.value
        return handle.value

    # ---- event-loop side ----------------------------------------------------

    def _call(self, op: Callable[[ctypes.CDLL, int], T], what: str) -> Awaitable[T]:
        """`op(library, handle)` on the worker thread (`WorkerLink` rules)."""
        return self._link.run(partial(self._with_lib, op), what)

    def _with_lib(self, op: Callable[[ctypes.CDLL, int], T], handle: int) -> T:
        if self._lib is None:
            raise ConnectionLost("library not loaded")
        return op(self._lib, handle)

    def _build_read_plan(self, names: tuple[str, ...]) -> _ReadPlan:
        """Ranges, spindle loads and diagnoses for this set of names (kept by
        `_read_plan`)."""
        wanted = select_addresses(names, self._all, "channel")
        pmc = [(n, a) for n, a in wanted.items() if isinstance(a, FocasPmcAddress)]
        return _ReadPlan(
            wanted=wanted,
            ranges=tuple(read_ranges(pmc)),
            diags=tuple((n, a) for n, a in wanted.items() if isinstance(a, FocasDiagAddress)),
            sploads=tuple((n, a) for n, a in wanted.items()
                          if isinstance(a, FocasSpindleLoadAddress)))

    async def read(self, names: Sequence[str]) -> dict[str, Sample]:
        plan = self._read_plan(names)
        wanted, ranges, diags, sploads = plan.wanted, plan.ranges, plan.diags, plan.sploads
        read_range = self._read_range

        def op(lib: ctypes.CDLL, h: int) -> dict[str, float]:
            values: dict[str, float] = {}
            for r in ranges:
                data = read_range(lib, h, r, wanted)
                for name in r.names:
                    a = wanted[name]
                    if isinstance(a, FocasPmcAddress):
                        values[name] = decode_pmc(a, data, a.address - r.start)
            if sploads:
                spn = abi.ODBSPN()
                rc = lib.cnc_rdspload(h, -1, ctypes.byref(spn))
                if rc != abi.EW_OK:
                    name, sa = sploads[0]
                    raise abi.error_for(rc, "cnc_rdspload", channel=name, address=sa.describe())
                for name, sa in sploads:
                    values[name] = spn.data[sa.spindle - 1] * sa.scale
            for name, da in diags:
                dgn = abi.ODBDGN()
                rc = lib.cnc_diagnoss(h, da.number, da.axis, 4 + ctypes.sizeof(abi.FLONG),
                                      ctypes.byref(dgn))
                if rc != abi.EW_OK:
                    raise abi.error_for(rc, "cnc_diagnoss", channel=name, address=da.describe())
                values[name] = dgn.u.ldata * da.scale
            return values

        values = await self._call(op, "read")
        now = time.time()
        return {name: Sample(values[name], now, Quality.GOOD) for name in names}

    def _read_range(self, lib: ctypes.CDLL, h: int, r: PmcRange,
                    wanted: Mapping[str, FocasAddress]) -> bytes:
        buf = abi.pmc_buffer(r.size)
        rc = lib.pmc_rdpmcrng(h, PMC_AREAS[r.area], _BYTE, r.start, r.end,
                              abi.PMC_HEADER_BYTES + r.size, buf)
        if rc == abi.EW_OK:
            return bytes(buf[abi.PMC_HEADER_BYTES:abi.PMC_HEADER_BYTES + r.size])
        if rc in abi.ADDRESS_CODES:  # find the channel to blame
            for name in r.names:
                a = wanted[name]
                if not isinstance(a, FocasPmcAddress):
                    continue
                n = PMC_TYPES[a.type][1]
                one = abi.pmc_buffer(n)
                rc1 = lib.pmc_rdpmcrng(h, PMC_AREAS[a.area], _BYTE, a.address,
                                       a.address + n - 1, abi.PMC_HEADER_BYTES + n, one)
                if rc1 != abi.EW_OK:
                    raise abi.error_for(rc1, "pmc_rdpmcrng", channel=name, address=a.describe())
        name = r.names[0]
        raise abi.error_for(rc, "pmc_rdpmcrng", channel=name, address=wanted[name].describe())

    def _build_write_plan(self, names: tuple[str, ...]) -> tuple[
            list[tuple[str, FocasPmcAddress]], list[PmcRange]]:
        """The outputs and their runs for this set of names (kept by `_write_plan`)."""
        wanted = select_addresses(names, self._outputs, "output")
        items = [(n, a) for n, a in wanted.items() if isinstance(a, FocasPmcAddress)]
        return items, write_runs(items)

    async def write(self, values: Mapping[str, float]) -> None:
        items, runs = self._write_plan(tuple(values))
        payload: dict[str, bytes] = {}
        for name, a in items:
            try:
                payload[name] = encode_pmc(a, float(values[name]))
            except (ValueError, TypeError) as exc:
                raise BadAddress(f"cannot encode {values[name]!r}: {exc}", channel=name,
                                 address=a.describe()) from exc

        def op(lib: ctypes.CDLL, h: int) -> None:
            for r in runs:
                data = b"".join(payload[n] for n in r.names)
                buf = abi.pmc_buffer(r.size)
                hdr = abi.IODBPMC.from_buffer(buf)
                hdr.type_a, hdr.type_d = PMC_AREAS[r.area], _BYTE
                hdr.datano_s, hdr.datano_e = r.start, r.end
                ctypes.memmove(ctypes.addressof(buf) + abi.PMC_HEADER_BYTES, data, len(data))
                rc = lib.pmc_wrpmcrng(h, abi.PMC_HEADER_BYTES + r.size, buf)
                if rc != abi.EW_OK:
                    name = r.names[0]
                    raise abi.error_for(rc, "pmc_wrpmcrng", channel=name,
                                        address=dict(items)[name].describe(), writing=True)

        await self._call(op, "write")

