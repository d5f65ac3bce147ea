"""A password written raw in the endpoint URL, with "/", "?", "#", "@", ":" or
"%" in it (which would hide it from urlsplit), is refused by
``compd check`` (text and --json), ``compd run`` and ``compd sim --drive``
and never printed; a running daemon told to reload such a config logs
``reload_failed`` without it and keeps its old endpoint.

Every secret is wrapped in two markers (``Qx7`` ... ``Zk9``): neither may
appear anywhere, so a secret shown in part fails too."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import string
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from compd.cli import main
from compd.sysexits import EX_CONFIG, EX_USAGE
from drivers.protocols import PROTOCOLS
from drivers.sim.ports import free_tcp_port
from tests.configs import Toml, write_config
from tests.faults.daemon_run import ROOT, daemon_env, forget_daemon_logging

from .test_bad_configs import BASES

MARKS = ("Qx7", "Zk9")
HOSTILE = "/?#@:%"
SETTINGS = settings(max_examples=int(os.environ.get("COMPD_FUZZ_EXAMPLES", "40")),
                    deadline=None, derandomize=os.environ.get("COMPD_FUZZ_EXAMPLES") is None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])

_raw = st.text(alphabet=string.ascii_letters + string.digits + HOSTILE * 4
               + " !$&'()*+,;=[]~-._\"\\", max_size=12)
#: a password with at least one of the characters that hid it
passwords = st.builds(lambda a, c, b: f"{MARKS[0]}{a}{c}{b}{MARKS[1]}", _raw,
                      st.sampled_from(HOSTILE), _raw)
#: where the password stands: after a user name, after the typo "///", before a path,
#: alone where the user goes
FORMS = ("{s}://operator:{pw}@127.0.0.1:{port}", "{s}:///operator:{pw}@127.0.0.1:{port}",
         "{s}://operator:{pw}@127.0.0.1:{port}/", "{s}://{pw}@127.0.0.1:{port}")


@pytest.fixture(scope="module")
def workdir() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="compd-secrets-") as d:
        yield Path(d)


def _config(workdir: Path, protocol: str, endpoint: str) -> Path:
    """The protocol's base config (tests/faults/test_bad_configs) with `endpoint`
    (a TOML basic string takes JSON's escapes for ASCII text)."""
    return write_config(workdir, Toml(json.dumps(endpoint)), base=BASES[protocol],
                        filename=f"{protocol}.toml")


def _assert_hidden(text: str, what: object) -> None:
    for mark in MARKS:
        assert mark not in text, (what, text)
    assert "Traceback" not in text, (what, text)


@SETTINGS
@example(protocol="opcua", form=FORMS[0], password=f"{MARKS[0]}SE/CRETX4{MARKS[1]}")
@example(protocol="opcua", form=FORMS[0], password=f"{MARKS[0]}SE?CRETX4{MARKS[1]}")
@example(protocol="opcua", form=FORMS[0], password=f"{MARKS[0]}SE#CRETX4{MARKS[1]}")
@example(protocol="opcua", form=FORMS[1], password=f"{MARKS[0]}SECRET{MARKS[1]}")
@given(protocol=st.sampled_from(sorted(PROTOCOLS)), form=st.sampled_from(FORMS),
       password=passwords)
def test_a_password_in_the_endpoint_is_refused_and_never_shown(
        protocol: str, form: str, password: str, workdir: Path, listener: socket.socket,
        capsys: pytest.CaptureFixture[str]) -> None:
    port = listener.getsockname()[1]
    url = form.format(s=PROTOCOLS[protocol].scheme, pw=password, port=port)
    config = str(_config(workdir, protocol, url))
    capsys.readouterr()
    for argv in (["check", config], ["check", config, "--json"], ["run", config, "--once"]):
        try:
            rc = main(argv)
        finally:
            forget_daemon_logging()
        out = capsys.readouterr()
        _assert_hidden(out.out + out.err, argv)
        assert rc == EX_CONFIG, (argv, out.err)
        assert "controller.endpoint" in out.err and "credentials never go in a URL" in out.err
        assert out.err.count("\n") == 1 and not out.out, (argv, out)
    drive = form.format(s=protocol, pw=password, port=port)
    assert main(["sim", "--drive", drive, "--print-every-s", "0"]) == EX_USAGE
    out = capsys.readouterr()
    _assert_hidden(out.out + out.err, drive)
    assert "credentials never go in a URL" in out.err and out.err.count("\n") == 1
    with pytest.raises(BlockingIOError):  # nothing was asked of the controller
        listener.accept()[0].close()


async def _line(stream: asyncio.StreamReader, seen: list[str], *events: str) -> str:
    """Read the daemon's log until a line with one of `events`; return that event."""
    while True:
        raw = await stream.readline()
        if not raw:
            raise AssertionError("the daemon ended; its log:\n" + "".join(seen[-20:]))
        line = raw.decode("utf-8", "replace")
        seen.append(line)
        for event in events:
            if f'"event": "{event}"' in line:
                return event


async def test_a_reload_to_an_endpoint_with_a_password_is_refused_unlogged(
        tmp_path: Path) -> None:
    """The run's own log: started against a port where nothing listens, it logs
    daemon_starting and controller_connect_failed; each SIGHUP to a config whose
    endpoint carries a raw password ends in reload_failed, and the secret is in
    no line before, between or after."""
    port = free_tcp_port()
    good = f"modbus://127.0.0.1:{port}"
    config = write_config(tmp_path, good, time_scale=1.0, timeout_s=0.2)
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "compd", "run", str(config), stdin=asyncio.subprocess.DEVNULL,
        stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE, env=daemon_env(),
        cwd=str(ROOT))
    assert proc.stderr is not None
    seen: list[str] = []
    try:
        await asyncio.wait_for(_line(proc.stderr, seen, "controller_connect_failed"), 60)
        for char in HOSTILE:
            for form in FORMS[:2]:
                url = form.format(s="modbus", pw=f"{MARKS[0]}SE{char}CRET{MARKS[1]}", port=port)
                config.write_text(config.read_text(encoding="utf-8").replace(
                    good, url), encoding="utf-8")
                proc.send_signal(signal.SIGHUP)
                got = await asyncio.wait_for(
                    _line(proc.stderr, seen, "reload_failed", "reload_succeeded"), 60)
                assert got == "reload_failed", seen[-1]
                config.write_text(config.read_text(encoding="utf-8").replace(url, good),
                                  encoding="utf-8")
        proc.send_signal(signal.SIGTERM)
        rest = await asyncio.wait_for(proc.stderr.read(), 60)
        seen.append(rest.decode("utf-8", "replace"))
        assert await asyncio.wait_for(proc.wait(), 60) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    text = "".join(seen)
    _assert_hidden(text, "compd run")
    assert '"event": "daemon_starting"' in text and '"event": "daemon_stopped"' in text
    assert f"127.0.0.1:{port}" in text
    failed = [json.loads(ln[ln.index("{"):]) for ln in seen if '"reload_failed"' in ln]
    assert len(failed) == 2 * len(HOSTILE)
    assert all("credentials never go in a URL" in str(f) for f in failed), failed
