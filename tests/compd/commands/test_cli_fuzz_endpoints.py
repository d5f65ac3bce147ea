"""The command-line fuzzer's hostile endpoints, beside
`test_cli_fuzz` and judged as it judges (a sysexits code, no traceback, one
line): each protocol's config with an endpoint that carries a raw password
(``/``, ``?``, ``#``, ``@``, ``%``, the ``///`` typo, a password where the user
goes) or that cannot be one (port ``:99999``, ``:0``, ``:abc``, ``:``, a path,
query or fragment where the protocol has none, a 64-character label, a
254-character name, a name without an IDNA form, a bare IPv6 address, a bad
IPv4 address, a space) under ``check``, ``check --json`` and ``run --once``,
and the same URLs under ``sim --drive``. Here each must be refused (78, or
64 for sim --drive) by the same check, the secret never printed, the
controller (a listening socket) never asked. Counted in `CASES`."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest

from compd.cli import main
from compd.sysexits import EX_CONFIG, EX_USAGE
from drivers.protocols import PROTOCOLS
from tests.compd.commands.test_cli_fuzz import _check, _real, root  # noqa: F401 - the fixture
from tests.faults.daemon_run import forget_daemon_logging
from tests.faults.test_bad_configs import BASES

MARKS = ("Qx7", "Zk9")
SECRET = MARKS[0] + "SE{}CRET" + MARKS[1]
#: {s} the scheme, {port} the listening socket's port
ENDPOINTS: dict[str, str] = {
    **{f"password-{name}": "{s}://operator:" + SECRET.format(c) + "@127.0.0.1:{port}"
       for name, c in (("slash", "/"), ("query", "?"), ("hash", "#"), ("at", "@"),
                       ("percent", "%"), ("colon", ":"))},
    "password-slash-path": "{s}://operator:" + SECRET.format("/") + "@127.0.0.1:{port}/x",
    "typo-three-slashes": "{s}:///operator:" + SECRET.format("") + "@127.0.0.1:{port}",
    "password-as-user": "{s}://" + SECRET.format("/") + "@127.0.0.1:{port}",
    "port-99999": "{s}://127.0.0.1:99999",
    "port-0": "{s}://127.0.0.1:0",
    "port-abc": "{s}://127.0.0.1:abc",
    "port-empty": "{s}://127.0.0.1:",
    "path-query": "{s}://127.0.0.1:{port}/path?q",
    "fragment": "{s}://127.0.0.1:{port}#f",
    "label-64": "{s}://" + "a" * 64 + ".example:{port}",
    "name-254": "{s}://" + "a." * 126 + "ab:{port}",
    "no-idna": "{s}://" + "ü" * 60 + ".example:{port}",
    "bare-ipv6": "{s}://::1:{port}",
    "bad-ipv4": "{s}://999.0.0.1:{port}",
    "space": "{s}://127.0.0.1 :{port}",
}


def _cases() -> list[list[str]]:
    out: list[list[str]] = []
    for protocol in sorted(PROTOCOLS):
        for name, form in ENDPOINTS.items():
            config = f"@/endpoint-{protocol}-{name}.toml"
            out += [["check", config], ["check", config, "--json"], ["run", config, "--once"],
                    ["sim", "--drive", form.replace("{s}", protocol), "--print-every-s", "0",
                     "--duration-h", "0.001", "--speedup", "100"]]
    return out


CASES = _cases()
print(f"\ncompd CLI fuzzer, hostile endpoints: {len(CASES)} in-process cases")


@pytest.fixture(scope="module")
def configs(root: Path, listener: socket.socket) -> str:  # noqa: F811
    """Every protocol's base config with every hostile endpoint, in `root`;
    returns the port."""
    port = str(listener.getsockname()[1])
    for protocol in PROTOCOLS:
        for name, form in ENDPOINTS.items():
            url = form.format(s=PROTOCOLS[protocol].scheme, port=port)
            lines = [f"endpoint = {json.dumps(url)}" if ln.startswith("endpoint = ") else ln
                     for ln in BASES[protocol].replace("{port}", port).splitlines()]
            (root / f"endpoint-{protocol}-{name}.toml").write_text(
                "\n".join(lines) + "\n", encoding="utf-8")
    return port


@pytest.mark.parametrize("argv", CASES, ids=[" ".join(c)[:90] for c in CASES])
def test_hostile_endpoint(argv: list[str], root: Path, configs: str,  # noqa: F811
                          listener: socket.socket, capsys: pytest.CaptureFixture[str]) -> None:
    real = [a.replace("{port}", configs) for a in _real(argv, root)]
    try:
        rc: object = main(real)
    except SystemExit as exc:
        rc = exc.code
    finally:
        forget_daemon_logging()
    out = capsys.readouterr()
    _check(rc, out.err, argv)
    for mark in MARKS:
        assert mark not in out.out + out.err, (argv, out)
    if argv[0] == "sim":
        assert rc == EX_USAGE, (argv, out.err)
    else:
        assert rc == EX_CONFIG, (argv, out.err)
        assert "controller.endpoint" in out.err and not out.out, (argv, out)
    with pytest.raises(BlockingIOError):  # the controller was never asked
        listener.accept()[0].close()
