"""Address footprints: the cells each address occupies, the clash rule, and a
property holding the footprints to what the codecs actually write."""

from __future__ import annotations

import itertools
from typing import Any

import pytest
from asyncua import ua
from hypothesis import given
from hypothesis import strategies as st
from pydantic import TypeAdapter

from drivers import focas_codec, modbus_codec, s7_codec
from drivers.addresses import (
    Address,
    FocasAddress,
    FocasPmcAddress,
    ModbusAddress,
    OpcUaAddress,
    S7Address,
)
from drivers.encodings import ENCODINGS, MODBUS_TYPES, PMC_ENCODINGS, S7_TYPES
from drivers.footprint import Footprint, Use, first_clash

_FOCAS = TypeAdapter(FocasAddress)


def mb(address: int, type_: str = "float32", **kw: Any) -> ModbusAddress:
    return ModbusAddress.model_validate({"address": address, "type": type_, **kw})


def s7(offset: int, type_: str = "REAL", db: int = 1, **kw: Any) -> S7Address:
    return S7Address.model_validate({"db": db, "offset": offset, "type": type_, **kw})


def pmc(address: int, type_: str = "long", area: str = "D", **kw: Any) -> FocasPmcAddress:
    return FocasPmcAddress.model_validate({"area": area, "address": address, "type": type_,
                                           **kw})


def overlaps(a: Address, b: Address) -> bool:
    fa, fb = a.footprint(), b.footprint()
    return fa is not None and fb is not None and fa.overlap(fb) is not None


# -- footprints per protocol, edge-adjacent spans included ----------------------

@pytest.mark.parametrize(("a", "b", "expected"), [
    # Modbus: registers by the type's width, per unit and table
    (mb(0), mb(1, "uint16"), True),            # float32 0-1 and register 1: an overlap
    (mb(0), mb(2, "uint16"), False),           # edge-adjacent: 0-1 and 2
    (mb(1, "int32"), mb(0, "int16"), False),   # 1-2 and 0
    (mb(1, "int32"), mb(2, "int16"), True),
    (mb(0), mb(1, "uint16", kind="input"), False),   # another table
    (mb(0), mb(1, "uint16", unit=2), False),         # another unit
    # S7: DB bytes by the type's size, per DB
    (s7(0), s7(3, "INT"), True),               # REAL 0-3 and INT 3-4
    (s7(0), s7(4, "INT"), False),              # edge-adjacent
    (s7(2, "WORD"), s7(0, "INT"), False),      # 2-3 and 0-1
    (s7(2, "DINT"), s7(5, "WORD"), True),      # 2-5 and 5-6: one shared byte
    (s7(0), s7(0, db=2), False),               # another DB
    # FOCAS PMC: bytes by the type's size, per area
    (pmc(100), pmc(103, "byte"), True),        # long 100-103 and byte 103
    (pmc(100), pmc(104), False),               # edge-adjacent
    (pmc(100, "double"), pmc(104), True),      # a double is 8 bytes
    (pmc(100), pmc(100, area="R"), False),     # another area
    # OPC UA: one node, the same node however spelt
    (OpcUaAddress(node="ns=2;i=42"), OpcUaAddress(node="ns=2;i=0042"), True),
    (OpcUaAddress(node="i=5"), OpcUaAddress(node="ns=0;i=5"), True),
    (OpcUaAddress(node="ns=2;s=Machine.Offset"), OpcUaAddress(node="ns=2;s=Machine.offset"),
     False),
    (OpcUaAddress(node="ns=2;s=X"), OpcUaAddress(node="ns=3;s=X"), False),
])
def test_overlap_per_protocol(a: Address, b: Address, expected: bool) -> None:
    assert overlaps(a, b) is expected
    assert overlaps(b, a) is expected


def test_footprints_name_their_cells() -> None:
    assert mb(10).footprint() == Footprint(("modbus", 1, "holding"), 10, 12, "register")
    assert s7(4, "DINT", db=3).footprint() == Footprint(("s7", "DB", 3), 4, 8, "byte")
    assert pmc(100, "word").footprint() == Footprint(("pmc", "D"), 100, 102, "byte")
    assert mb(1, "uint16").footprint().describe() == "holding register 1 of unit 1"
    assert s7(0).footprint().describe() == "DB1 bytes 0..3"
    assert pmc(100).footprint().describe() == "PMC D100..103"


def test_focas_calls_that_are_not_pmc_memory_have_no_footprint() -> None:
    diag = _FOCAS.validate_python({"kind": "diag", "number": 403})
    spload = _FOCAS.validate_python({"kind": "spload"})
    assert diag.footprint() is None and spload.footprint() is None
    assert diag.raw_range is None


@pytest.mark.parametrize("node", ["ns=2;i=\u00b2", "ns=\u00b9;s=X"])
def test_a_node_id_with_digits_int_cannot_read_is_refused(node: str) -> None:
    # str.isdigit takes superscripts; the footprint's int() would not
    with pytest.raises(ValueError, match="must be an integer"):
        OpcUaAddress(node=node)


@given(st.text(alphabet="nsuigb=;0129\u00b2x: ", max_size=16))
def test_every_node_id_the_model_accepts_has_a_footprint(node: str) -> None:
    try:
        address = OpcUaAddress(node=node)
    except ValueError:
        return  # refused as a config mistake, with its reason
    assert address.footprint().space[0] == "opcua"


def test_raw_ranges_come_from_the_one_table() -> None:
    assert mb(0, "int16").raw_range == (-32768, 32767)
    assert s7(0, "WORD").raw_range == (0, 65535)
    assert pmc(0, "byte").raw_range == (-128, 127)
    assert s7(0).raw_range == ENCODINGS["float32"].range
    assert OpcUaAddress(node="ns=2;s=X").raw_range is None  # typed by the server
    for table in (MODBUS_TYPES, S7_TYPES, PMC_ENCODINGS):
        assert all(enc is ENCODINGS[enc.name] for enc in table.values())


# -- the clash rule --------------------------------------------------------------

def test_a_written_address_may_share_no_cell() -> None:
    clash = first_clash([mb(0).use("output.offset", written=True),
                         mb(1, "uint16").use("output.heartbeat", written=True)])
    assert clash is not None
    assert (clash.first.key, clash.second.key) == ("output.offset", "output.heartbeat")
    assert clash.cells == Footprint(("modbus", 1, "holding"), 1, 2, "register")
    assert "both are written" in clash.reason()
    read = mb(1, "uint16").use("channels.x.address", written=False)
    assert first_clash([mb(0).use("output.offset", written=True), read]) is not None
    assert first_clash([mb(0).use("a", written=True), mb(0).use("b", written=True)]) is not None


def test_reads_may_coincide_only_when_they_read_the_same_value() -> None:
    same = [mb(4, "int16", scale=0.1, kind="input").use("channels.a.address", written=False),
            mb(4, "int16", scale=1.0, kind="input").use("channels.b.address", written=False)]
    assert first_clash(same) is None
    other_type = [mb(4, "int16").use("a", written=False), mb(4, "uint16").use("b", written=False)]
    part = [mb(4).use("a", written=False), mb(5, "int16").use("b", written=False)]
    order = [mb(4).use("a", written=False), mb(4, word_order="little").use("b", written=False)]
    for uses in (other_type, part, order):
        clash = first_clash(uses)
        assert clash is not None and "different values" in clash.reason()


def test_the_clash_reported_is_named_by_the_later_key() -> None:
    uses = [mb(0).use("output.offset", written=True),
            mb(2, "uint16").use("output.heartbeat", written=True),
            mb(10, "int16").use("channels.a.address", written=False),
            mb(1, "uint16").use("channels.b.address", written=False)]
    clash = first_clash(uses)
    assert clash is not None
    assert (clash.first.key, clash.second.key) == ("output.offset", "channels.b.address")


def _brute_force(uses: list[Use]) -> bool:
    """Any clash, pair by pair (the rule as the docstring states it)."""
    for a, b in itertools.combinations(uses, 2):
        if a.footprint is None or b.footprint is None:
            continue
        if a.footprint.overlap(b.footprint) is None:
            continue
        if a.written or b.written or a.footprint != b.footprint or a.value != b.value:
            return True
    return False


_USES = st.lists(st.builds(
    lambda start, width, written, value, space: Use(
        "k", Footprint(("s", space), start, start + width, "byte"), written, value),
    st.integers(0, 30), st.integers(1, 4), st.booleans(), st.integers(0, 1),
    st.integers(0, 1)), max_size=12)


@given(_USES)
def test_the_sweep_finds_a_clash_exactly_when_some_pair_clashes(uses: list[Use]) -> None:
    clash = first_clash(uses)
    assert (clash is not None) == _brute_force(uses)
    if clash is not None:
        assert clash.first.footprint is not None and clash.second.footprint is not None
        assert clash.first.footprint.overlap(clash.second.footprint) == clash.cells


# -- property: footprints are what the codecs write -----------------------------

def _touched(addr: Address, value: float) -> set[tuple[object, ...]]:
    """The cells the codec's own write path covers for `addr` = `value`: the
    request(s) its write planner makes, with the encoded payload's length."""
    if isinstance(addr, ModbusAddress):
        words = modbus_codec.encode(addr, value)
        [(span, sent)] = modbus_codec.plan_writes([("x", addr, words)])
        assert len(sent) == span.count
        return {("modbus", span.unit, span.kind, span.start + i) for i in range(span.count)}
    if isinstance(addr, S7Address):
        data = s7_codec.encode(addr, value)
        [run] = s7_codec.write_runs([("x", addr)])
        assert len(data) == run.size
        return {("s7", "DB", run.db, run.start + i) for i in range(run.size)}
    if isinstance(addr, FocasPmcAddress):
        data = focas_codec.encode_pmc(addr, value)
        [r] = focas_codec.write_runs([("x", addr)])
        assert len(data) == r.size
        return {("pmc", r.area, r.start + i) for i in range(r.size)}
    raise AssertionError(addr)


def _cells(addr: Address) -> set[tuple[object, ...]]:
    fp = addr.footprint()
    assert fp is not None
    return {(*fp.space, i) for i in fp.cells()}


_MB = st.builds(lambda a, t, u: mb(a, t, unit=u), st.integers(0, 12),
                st.sampled_from(sorted(MODBUS_TYPES)), st.integers(1, 2))
_S7 = st.builds(lambda o, t, d: s7(o, t, db=d), st.integers(0, 12),
                st.sampled_from(sorted(S7_TYPES)), st.integers(1, 2))
_PMC = st.builds(lambda a, t, area: pmc(a, t, area=area), st.integers(0, 12),
                 st.sampled_from(sorted(PMC_ENCODINGS)), st.sampled_from(["D", "R"]))
_VALUE = st.integers(0, 100).map(float)  # every type holds these (uint16, PMC byte)


@given(st.one_of(st.tuples(_MB, _MB), st.tuples(_S7, _S7), st.tuples(_PMC, _PMC)),
       _VALUE, _VALUE)
def test_footprint_overlap_agrees_with_the_cells_the_codec_writes(
        pair: tuple[Address, Address], x: float, y: float) -> None:
    a, b = pair
    ta, tb = _touched(a, x), _touched(b, y)
    assert ta == _cells(a) and tb == _cells(b)
    assert bool(ta & tb) == overlaps(a, b)


_NODE = st.builds(lambda ns, kind, ident, pad: (
    ("" if ns is None else f"ns={ns};") + (f"i={'0' * pad}{ident}" if kind == "i"
                                           else f"s=N{ident}")),
    st.one_of(st.none(), st.integers(0, 2)), st.sampled_from(["i", "s"]),
    st.integers(0, 3), st.integers(0, 2))


@given(_NODE, _NODE)
def test_opcua_nodes_overlap_exactly_when_asyncua_parses_them_to_one_node(
        n1: str, n2: str) -> None:
    same = ua.NodeId.from_string(n1) == ua.NodeId.from_string(n2)
    assert overlaps(OpcUaAddress(node=n1), OpcUaAddress(node=n2)) is same
