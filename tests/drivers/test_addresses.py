"""Typed addresses: what a config may say, and what it may not."""

from __future__ import annotations

import pytest
from pydantic import TypeAdapter, ValidationError

from drivers.addresses import (
    FocasAddress,
    ModbusAddress,
    OpcUaAddress,
    S7Address,
)


def test_valid_addresses_of_each_protocol() -> None:
    assert OpcUaAddress(node="ns=2;s=Machine.Bearing").describe() == "ns=2;s=Machine.Bearing"
    assert S7Address(db=1, offset=4, type="INT", scale=0.1).size == 2
    assert ModbusAddress(address=10, type="float32", word_order="little", scale=1).count == 2
    pmc = TypeAdapter(FocasAddress).validate_python({"kind": "pmc", "area": "D", "address": 100})
    assert pmc.describe() == "PMC D100:long"


@pytest.mark.parametrize(("model", "doc", "field"), [
    (ModbusAddress, {"address": "5"}, "address"),
    (ModbusAddress, {"address": 5, "scale": "0.1"}, "scale"),
    (ModbusAddress, {"address": 65535, "type": "float32"}, "runs past register 65535"),
    (ModbusAddress, {"address": 5, "scale": 0}, "scale"),
    (ModbusAddress, {"address": 5, "colour": "red"}, "colour"),
    (S7Address, {"db": 0, "offset": 0}, "db"),
    (S7Address, {"db": 1, "offset": 0, "type": "FLOAT"}, "type"),
    (OpcUaAddress, {"node": "Machine.Bearing"}, "not an OPC UA NodeId"),
    (OpcUaAddress, {"node": "ns=x;s=a"}, "namespace index"),
])
def test_bad_addresses_are_refused_naming_the_field(model: type, doc: dict[str, object],
                                                    field: str) -> None:
    with pytest.raises(ValidationError, match=field):
        model(**doc)
