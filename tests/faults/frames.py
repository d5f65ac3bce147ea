"""Frame lengths and request kinds of the three TCP protocols, for counting
requests at the proxy (`tests.faults.proxy.FaultProxy(frame_length=...)`).

Only the outer framing is parsed: Modbus TCP's MBAP header, S7's TPKT
(RFC 1006) + COTP data header, OPC UA's message header (no security, so the
request's type id is readable).
"""

from __future__ import annotations

from collections.abc import Callable

from tests.faults.proxy import FrameLength

#: Modbus function codes that write (coils, registers, read/write multiple)
_MODBUS_WRITES = frozenset({5, 6, 15, 16, 22, 23})
#: S7 job functions: 0x04 read var, 0x05 write var
_S7_WRITE = 0x05
#: OPC UA binary encoding ids of the service requests (ns=0)
_OPCUA_WRITE_REQUEST = 673


def modbus_frame_length(buf: bytes) -> int | None:
    """MBAP: transaction(2) protocol(2) length(2), then `length` bytes."""
    if len(buf) < 6:
        return None
    return 6 + int.from_bytes(buf[4:6], "big")


def s7_frame_length(buf: bytes) -> int | None:
    """TPKT: version(1) reserved(1) length(2) counting the whole packet."""
    if len(buf) < 4:
        return None
    return int.from_bytes(buf[2:4], "big")


def opcua_frame_length(buf: bytes) -> int | None:
    """OPC UA TCP: type(3) chunk(1) size(4, little-endian) counting the whole chunk."""
    if len(buf) < 8:
        return None
    return int.from_bytes(buf[4:8], "little")


def modbus_is_write(frame: bytes) -> bool:
    return len(frame) > 7 and frame[7] in _MODBUS_WRITES


def s7_is_write(frame: bytes) -> bool:
    """TPKT(4) + COTP (length indicator + that many bytes) + S7 job header (10)."""
    if len(frame) < 6:
        return False
    s7 = 4 + 1 + frame[4]
    return (len(frame) > s7 + 10 and frame[s7] == 0x32 and frame[s7 + 1] == 0x01
            and frame[s7 + 10] == _S7_WRITE)


def opcua_is_write(frame: bytes) -> bool:
    """A 'MSG' chunk whose body starts with the WriteRequest's four-byte NodeId
    (after the channel id, token id, sequence number and request id)."""
    if len(frame) < 28 or frame[:3] != b"MSG":
        return False
    # four-byte NodeId: 0x01, ns (1 byte), id (2 bytes); a two-byte one has id < 256
    return (frame[24] == 0x01 and frame[25] == 0
            and int.from_bytes(frame[26:28], "little") == _OPCUA_WRITE_REQUEST)


FRAME_LENGTH: dict[str, FrameLength] = {
    "modbus": modbus_frame_length,
    "s7": s7_frame_length,
    "opcua": opcua_frame_length,
}
IS_WRITE: dict[str, Callable[[bytes], bool]] = {
    "modbus": modbus_is_write,
    "s7": s7_is_write,
    "opcua": opcua_is_write,
}
