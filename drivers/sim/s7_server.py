"""A simulated S7 CPU: python-snap7's own server on 127.0.0.1.

Memory layout (big-endian, non-optimised DBs as on an S7-300/400):

DB1 (inputs, 32 bytes)
    0 bearing INT ×0.1 °C   2 motor INT ×0.1 °C   4 column INT ×0.1 °C
    6 table INT ×0.1 °C     8 ambient INT ×0.1 °C
    10 spindle_rpm DINT     14 power_kw REAL      18 growth_um REAL   22 error_um REAL
  Temperatures are INT tenths of a degree so that a Pt100 card's open/short
  sentinels (raw 32767 / -32768) are representable and pass through.
DB2 (outputs, 16 bytes)
    0 offset REAL µm        4 heartbeat DINT      8 status WORD
DB3 (encodings, 16 bytes)
    0 enc_int INT ×0.1      2 enc_dint_milli DINT ×0.001
    6 enc_real REAL         10 enc_word WORD
DB10, DB11, DB12 (temperature compensation of axis X, Y, Z; 12 bytes each,
  SINUMERIK units, `drivers.sim.temp_comp`)
    0 <axis>_comp_value REAL mm (SD43900)   4 <axis>_comp_slope REAL tan β (SD43910)
    8 <axis>_comp_reference REAL mm (SD43920)
  The PLC hands them on to the NCK; `compensation(axis)` is the line in force.

The DB buffers are bytearrays registered with the server (it serves the very
same objects); `publish`/`outputs` go through the server's own area locks.
`stop()` also shuts the open client connections (snap7's server would let a
connected client get one more answer), so a stopped CPU looks stopped.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
from collections.abc import Iterator, Mapping
from typing import Any

from snap7.server import Server
from snap7.type import SrvArea

from drivers.addresses import Address, S7Address
from drivers.s7_codec import decode, encode
from drivers.sim.ports import free_tcp_port, start_on_free_port
from drivers.sim.temp_comp import SINUMERIK_SCALES, line_of
from drivers.temp_comp import AXES, PARAMETERS, AxisCompensation, output_name

INPUT_DB, OUTPUT_DB, ENCODING_DB = 1, 2, 3
#: one data block per axis for its temperature-compensation parameters
AXIS_DBS: dict[str, int] = {"x": 10, "y": 11, "z": 12}
#: the channel's tool temperature compensation (SD42960, mm) as a REAL at byte 0
TOOL_DB = 13
_SIZES = {INPUT_DB: 40, OUTPUT_DB: 16, ENCODING_DB: 16, **dict.fromkeys(AXIS_DBS.values(), 12),
          TOOL_DB: 4}

CHANNELS: dict[str, S7Address] = {
    "bearing": S7Address(db=1, offset=0, type="INT", scale=0.1),
    "motor": S7Address(db=1, offset=2, type="INT", scale=0.1),
    "column": S7Address(db=1, offset=4, type="INT", scale=0.1),
    "table": S7Address(db=1, offset=6, type="INT", scale=0.1),
    "ambient": S7Address(db=1, offset=8, type="INT", scale=0.1),
    "spindle_rpm": S7Address(db=1, offset=10, type="DINT"),
    "power_kw": S7Address(db=1, offset=14, type="REAL"),
    "growth_um": S7Address(db=1, offset=18, type="REAL"),
    "error_um": S7Address(db=1, offset=22, type="REAL"),
}
PROBES: dict[str, S7Address] = {
    "probe_value": S7Address(db=1, offset=26, type="REAL"),
    "probe_counter": S7Address(db=1, offset=30, type="DINT"),
}
OUTPUTS: dict[str, S7Address] = {
    "offset": S7Address(db=2, offset=0, type="REAL"),
    "heartbeat": S7Address(db=2, offset=4, type="DINT"),
    "status": S7Address(db=2, offset=8, type="WORD"),
}
ENCODINGS: dict[str, S7Address] = {
    "enc_int": S7Address(db=3, offset=0, type="INT", scale=0.1),
    "enc_dint_milli": S7Address(db=3, offset=2, type="DINT", scale=0.001),
    "enc_real": S7Address(db=3, offset=6, type="REAL"),
    "enc_word": S7Address(db=3, offset=10, type="WORD"),
}

#: each axis's value, slope and reference as REALs at bytes 0, 4, 8 of its DB
TEMP_COMP: dict[str, S7Address] = {
    output_name(axis, p): S7Address(db=AXIS_DBS[axis], offset=4 * i, type="REAL",
                                    scale=SINUMERIK_SCALES[p])
    for axis in AXES for i, p in enumerate(PARAMETERS)}
TOOL_COMP: dict[str, S7Address] = {
    output_name("tool", "value"): S7Address(db=TOOL_DB, offset=0, type="REAL",
                                            scale=SINUMERIK_SCALES["value"])}


class _Server(Server):
    """snap7's server, remembering client sockets so stop() can close them."""

    def __init__(self) -> None:
        super().__init__(log=False)
        self._socks: set[socket.socket] = set()
        self._socks_lock = threading.Lock()
        #: S7 requests served, by function code (0x04 read, 0x05 write, 0xF0 setup)
        self.requests: dict[int, int] = {}
        #: while set, requests are swallowed without an answer (a hung CPU)
        self.frozen = threading.Event()

    def _process_request(self, request_data: bytes, client_address: Any) -> bytes | None:
        if self.frozen.is_set():
            return None
        if len(request_data) > 10 and request_data[0] == 0x32 and request_data[1] == 0x01:
            header_len = 12 if request_data[1] in (0x02, 0x03) else 10
            function = request_data[header_len]
            self.requests[function] = self.requests.get(function, 0) + 1
        response: bytes | None = super()._process_request(request_data, client_address)
        return response

    def _handle_client(self, client_socket: socket.socket, address: Any) -> None:
        with self._socks_lock:
            self._socks.add(client_socket)
        try:
            super()._handle_client(client_socket, address)
        finally:
            with self._socks_lock:
                self._socks.discard(client_socket)

    def drop_clients(self) -> None:
        with self._socks_lock:
            socks = list(self._socks)
        for s in socks:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)


def _clamp(addr: S7Address, value: float) -> float:
    """A plant value saturates like an analog card instead of wrapping."""
    enc = addr.encoding
    if not enc.integer:
        return value
    raw = min(max(round(value / addr.scale), int(enc.lo)), int(enc.hi))
    return raw * addr.scale


class S7SimController:
    """A real S7 server (python-snap7) standing in for the machine's CPU."""

    protocol = "s7"

    def __init__(self, host: str = "127.0.0.1", port: int = 0, **options: Any) -> None:
        if options:
            raise TypeError(f"unknown S7 sim options: {sorted(options)}")
        self.host = host
        #: the port was picked here (not named by the caller): it may be picked again
        self._picked = not port
        self.port = port or free_tcp_port(host)
        self.endpoint = f"s7://{host}:{self.port}"
        self.channels: dict[str, Address] = dict(CHANNELS)
        self.outputs_map: dict[str, Address] = dict(OUTPUTS)
        self.encodings: dict[str, S7Address] = dict(ENCODINGS)
        self.probes: dict[str, Address] = dict(PROBES)
        self.temp_comp: dict[str, S7Address] = dict(TEMP_COMP)
        self.tool_comp: dict[str, S7Address] = dict(TOOL_COMP)
        self._table: dict[str, S7Address] = {**CHANNELS, **OUTPUTS, **ENCODINGS, **PROBES,
                                             **TEMP_COMP, **TOOL_COMP}
        self._dbs = {db: bytearray(size) for db, size in _SIZES.items()}
        self._server: _Server | None = None

    @property
    def running(self) -> bool:
        return self._server is not None

    def request_counts(self) -> dict[int, int]:
        """S7 requests served since start, by function (0x04 read, 0x05 write)."""
        return dict(self._server.requests) if self._server is not None else {}

    def freeze(self, frozen: bool = True) -> None:
        """Model a hung CPU: connections stay open, requests get no answer."""
        if self._server is not None:
            if frozen:
                self._server.frozen.set()
            else:
                self._server.frozen.clear()

    async def start(self) -> None:
        if self._server is not None:
            return
        server = _Server()
        for db, buf in self._dbs.items():
            server.register_area(SrvArea.DB, db, buf)

        async def listen() -> None:
            server.start_to(self.host, self.port)

        await start_on_free_port(listen, self._repick, picked=self._picked)
        self._server = server

    def _repick(self) -> None:
        self.port = free_tcp_port(self.host)
        self.endpoint = f"s7://{self.host}:{self.port}"

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is None:
            return
        server.drop_clients()
        await asyncio.to_thread(server.stop)
        server.drop_clients()

    def _put(self, name: str, value: float) -> None:
        addr = self._table[name]
        data = encode(addr, _clamp(addr, value))
        buf = self._dbs[addr.db]
        with self._lock(addr.db):
            buf[addr.offset:addr.offset + addr.size] = data

    @contextlib.contextmanager
    def _lock(self, db: int) -> Iterator[None]:
        """The server's own lock of a DB (held while it serves a request)."""
        server = self._server
        if server is None:
            yield
            return
        server.lock_area(SrvArea.DB, db)
        try:
            yield
        finally:
            server.unlock_area(SrvArea.DB, db)

    async def publish(self, values: Mapping[str, float]) -> None:
        unknown = sorted(set(values) - set(self._table))
        if unknown:
            raise KeyError(f"unknown S7 sim names: {unknown}")
        for name, value in values.items():
            self._put(name, float(value))

    async def outputs(self) -> dict[str, float]:
        result = {}
        for name, addr in OUTPUTS.items():
            with self._lock(addr.db):
                result[name] = decode(addr, self._dbs[addr.db], addr.offset)
        return result

    async def read_back(self, name: str) -> float:
        """Any simulated value by name (channels, outputs, encodings)."""
        addr = self._table[name]
        with self._lock(addr.db):
            return decode(addr, self._dbs[addr.db], addr.offset)

    async def forget_outputs(self) -> None:
        """Outputs and every axis's compensation parameters back at 0 (a restart)."""
        for db in (OUTPUT_DB, *AXIS_DBS.values(), TOOL_DB):
            buf = self._dbs[db]
            with self._lock(db):
                buf[:] = bytes(len(buf))

    async def compensation(self, axis: str) -> AxisCompensation:
        """The line the controller applies to `axis` now (its DB's parameters)."""
        return line_of({name: await self.read_back(name) for name in TEMP_COMP
                        if name.startswith(f"{axis}_")}, axis)
