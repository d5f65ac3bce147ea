"""Register encoding and request planning for Modbus (pure functions)."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.addresses import ModbusAddress
from drivers.errors import BadAddress
from drivers.modbus_codec import (
    MAX_READ_REGISTERS,
    ValueOutOfRangeError,
    decode,
    decode_at,
    encode,
    plan_reads,
    plan_writes,
)


def addr(address: int = 0, type_: str = "float32", **kw: object) -> ModbusAddress:
    return ModbusAddress.model_validate({"address": address, "type": type_, **kw})


def test_float32_word_orders() -> None:
    big = addr(word_order="big")
    little = addr(word_order="little")
    assert encode(big, 1.5) == [0x3FC0, 0x0000]
    assert encode(little, 1.5) == [0x0000, 0x3FC0]
    assert decode(big, [0x3FC0, 0x0000]) == 1.5
    assert decode(little, [0x0000, 0x3FC0]) == 1.5
    assert decode(big, encode(big, -273.15)) == pytest.approx(-273.15, abs=1e-4)


def test_int32_word_orders_and_sign() -> None:
    big = addr(type_="int32")
    little = addr(type_="int32", word_order="little")
    assert encode(big, -2) == [0xFFFF, 0xFFFE]
    assert encode(little, 0x12345678) == [0x5678, 0x1234]
    assert decode(big, [0xFFFF, 0xFFFE]) == -2
    assert decode(little, [0x5678, 0x1234]) == 0x12345678


def test_int16_is_signed_uint16_is_not() -> None:
    assert decode(addr(type_="int16"), [0xFFFF]) == -1
    assert decode(addr(type_="uint16"), [0xFFFF]) == 65535
    assert encode(addr(type_="int16"), -1) == [0xFFFF]
    assert encode(addr(type_="int16"), -32768) == [0x8000]


def test_scaled_integers() -> None:
    temp = addr(type_="int16", scale=0.1)
    assert encode(temp, 21.5) == [215]
    assert decode(temp, [215]) == pytest.approx(21.5)
    # the Pt100 sentinels of a PLC analog card stay representable (not filtered here)
    assert decode(temp, [0x7FFF]) == pytest.approx(3276.7)
    assert decode(temp, [0x8000]) == pytest.approx(-3276.8)
    milli = addr(type_="int32", scale=0.001)
    assert encode(milli, -123.456) == list(struct.unpack(">HH", struct.pack(">i", -123456)))


@pytest.mark.parametrize(("type_", "scale", "value"), [
    ("int16", 0.1, 3276.8),      # raw 32768
    ("int16", 0.1, -3276.9),     # raw -32769
    ("uint16", 1.0, -1.0),
    ("uint16", 1.0, 65536.0),
    ("int32", 0.001, 2147483.648),
    ("int16", 1.0, math.nan),
    ("uint16", 1.0, math.inf),
    ("float32", 1.0, 1e39),
])
def test_out_of_range_is_refused(type_: str, scale: float, value: float) -> None:
    a = addr(type_=type_, scale=scale)
    with pytest.raises(ValueOutOfRangeError) as caught:
        encode(a, value, channel="offset")
    assert isinstance(caught.value, BadAddress)
    assert isinstance(caught.value, ValueError)
    assert caught.value.channels == ("offset",)
    assert a.describe() in str(caught.value)


def test_edges_of_range_fit() -> None:
    assert encode(addr(type_="int16", scale=0.1), 3276.7) == [0x7FFF]
    assert encode(addr(type_="uint16"), 65535) == [0xFFFF]
    assert encode(addr(type_="int32"), -(2**31)) == [0x8000, 0x0000]


@given(st.integers(-(2**31), 2**31 - 1), st.sampled_from(["big", "little"]),
       st.sampled_from([1.0, 0.001, 0.5]))
def test_int32_round_trip(raw: int, order: str, scale: float) -> None:
    a = addr(type_="int32", word_order=order, scale=scale)
    assert round(decode(a, encode(a, raw * scale)) / scale) == raw


@given(st.floats(width=32, allow_nan=False, allow_infinity=False),
       st.sampled_from(["big", "little"]))
def test_float32_round_trip_is_exact(value: float, order: str) -> None:
    a = addr(word_order=order)
    assert decode(a, encode(a, value)) == value


def _items(*addresses: ModbusAddress) -> list[tuple[str, ModbusAddress]]:
    return [(f"c{i}", a) for i, a in enumerate(addresses)]


def test_plan_merges_small_gaps_and_groups_by_unit_and_kind() -> None:
    spans = plan_reads(_items(
        addr(0, "int16", kind="input"), addr(1, "int16", kind="input"),
        addr(6, kind="input"), addr(0, kind="holding"), addr(0, unit=2, kind="input")))
    got = {(s.unit, s.kind, s.start, s.count) for s in spans}
    assert got == {(1, "input", 0, 8), (1, "holding", 0, 2), (2, "input", 0, 2)}


def test_plan_splits_large_gaps_and_caps_at_125() -> None:
    gap = plan_reads(_items(addr(0), addr(100)), max_gap=8)
    assert [(s.start, s.count) for s in gap] == [(0, 2), (100, 2)]
    near = plan_reads(_items(addr(0), addr(100)), max_gap=200)
    assert [(s.start, s.count) for s in near] == [(0, 102)]
    capped = plan_reads(_items(addr(0), addr(MAX_READ_REGISTERS - 1)), max_gap=200)
    assert [(s.start, s.count) for s in capped] == [(0, 2), (124, 2)]
    exact = plan_reads(_items(addr(0), addr(MAX_READ_REGISTERS - 2)), max_gap=200)
    assert [(s.start, s.count) for s in exact] == [(0, 125)]


def test_plan_many_registers_stays_within_limit() -> None:
    spans = plan_reads(_items(*(addr(i, "int16") for i in range(300))))
    assert [s.count for s in spans] == [125, 125, 50]
    assert sum(len(s.items) for s in spans) == 300


def test_plan_writes_merges_only_back_to_back_registers() -> None:
    writes = plan_writes([
        ("status", addr(3, "uint16"), [5]),
        ("offset", addr(0), [1, 2]),
        ("heartbeat", addr(2, "uint16"), [7]),
        ("far", addr(10, "uint16"), [9]),
    ])
    assert [(s.start, s.count, s.names, words) for s, words in writes] == [
        (0, 4, ("offset", "heartbeat", "status"), [1, 2, 7, 5]),
        (10, 1, ("far",), [9]),
    ]


@pytest.mark.parametrize("kind", ["uint16", "int16", "int32", "float32"])
@pytest.mark.parametrize("order", ["big", "little"])
def test_decode_at_an_offset_of_a_span_is_decode_of_its_registers(kind: str,
                                                                  order: str) -> None:
    """The driver decodes each value in place in its read's span (no copy per value):
    the same value as decoding its own registers, signs and word orders included."""
    addr = ModbusAddress(address=0, type=kind, word_order=order, scale=0.5)  # type: ignore[arg-type]
    span = [0x1234, 0x8000, 0xFFFF, 0x0001, 0x7FFF, 0xC2F6]
    for offset in range(len(span) - 1):
        got, alone = decode_at(addr, span, offset), decode(addr, span[offset:offset + addr.count])
        assert got == alone or (math.isnan(got) and math.isnan(alone))  # 0xFFFF..: a NaN
    if kind != "float32" and (kind != "int32" or order == "big"):  # 0xFFFF, 0x0001
        assert decode_at(addr, span, 2) == {"uint16": 32767.5, "int16": -0.5,
                                            "int32": -32767.5}[kind]
