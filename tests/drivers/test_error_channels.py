"""Driver errors name their channels as a tuple: a string is
one name, never split; a combined request names each of its channels."""

from __future__ import annotations

from drivers.addresses import ModbusAddress
from drivers.errors import ConnectionLost, DriverError, WriteRejected, channel_names
from drivers.modbus_codec import Span


def test_one_name_several_or_none() -> None:
    assert DriverError("x", channel="offset").channels == ("offset",)
    assert DriverError("x", channel=["offset", "heartbeat"]).channels == ("offset", "heartbeat")
    assert DriverError("x").channels == () and channel_names("") == ()
    # a name is never split, whatever it holds
    assert channel_names("a,b") == ("a,b",)


def test_the_message_names_them_and_the_address() -> None:
    err = WriteRejected("refused", channel=("offset", "heartbeat"), address="unit1/holding/0+3",
                        permanent=True)
    assert str(err) == "refused (channel=offset,heartbeat, address=unit1/holding/0+3)"
    assert err.permanent and err.channels == ("offset", "heartbeat")
    assert str(ConnectionLost("down")) == "down"


def test_a_modbus_span_names_each_channel_it_carries() -> None:
    a = ModbusAddress(kind="holding", address=0, type="float32")
    b = ModbusAddress(kind="holding", address=2, type="uint16")
    span = Span(unit=1, kind="holding", start=0, count=3, items=(("offset", a), ("heartbeat", b)))
    assert span.names == ("offset", "heartbeat")
    assert span.where() == (("offset", "heartbeat"), "unit1/holding/0+3")
