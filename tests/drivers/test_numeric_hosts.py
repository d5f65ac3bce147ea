"""A numeric host has one spelling, the dotted quad: every other spelling the C
resolver reads as an IPv4 address (hex, octal, fewer than four parts) is refused
with the address it would reach, by the endpoints (config, drivers, ``sim --drive``)
and by the hosts compd listens on alike. ``0x0a.0x0.0x0.0x1`` and ``0x7f000001``
passed as names and reached 10.0.0.1 and 127.0.0.1 while ``127.1`` was refused."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from compd.cli import main
from compd.errors import EX_CONFIG
from compd.sysexits import EX_USAGE
from drivers.endpoint import EndpointError, endpoint_of, numeric_host_reason
from drivers.sim.drive import drive_endpoint

#: spelling -> the address inet_aton reads from it
SPELLINGS = {
    "0x0a.0x0.0x0.0x1": "10.0.0.1",
    "0x7f000001": "127.0.0.1",
    "0X7F.1": "127.0.0.1",
    "127.1": "127.0.0.1",
    "127.0.1": "127.0.0.1",
    "0177.0.0.1": "127.0.0.1",
    "010.0.0.1": "8.0.0.1",  # octal: not 10.0.0.1
    "2130706433": "127.0.0.1",
    "0": "0.0.0.0",
    "1.0x10000": "1.1.0.0",
}


@pytest.mark.parametrize(("spelling", "address"), SPELLINGS.items())
def test_the_rule_names_the_address_a_spelling_reaches(spelling: str, address: str) -> None:
    # the C resolver itself reads the spelling as that address
    assert socket.inet_ntoa(socket.inet_aton(spelling)) == address
    assert numeric_host_reason(spelling) == (f"{spelling} is a numeric spelling of {address}: "
                                             f"write the address as {address}")


@pytest.mark.parametrize("spelling", ["1.2.3.4.5", "999.0.0.1", "09.1.1.1", "0x",
                                      "4294967296", "1.2.65536", "0xFFFFFFFFF"])
def test_numbers_that_are_no_address_are_refused_too(spelling: str) -> None:
    assert numeric_host_reason(spelling) == f"{spelling} is not an IPv4 address"


@pytest.mark.parametrize("host", ["127.0.0.1", "10.0.0.1", "0.0.0.0", "255.255.255.255",
                                  "plc", "deadbeef", "0xcafe.example", "0x1g", "00x1",
                                  "plc-7.shop.example", "::", "::1"])
def test_the_dotted_quad_and_names_pass(host: str) -> None:
    assert numeric_host_reason(host) is None


@pytest.mark.parametrize("protocol", ["opcua", "s7", "modbus", "focas"])
@pytest.mark.parametrize("spelling", [*SPELLINGS, "127.0.0.1."])
def test_every_protocols_endpoint_refuses_every_numeric_spelling(protocol: str,
                                                                 spelling: str) -> None:
    scheme = {"opcua": "opc.tcp"}.get(protocol, protocol)
    with pytest.raises(EndpointError, match="is a numeric spelling of") as info:
        endpoint_of(protocol, f"{scheme}://{spelling}:4840")
    assert f"'{scheme}://{spelling}:4840'" in str(info.value)
    with pytest.raises(EndpointError, match="is a numeric spelling of"):
        drive_endpoint(f"{protocol}://{spelling}:4840")


CONFIG = """
[controller]
protocol = "opcua"
endpoint = "{endpoint}"

[channels.bearing]
address = {{ node = "ns=2;s=bearing" }}
unit = "degC"
range = [-20.0, 150.0]

[model]
file = "sp2"

[output]
offset = {{ node = "ns=2;s=offset" }}
limit_um = 100.0
slew_um_s = 1.0
{extra}"""


@pytest.mark.parametrize(("endpoint", "extra", "key", "spelling"), [
    ("opc.tcp://0x0a.0x0.0x0.0x1:4840", "", "controller.endpoint", "0x0a.0x0.0x0.0x1"),
    ("opc.tcp://0x7f000001:4840", "", "controller.endpoint", "0x7f000001"),
    ("opc.tcp://127.0.0.1:4840", '\n[telemetry]\nmetrics_port = 9100\nmetrics_host = "0"\n',
     "telemetry.metrics_host", "0"),
    ("opc.tcp://127.0.0.1:4840", '\n[faces.opcua]\nhost = "127.1"\n', "faces.opcua.host",
     "127.1"),
])
def test_check_refuses_a_numeric_spelling_naming_the_key(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], endpoint: str, extra: str,
        key: str, spelling: str) -> None:
    config = tmp_path / "compd.toml"
    config.write_text(CONFIG.format(endpoint=endpoint, extra=extra), encoding="utf-8")
    assert main(["check", str(config)]) == EX_CONFIG
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{key}: " in err
    assert f"{spelling} is a numeric spelling of" in err


@pytest.mark.parametrize("command", ["health", "status"])
@pytest.mark.parametrize("spelling", ["0x7f000001", "127.1", "0177.0.0.1"])
def test_the_daemons_url_is_held_to_the_rule_too(
        capsys: pytest.CaptureFixture[str], command: str, spelling: str) -> None:
    """`compd health --url` and `compd status --url` refuse before they connect."""
    assert main([command, "--url", f"http://{spelling}:9/", "--timeout-s", "1"]) == EX_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"{spelling} is a numeric spelling of 127.0.0.1: write the address as 127.0.0.1" in err
