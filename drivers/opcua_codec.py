"""OPC UA values and status codes <-> compd samples and driver errors.

Pure translation, no I/O: which VariantType a node's DataType means, how an
engineering value becomes a Variant of that type (and back), and which status
codes are a quality, a bad address, a permanent or transient write refusal,
or a lost session.
"""

from __future__ import annotations

import math
import time
from datetime import UTC, datetime

from asyncua import ua
from asyncua.ua.status_codes import StatusCodes

from drivers.addresses import OpcUaAddress
from drivers.base import Quality, Sample
from drivers.encodings import ENCODINGS, FLOAT32_MAX, Encoding
from drivers.errors import BadAddress

_VT = ua.VariantType
_SC = StatusCodes

#: numeric variant types and their encodings (`drivers.encodings`)
VARIANT_ENCODINGS: dict[ua.VariantType, Encoding] = {
    vt: ENCODINGS[name] for vt, name in (
        (_VT.SByte, "int8"), (_VT.Byte, "uint8"), (_VT.Int16, "int16"),
        (_VT.UInt16, "uint16"), (_VT.Int32, "int32"), (_VT.UInt32, "uint32"),
        (_VT.Int64, "int64"), (_VT.UInt64, "uint64"), (_VT.Float, "float32"),
        (_VT.Double, "float64"))}
#: integer variant types and their inclusive ranges
INT_RANGES: dict[ua.VariantType, tuple[int, int]] = {
    vt: (int(enc.lo), int(enc.hi)) for vt, enc in VARIANT_ENCODINGS.items() if enc.integer}
FLOAT_TYPES = frozenset(vt for vt, enc in VARIANT_ENCODINGS.items() if not enc.integer)
WRITABLE_TYPES = frozenset({*INT_RANGES, *FLOAT_TYPES, _VT.Boolean})

#: ns=0 data types derived from a numeric builtin (Part 5/6): id -> variant type
_DERIVED_TYPES: dict[int, ua.VariantType] = {
    290: _VT.Double,   # Duration
    288: _VT.UInt32,   # IntegerId
    289: _VT.UInt32,   # Counter
    29: _VT.Int32,     # Enumeration (and its subtypes are sent as Int32)
}

#: a Read or Write result meaning "no such node / attribute here"
ADDRESS_CODES = frozenset({_SC.BadNodeIdUnknown, _SC.BadNodeIdInvalid,
                           _SC.BadAttributeIdInvalid, _SC.BadNotReadable})
#: a write refusal retrying cannot cure
PERMANENT_WRITE_CODES = frozenset({
    _SC.BadTypeMismatch, _SC.BadNotWritable, _SC.BadUserAccessDenied,
    _SC.BadWriteNotSupported, _SC.BadOutOfRange, _SC.BadIndexRangeInvalid,
    _SC.BadIndexRangeNoData, _SC.BadNotSupported})
#: a service fault meaning the session/channel is gone: reconnect
SESSION_CODES = frozenset({
    _SC.BadSessionIdInvalid, _SC.BadSessionClosed, _SC.BadSessionNotActivated,
    _SC.BadSecureChannelIdInvalid, _SC.BadSecureChannelClosed,
    _SC.BadSecureChannelTokenUnknown, _SC.BadConnectionClosed, _SC.BadServerHalted,
    _SC.BadShutdown, _SC.BadCommunicationError, _SC.BadNotConnected,
    _SC.BadServerNotConnected, _SC.BadIdentityTokenInvalid,
    _SC.BadIdentityTokenRejected})


def status_name(code: int) -> str:
    """``BadTypeMismatch`` for a status code value (hex when unknown)."""
    name = ua.StatusCode(ua.UInt32(code)).name
    return name if name and not name.startswith("Unknown") else f"0x{code:08X}"


def variant_type_of(datatype: ua.NodeId) -> ua.VariantType | None:
    """The VariantType to write to a node whose DataType attribute is
    `datatype`; None when it is not a numeric/boolean builtin we can encode."""
    if datatype.NamespaceIndex != 0 or not isinstance(datatype.Identifier, int):
        return None
    ident = datatype.Identifier
    if ident in _DERIVED_TYPES:
        return _DERIVED_TYPES[ident]
    if 1 <= ident <= 25:
        vt = _VT(ident)
        return vt if vt in WRITABLE_TYPES else None
    return None


def encode(value: float, address: OpcUaAddress, vtype: ua.VariantType,
           channel: str) -> ua.Variant:
    """Engineering value -> Variant of the node's own type (raw = value / scale)."""
    if not math.isfinite(value):
        raise BadAddress(f"cannot write non-finite value {value!r}",
                         channel=channel, address=address.node)
    raw = value / address.scale
    if vtype in FLOAT_TYPES:
        if vtype is _VT.Float and abs(raw) > FLOAT32_MAX:
            raise BadAddress(f"{raw!r} does not fit a Float",
                             channel=channel, address=address.node)
        return ua.Variant(float(raw), vtype)
    if vtype is _VT.Boolean:
        return ua.Variant(raw != 0.0, vtype)
    lo, hi = INT_RANGES[vtype]
    iraw = round(raw)
    if not lo <= iraw <= hi:
        raise BadAddress(f"{iraw} does not fit {vtype.name} [{lo}, {hi}]",
                         channel=channel, address=address.node)
    return ua.Variant(iraw, vtype)


def quality_of(status: ua.StatusCode | None) -> Quality:
    if status is None or status.is_good():
        return Quality.GOOD
    if status.is_uncertain():
        return Quality.UNCERTAIN
    return Quality.BAD


def _timestamp_s(dv: ua.DataValue) -> float:
    ts = dv.SourceTimestamp or dv.ServerTimestamp
    if not isinstance(ts, datetime):
        return time.time()
    if ts.tzinfo is None:
        ts = ts.replace(tzinfo=UTC)
    return ts.timestamp()


def decode(dv: ua.DataValue, address: OpcUaAddress, channel: str) -> Sample:
    """DataValue -> Sample. A Bad status is a BAD quality (value NaN when the
    server sent none); an unknown node raises `BadAddress`."""
    status = dv.StatusCode
    code = status.value if status is not None else _SC.Good
    if code in ADDRESS_CODES:
        raise BadAddress(f"the server answered {status_name(code)}",
                         channel=channel, address=address.node)
    quality = quality_of(status)
    raw = dv.Value.Value if dv.Value is not None else None
    if isinstance(raw, bool | int | float):
        value = float(raw) * address.scale
    elif raw is None and quality is not Quality.GOOD:
        value = float("nan")
    else:
        raise BadAddress(f"value of type {type(raw).__name__} is not a number",
                         channel=channel, address=address.node)
    return Sample(value=value, timestamp_s=_timestamp_s(dv), quality=quality)
