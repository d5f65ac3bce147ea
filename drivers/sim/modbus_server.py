"""A simulated Modbus TCP controller: a real pymodbus 3.16.1 server on 127.0.0.1.

Register map (unit 1, protocol addresses, 0-based as on the wire; a
Modicon-style reference adds 30001 / 40001):

input registers (read-only, what the plant publishes)
    0..4   bearing, motor, column, table, ambient   int16, 0.1 °C per count
           (like a PLC's analog card, so the Pt100 sentinels 32767 / -32768
           are representable)
    5      spindle_rpm  uint16, 1 rpm
    6..7   power_kw     float32, big word order
    8..9   growth_um    float32, big word order
    10..11 error_um     float32, big word order
holding registers (written by the daemon)
    0..1   offset       float32 µm, big word order
    2      heartbeat    uint16
    3      status       uint16
    10..11 enc_f32_little    float32, little word order   (contract `encodings`)
    12..13 enc_i32_milli     int32, 0.001 per count
    14     enc_i16           int16, 1 per count
    15     enc_i16_centi     int16, 0.01 per count
    20     plc_update_permitted  uint16, set by the PLC (`publish`): a permit bit
    21     plc_rezero        uint16, set by the PLC: a re-zero pulse
    32..37, 38..43, 44..49  temperature compensation of axis X, Y, Z, TwinCAT
           units (`drivers.sim.temp_comp`), each an int32, big word order:
           +0 <axis>_comp_reference  P-AXIS-00272 position, 0.1 µm
           +2 <axis>_comp_value      P-AXIS-00273 offset, 0.1 µm
           +4 <axis>_comp_slope      P-AXIS-00274 coefficient, µm/m
           `compensation(axis)` is the line in force
Everything else up to input 31 / holding 63 (or the sizes given) reads as 0;
beyond is an illegal address (exception code 2), e.g. `BAD_ADDRESS`.

The server keeps pymodbus's SimDevice datastore (`SimData` addresses are the
wire addresses, where pymodbus's sequential blocks are one off from them). For tests it
counts every request it receives (`requests`), and can answer a chosen
register range with an exception code (`inject_exception`) or stall every
request until released (`set_hang`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.simulator.simcore import SimCore

from drivers.addresses import Address, ModbusAddress
from drivers.modbus_codec import decode, encode
from drivers.sim.ports import free_tcp_port, start_on_free_port
from drivers.sim.temp_comp import TWINCAT_SCALES, line_of
from drivers.temp_comp import AXES, AxisCompensation, output_name

UNIT = 1
INPUT_REGISTERS = 32
HOLDING_REGISTERS = 64


def _temp(address: int) -> ModbusAddress:
    return ModbusAddress(unit=UNIT, kind="input", address=address, type="int16", scale=0.1)


CHANNELS: dict[str, ModbusAddress] = {
    "bearing": _temp(0),
    "motor": _temp(1),
    "column": _temp(2),
    "table": _temp(3),
    "ambient": _temp(4),
    "spindle_rpm": ModbusAddress(unit=UNIT, kind="input", address=5, type="uint16"),
    "power_kw": ModbusAddress(unit=UNIT, kind="input", address=6, type="float32"),
    "growth_um": ModbusAddress(unit=UNIT, kind="input", address=8, type="float32"),
    "error_um": ModbusAddress(unit=UNIT, kind="input", address=10, type="float32"),
}
PROBES: dict[str, ModbusAddress] = {
    "probe_value": ModbusAddress(unit=UNIT, kind="input", address=12, type="float32"),
    "probe_counter": ModbusAddress(unit=UNIT, kind="input", address=14, type="uint16"),
}
OUTPUTS: dict[str, ModbusAddress] = {
    "offset": ModbusAddress(unit=UNIT, kind="holding", address=0, type="float32"),
    "heartbeat": ModbusAddress(unit=UNIT, kind="holding", address=2, type="uint16"),
    "status": ModbusAddress(unit=UNIT, kind="holding", address=3, type="uint16"),
}
ENCODINGS: dict[str, ModbusAddress] = {
    "enc_f32_little": ModbusAddress(unit=UNIT, kind="holding", address=10, type="float32",
                                    word_order="little"),
    "enc_i32_milli": ModbusAddress(unit=UNIT, kind="holding", address=12, type="int32",
                                   scale=0.001),
    "enc_i16": ModbusAddress(unit=UNIT, kind="holding", address=14, type="int16"),
    "enc_i16_centi": ModbusAddress(unit=UNIT, kind="holding", address=15, type="int16",
                                   scale=0.01),
}
#: the PLC's bits a daemon may read (`[output] update_permitted`, `rezero`): holding
#: registers the PLC sets (`publish`), 0 at start
PLC: dict[str, ModbusAddress] = {
    "plc_update_permitted": ModbusAddress(unit=UNIT, kind="holding", address=20, type="uint16"),
    "plc_rezero": ModbusAddress(unit=UNIT, kind="holding", address=21, type="uint16"),
}
#: the first holding register of each axis's compensation parameters
AXIS_REGISTERS: dict[str, int] = {"x": 32, "y": 38, "z": 44}
#: TwinCAT's order: P-AXIS-00272 position, 00273 offset, 00274 coefficient
_TWINCAT_ORDER: tuple[str, ...] = ("reference", "value", "slope")
TEMP_COMP: dict[str, ModbusAddress] = {
    output_name(axis, p): ModbusAddress(unit=UNIT, kind="holding",
                                        address=AXIS_REGISTERS[axis] + 2 * i, type="int32",
                                        scale=TWINCAT_SCALES[p])
    for axis in AXES for i, p in enumerate(_TWINCAT_ORDER)}
#: each axis's present position (mm, float32 input registers the PLC keeps current) and
#: a plain offset per axis (µm, float32 holding registers) for a controller without
#: compensation parameters: it applies the offset as it is at whatever position
POSITIONS: dict[str, ModbusAddress] = {
    f"{axis}_position": ModbusAddress(unit=UNIT, kind="input", address=16 + 2 * i,
                                      type="float32")
    for i, axis in enumerate(AXES)}
AXIS_OFFSETS: dict[str, ModbusAddress] = {
    output_name(axis, "offset"): ModbusAddress(unit=UNIT, kind="holding",
                                               address=50 + 2 * i, type="float32")
    for i, axis in enumerate(AXES)}
#: valid for the protocol, absent on this server
BAD_ADDRESS = ModbusAddress(unit=UNIT, kind="holding", address=5000, type="float32")

_READ_KIND = {3: "holding", 4: "input", 23: "holding"}
_WRITE_KIND = {6: "holding", 16: "holding", 22: "holding", 23: "holding"}


@dataclass
class Fault:
    """Answer requests touching [address, address + count) of `kind` with `code`."""

    kind: Literal["holding", "input"]
    address: int
    count: int
    code: int
    on: Literal["read", "write", "both"]


@dataclass(frozen=True)
class Request:
    """One request as the server received it."""

    unit: int
    function_code: int
    address: int
    count: int


class ModbusSimController:
    """See the module docstring. Implements `drivers.sim.base.SimController`."""

    protocol = "modbus"

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *,
                 input_registers: int = INPUT_REGISTERS,
                 holding_registers: int = HOLDING_REGISTERS, **options: Any) -> None:
        if options:
            raise TypeError(f"unknown options for the Modbus sim: {sorted(options)}")
        if not (INPUT_REGISTERS <= input_registers <= 65536
                and HOLDING_REGISTERS <= holding_registers <= 65536):
            raise ValueError("register tables must hold at least the standard map")
        self.input_registers = input_registers
        self.holding_registers = holding_registers
        self.host = host
        #: the port was picked here (not named by the caller): it may be picked again
        self._picked = not port
        self.port = port or free_tcp_port(host)
        self.endpoint = f"modbus://{host}:{self.port}"
        self.channels: dict[str, Address] = dict(CHANNELS)
        self.outputs_map: dict[str, Address] = dict(OUTPUTS)
        self.encodings: dict[str, ModbusAddress] = dict(ENCODINGS)
        self.probes: dict[str, Address] = dict(PROBES)
        self.temp_comp: dict[str, ModbusAddress] = dict(TEMP_COMP)
        self.positions: dict[str, ModbusAddress] = dict(POSITIONS)
        self.axis_offsets: dict[str, ModbusAddress] = dict(AXIS_OFFSETS)
        self.requests: list[Request] = []
        self.faults: list[Fault] = []
        self._input = [0] * input_registers
        self._holding = [0] * holding_registers
        self._server: ModbusTcpServer | None = None
        self._release = asyncio.Event()
        self._release.set()

    # -- lifecycle ----------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._server is not None

    async def start(self) -> None:
        if self._server is not None:
            return
        bits = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        device = SimDevice(
            id=UNIT,
            simdata=(list(bits), list(bits),
                     [SimData(0, values=list(self._holding), datatype=DataType.REGISTERS)],
                     [SimData(0, values=list(self._input), datatype=DataType.REGISTERS)]),
            action=self._action,
        )
        server: ModbusTcpServer | None = None

        async def listen() -> None:
            nonlocal server
            server = ModbusTcpServer(device, address=(self.host, self.port),
                                     trace_pdu=self._trace_pdu)
            await server.serve_forever(background=True)

        await start_on_free_port(listen, self._repick, picked=self._picked,
                                 taken=_listen_failed)
        assert server is not None
        # From here on the server's own register lists are the state.
        if not isinstance(server.context, SimCore):
            raise RuntimeError("pymodbus did not build a SimCore datastore")
        runtime = server.context.devices[UNIT]
        self._input = runtime.block["i"][2]
        self._holding = runtime.block["h"][2]
        self._server = server

    def _repick(self) -> None:
        self.port = free_tcp_port(self.host)
        self.endpoint = f"modbus://{self.host}:{self.port}"

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is None:
            return
        self._release.set()
        # Keep the register images (minus pymodbus's trailing guard register).
        self._input = list(self._input[:self.input_registers])
        self._holding = list(self._holding[:self.holding_registers])
        await server.shutdown()  # type: ignore[no-untyped-call]  # untyped in pymodbus
        await asyncio.sleep(0)  # let the closed connections' callbacks run

    # -- plant side -----------------------------------------------------------

    async def publish(self, values: Mapping[str, float]) -> None:
        """Set channel (input register) values; outputs and encodings may be
        set too (as the PLC would)."""
        for name, value in values.items():
            addr = self._address(name)
            self._poke(addr, encode(addr, value, channel=name))

    async def outputs(self) -> dict[str, float]:
        return {name: decode(addr, self._peek(addr)) for name, addr in OUTPUTS.items()}

    async def read_values(self, names: list[str]) -> dict[str, float]:
        """Current engineering values of any known names (tests)."""
        return {name: decode(a, self._peek(a)) for name in names
                for a in [self._address(name)]}

    async def forget_outputs(self) -> None:
        """Outputs, every axis's compensation parameters and offset back at 0 (a
        restart)."""
        for addr in (*OUTPUTS.values(), *TEMP_COMP.values(), *AXIS_OFFSETS.values()):
            self._poke(addr, [0] * addr.count)

    async def compensation(self, axis: str) -> AxisCompensation:
        """The line the controller applies to `axis` now (its parameters)."""
        return line_of({name: decode(addr, self._peek(addr)) for name, addr in TEMP_COMP.items()
                        if name.startswith(f"{axis}_")}, axis)

    def set_raw(self, kind: Literal["holding", "input"], address: int,
                registers: list[int]) -> None:
        """Set raw register words (e.g. a sentinel 0x7FFF)."""
        table = self._input if kind == "input" else self._holding
        table[address: address + len(registers)] = [r & 0xFFFF for r in registers]

    def raw(self, kind: Literal["holding", "input"], address: int, count: int) -> list[int]:
        table = self._input if kind == "input" else self._holding
        return list(table[address: address + count])

    # -- fault injection --------------------------------------------------------

    def inject_exception(self, kind: Literal["holding", "input"], address: int, code: int,
                         *, count: int = 1,
                         on: Literal["read", "write", "both"] = "both") -> None:
        """Answer requests touching these registers with exception `code`."""
        self.faults.append(Fault(kind, address, count, code, on))

    def clear_faults(self) -> None:
        self.faults.clear()
        self._release.set()

    def set_hang(self, hang: bool) -> None:
        """Hold every request unanswered (a hung controller) until released;
        `stop()` releases too."""
        if hang:
            self._release.clear()
        else:
            self._release.set()

    # -- internals ----------------------------------------------------------------

    def _address(self, name: str) -> ModbusAddress:
        for table in (CHANNELS, OUTPUTS, ENCODINGS, PROBES, PLC, TEMP_COMP, POSITIONS,
                      AXIS_OFFSETS):
            if name in table:
                return table[name]
        raise KeyError(f"the Modbus sim has no channel or output {name!r}")

    def _poke(self, addr: ModbusAddress, words: list[int]) -> None:
        self.set_raw(addr.kind, addr.address, words)

    def _peek(self, addr: ModbusAddress) -> list[int]:
        return self.raw(addr.kind, addr.address, addr.count)

    def _trace_pdu(self, sending: bool, pdu: Any) -> Any:
        if not sending:
            count = getattr(pdu, "count", None) or len(getattr(pdu, "registers", []) or [1])
            self.requests.append(Request(int(pdu.dev_id), int(pdu.function_code),
                                         int(getattr(pdu, "address", 0)), int(count)))
        return pdu

    async def _action(self, function_code: int, _start: int, address: int, count: int,
                      _registers: list[int], set_values: list[int] | list[bool] | None
                      ) -> ExcCodes | None:
        if not self._release.is_set():
            await self._release.wait()
            if self._server is None:
                return ExcCodes.DEVICE_FAILURE
        writing = set_values is not None
        kind = (_WRITE_KIND if writing else _READ_KIND).get(function_code)
        for fault in self.faults:
            if fault.kind != kind or fault.on not in ("both", "write" if writing else "read"):
                continue
            if address < fault.address + fault.count and fault.address < address + count:
                return ExcCodes(fault.code)
        return None


def _listen_failed(exc: BaseException) -> bool:
    """pymodbus's server reports a bind that failed as this RuntimeError, the
    errno dropped: on a port picked on 127.0.0.1, the port was taken."""
    return isinstance(exc, RuntimeError) and "could not start listen" in str(exc).lower()
