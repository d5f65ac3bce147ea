"""`drivers.endpoint`: the one check of a controller endpoint that the config,
the drivers and ``compd sim --drive`` share: every
form accepted or refused with its reason, a userinfo found however the
password is written and never shown."""

from __future__ import annotations

import pytest

from compd.config.urls import redact_urls, url_credentials
from drivers.endpoint import Endpoint, EndpointError, endpoint_of, redact_endpoint
from drivers.focas import parse_endpoint as focas_endpoint
from drivers.modbus import parse_endpoint as modbus_endpoint
from drivers.s7 import parse_endpoint as s7_endpoint
from drivers.sim.drive import drive_endpoint

SECRET = "Qx7SE{}CRETZk9"
#: the characters that hid a password from urlsplit, and the others a raw one may hold
HOSTILE = "/?#@:%"


@pytest.mark.parametrize(("protocol", "url", "expected"), [
    ("opcua", "opc.tcp://127.0.0.1:4840", Endpoint("opc.tcp", "127.0.0.1", 4840)),
    ("opcua", "opc.tcp://plc:4841/freeopcua/server/",
     Endpoint("opc.tcp", "plc", 4841, "/freeopcua/server/")),
    ("opcua", "OPC.TCP://plc", Endpoint("opc.tcp", "plc", 4840)),
    ("s7", "s7://10.0.0.5", Endpoint("s7", "10.0.0.5", 102)),
    ("s7", "s7://plc-1.shop.example:1102/", Endpoint("s7", "plc-1.shop.example", 1102)),
    ("modbus", "127.0.0.1:5020", Endpoint("modbus", "127.0.0.1", 5020)),
    ("modbus", "tcp://[::1]:1502", Endpoint("modbus", "::1", 1502)),
    ("modbus", "modbus+tcp://PLC_7", Endpoint("modbus", "PLC_7", 502)),
    ("modbus", "modbus://[fe80::1%25eth0]:502", Endpoint("modbus", "fe80::1%eth0", 502)),
    ("focas", "focas://cnc.", Endpoint("focas", "cnc.", 8193)),
    ("focas", "focas://bücher.example:8193", Endpoint("focas", "xn--bcher-kva.example", 8193)),
    ("focas", f"focas://{'a' * 63}.{'b' * 63}.{'c' * 63}.{'d' * 61}",
     Endpoint("focas", f"{'a' * 63}.{'b' * 63}.{'c' * 63}.{'d' * 61}", 8193)),
])
def test_accepted_forms(protocol: str, url: str, expected: Endpoint) -> None:
    assert endpoint_of(protocol, url) == expected


@pytest.mark.parametrize(("url", "why"), [
    ("modbus://127.0.0.1:99999", "port 99999 is out of range 1..65535"),
    ("modbus://127.0.0.1:0", "port 0 is out of range"),
    ("modbus://127.0.0.1:065536", "out of range"),
    ("modbus://127.0.0.1:abc", "port 'abc' is not a number"),
    ("modbus://127.0.0.1:\u0663", "is not a number"),  # an Arabic-Indic 3: isdigit() says yes
    ("modbus://127.0.0.1:", "an empty port"),
    ("modbus://127.0.0.1:1/path?q", "a query or fragment"),
    ("modbus://127.0.0.1:1/path", "a path ('/path')"),
    ("modbus://127.0.0.1:1#top", "a query or fragment"),
    ("modbus://127.0.0.1:1?", "a query or fragment"),
    (f"modbus://{'a' * 64}.example:1", "is 64 characters; at most 63"),
    (f"modbus://{'a.' * 126}ab:1", "host name is 254 characters; at most 253"),
    (f"modbus://{'ü' * 60}.example:1", "has no IDNA form"),
    ("modbus://-plc:1", "starts or ends with '-'"),
    ("modbus://a..b:1", "an empty label"),
    ("modbus://pl*c:1", "a character other than"),
    ("modbus://999.0.0.1:1", "999.0.0.1 is not an IPv4 address"),
    ("modbus://::1:502", "an IPv6 address goes in brackets"),
    ("modbus://[::g]:502", "is not an IPv6 address"),
    ("modbus://[::1:502", "malformed IPv6"),
    ("modbus://:502", "no host"),
    ("modbus://", "no host"),
    ("modbus:///127.0.0.1:502", "'://' must be followed by the host"),
    ("modbus:/127.0.0.1:502", "must be followed by '//'"),
    ("modbus://127.0.0.1:502 ", "space or control character"),
    ("modbus://127.0.0.1\t:502", "space or control character"),
    ("s7://plc:102:102", "an IPv6 address goes in brackets"),
    ("http://plc:502", "the scheme is 'http'"),
])
def test_refused_forms_name_the_reason(url: str, why: str) -> None:
    with pytest.raises(EndpointError, match=r"not a valid (Modbus TCP|S7) endpoint") as info:
        endpoint_of("s7" if url.startswith("s7") else "modbus", url)
    assert why in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("protocol", ["opcua", "s7", "modbus", "focas"])
def test_no_protocol_has_a_query_and_only_opcua_a_path(protocol: str) -> None:
    from drivers.protocols import PROTOCOLS

    base = f"{PROTOCOLS[protocol].scheme}://127.0.0.1:9"
    for tail in ("?q", "/path?q", "#f", "/x#f"):
        with pytest.raises(EndpointError, match="a query or fragment"):
            endpoint_of(protocol, base + tail)
    if protocol == "opcua":
        assert endpoint_of(protocol, base + "/path").path == "/path"
    else:
        with pytest.raises(EndpointError, match="a path"):
            endpoint_of(protocol, base + "/path")


def _forms(secret: str) -> list[str]:
    return [f"opc.tcp://user:{secret}@127.0.0.1:4840",
            f"opc.tcp:///user:{secret}@127.0.0.1:4840",  # the typo: three slashes
            f"opc.tcp://user:{secret}@127.0.0.1:4840/path",
            f"opc.tcp://{secret}@127.0.0.1:4840"]  # a password where the user goes


@pytest.mark.parametrize("char", HOSTILE)
def test_a_raw_password_is_found_and_never_shown(char: str) -> None:
    secret = SECRET.format(char)
    for url in _forms(secret):
        assert url_credentials(url) is not None, url
        with pytest.raises(EndpointError, match="credentials never go in a URL") as info:
            endpoint_of("opcua", url)
        for text in (str(info.value), redact_endpoint(url), redact_urls(f"at {url} (x)")):
            assert "Qx7" not in text and "Zk9" not in text, text
            assert "***@127.0.0.1:4840" in text, text


def test_redaction_hides_the_whole_userinfo_and_keeps_the_rest() -> None:
    assert redact_endpoint("opc.tcp://op:SE/CR@h:1/x") == "opc.tcp://***@h:1/x"
    assert redact_endpoint("opc.tcp:///op:S@h:1") == "opc.tcp:///***@h:1"
    assert redact_endpoint("opc.tcp://S#E@h:1") == "opc.tcp://***@h:1"
    assert redact_endpoint("u:S@h:1") == "***@h:1"
    assert redact_endpoint("modbus://h:1") == "modbus://h:1"
    assert redact_urls("a s7://u:p?q@h b http://x:1/m c") == "a s7://***@h b http://x:1/m c"


def test_every_caller_refuses_alike() -> None:
    """The drivers' own parsers and sim --drive are the same check."""
    for parse, url in ((modbus_endpoint, "modbus://h:99999"), (s7_endpoint, "s7://h:abc"),
                       (focas_endpoint, "focas://h:1/path?q")):
        with pytest.raises(EndpointError):
            parse(url)
    with pytest.raises(EndpointError, match=r"'opc\.tcp://\*\*\*@h:9'"):
        drive_endpoint("opcua://u:SE/CRET@h:9")
    with pytest.raises(EndpointError, match="unknown protocol") as info:
        drive_endpoint("u:SECRET@h://x")
    assert "SECRET" not in str(info.value)
    assert drive_endpoint("opcua://h:9") == ("opcua", "opc.tcp://h:9")
