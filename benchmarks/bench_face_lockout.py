"""Can the operator reach SetHold on compd's OPC UA face while other clients
flood it? `compd run` with ``[faces.opcua]`` (Basic256Sha256, an operator,
``anonymous_read``, ``max_connections = 8``, ``max_sessions = 4``, the
default 10 s handshake timeout) against the simulated Modbus controller, and
two floods, one after the other:

- **silent**: eight TCP connections that never send a byte, each reopened
  as soon as the face closes it (the handshake timeout, or an eviction);
- **anonymous**: anonymous sessions, as many as the face gives (up to
  ``max_sessions``), held open.

Under each, for ``--seconds``, the operator (asyncua's client, user name and
password over Basic256Sha256) connects, calls SetHold(true) and
SetHold(false), and disconnects, again and again (0.5 s apart); a connect is
counted when both calls were applied. The face's counts (evicted, refused,
sessions refused) are read from /metrics at the end of each flood.

    .venv/bin/python benchmarks/bench_face_lockout.py [--seconds 40] [--peer DIR]

``--peer DIR`` runs the daemon of another checkout (``git worktree add DIR
REV``) the same way afterwards, e.g. the face before it evicted connections.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from daemon_bench_common import config_doc, start_sim, write_config  # noqa: E402

from drivers.sim.ports import free_tcp_port  # noqa: E402
from tests.pki import Pki, server_and_client  # noqa: E402

OPERATOR, PASSWORD = "setter", "bench-h0ld-pw"
MAX_CONNECTIONS, MAX_SESSIONS = 8, 4
CLIENT_URI = "urn:compd:bench:client"


@dataclass
class Tries:
    ok: int = 0
    tries: int = 0
    first_error: str = ""


async def _client(port: int, pki: Pki, user: str | None = None) -> object:
    from asyncua import ua
    from asyncua.client.client import Client
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

    client = Client(f"opc.tcp://127.0.0.1:{port}", timeout=5)
    await client.set_security(SecurityPolicyBasic256Sha256, str(pki.client_cert),
                              str(pki.client_key), server_certificate=str(pki.server_cert),
                              mode=ua.MessageSecurityMode.SignAndEncrypt)
    client.application_uri = CLIENT_URI
    if user is not None:
        client.set_user(user)
        client.set_password(PASSWORD)
    return client


async def _operator_once(port: int, pki: Pki) -> None:
    client = await _client(port, pki, OPERATOR)
    async with client as op:  # type: ignore[attr-defined]
        idx = await op.get_namespace_index("urn:compd")
        machine = await op.nodes.objects.get_child(f"{idx}:bench-modbus")
        for hold in (True, False):
            if await machine.call_method(f"{idx}:SetHold", hold) is not True:
                raise RuntimeError(f"SetHold({hold}) not applied")


async def _operator(port: int, pki: Pki, seconds: float) -> Tries:
    tries = Tries()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        tries.tries += 1
        try:
            await asyncio.wait_for(_operator_once(port, pki), 30.0)
            tries.ok += 1
        except Exception as exc:  # counted: the operator did not get through
            tries.first_error = tries.first_error or (str(exc) or type(exc).__name__)[:120]
        await asyncio.sleep(0.5)
    return tries


@contextlib.asynccontextmanager
async def _silent(port: int, n: int) -> AsyncIterator[list[int]]:
    """`n` connections that never send a byte, reopened when closed; [opened]."""
    opened = [0]

    async def one() -> None:
        while True:
            try:
                reader, writer = await asyncio.open_connection("127.0.0.1", port)
            except OSError:
                await asyncio.sleep(0.05)
                continue
            opened[0] += 1
            with contextlib.suppress(OSError):
                await reader.read(1)
            writer.close()

    tasks = [asyncio.create_task(one()) for _ in range(n)]
    try:
        yield opened
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


@contextlib.asynccontextmanager
async def _anonymous(port: int, pki: Pki, n: int) -> AsyncIterator[int]:
    """Up to `n` anonymous sessions, held; yields how many the face gave."""
    async with contextlib.AsyncExitStack() as stack:
        held = 0
        for _ in range(n):
            try:
                await stack.enter_async_context(await _client(port, pki))  # type: ignore[arg-type]
                held += 1
            except Exception:  # BadTooManySessions: the face's share is full
                pass
        yield held


def _metrics(url: str) -> dict[str, float]:
    with urllib.request.urlopen(url, timeout=10) as answer:
        text = answer.read().decode()
    out: dict[str, float] = {}
    for line in text.splitlines():
        if line.startswith("compd_opcua_face_") and " " in line:
            name, value = line.rsplit(" ", 1)
            out[name] = float(value)
    return out


def _spawn(checkout: Path, cfg: Path) -> subprocess.Popen[str]:
    """`compd run CFG` with the compd of `checkout` (started once, before the floods)."""
    env = {**os.environ, "PYTHONPATH": str(checkout), "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-m", "compd", "run", str(cfg)], cwd=checkout,
                            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


async def _one_daemon(label: str, checkout: Path, args: argparse.Namespace, pki: Pki,
                      tmp: Path) -> None:
    sim = start_sim("modbus")
    face_port = free_tcp_port("127.0.0.1")
    metrics_port = free_tcp_port("127.0.0.1")
    doc = config_doc(sim.desc, state_dir=tmp / label / "state")
    doc["telemetry"]["metrics_port"] = metrics_port
    (tmp / label).mkdir(parents=True, exist_ok=True)
    (tmp / label / "operator.pw").write_text(PASSWORD + "\n", encoding="utf-8")
    doc["faces"] = {"opcua": {
        "enabled": True, "port": face_port, "certificate": str(pki.server_cert),
        "private_key": str(pki.server_key), "operator": OPERATOR,
        "operator_password_file": "operator.pw", "anonymous_read": True,
        "max_connections": MAX_CONNECTIONS, "max_sessions": MAX_SESSIONS}}
    cfg = write_config(doc, tmp / label / "compd.toml")
    proc = _spawn(checkout, cfg)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, "")),  # type: ignore[union-attr]
                              daemon=True)
    reader.start()
    url = f"http://127.0.0.1:{metrics_port}/metrics"
    try:
        for _ in range(3000):
            if any("opcua_face_started" in ln for ln in lines) or proc.poll() is not None:
                break
            await asyncio.sleep(0.02)
        if proc.poll() is not None:
            print("".join(lines)[-3000:], file=sys.stderr)
            raise SystemExit(1)
        print(f"{label}: compd run from {checkout}")
        async with _silent(face_port, MAX_CONNECTIONS) as opened:
            await asyncio.sleep(1.0)
            silent = await _operator(face_port, pki, args.seconds)
            counts = _metrics(url)
        print(f"  silent flood ({MAX_CONNECTIONS} sockets, reopened when closed, "
              f"{opened[0]} opened): operator {silent.ok} of {silent.tries} connects "
              f"reached SetHold in {args.seconds:.0f} s"
              + (f"; first failure: {silent.first_error}" if silent.first_error else ""))
        _print_counts(counts)
        async with _anonymous(face_port, pki, MAX_SESSIONS) as held:
            anon = await _operator(face_port, pki, args.seconds)
            counts = _metrics(url)
        print(f"  anonymous flood ({held} of {MAX_SESSIONS} anonymous sessions given and "
              f"held): operator {anon.ok} of {anon.tries} connects reached SetHold in "
              f"{args.seconds:.0f} s"
              + (f"; first failure: {anon.first_error}" if anon.first_error else ""))
        _print_counts(counts)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        reader.join(5.0)
        sim.stop()


def _print_counts(counts: dict[str, float]) -> None:
    shown = {name.removeprefix("compd_opcua_face_"): value for name, value in counts.items()
             if "refused_total" in name and value}
    print("    face counts so far: "
          + (", ".join(f"{k} {v:.0f}" for k, v in sorted(shown.items())) or "none"))


async def run(args: argparse.Namespace) -> int:
    logging.getLogger("asyncua").setLevel(logging.CRITICAL)  # each refused login's warning
    tmp = Path(tempfile.mkdtemp(prefix="compd-face-lockout-"))
    try:
        (tmp / "pki").mkdir()
        pki = server_and_client(tmp / "pki", server_uri="urn:compd:server",
                                client_uri=CLIENT_URI)
        await _one_daemon("this checkout", ROOT, args, pki, tmp)
        if args.peer is not None:
            await _one_daemon("peer", args.peer.resolve(), args, pki, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=40.0,
                        help="how long the operator tries under each flood")
    parser.add_argument("--peer", type=Path, default=None,
                        help="another checkout whose daemon is measured the same way")
    return asyncio.run(run(parser.parse_args()))


if __name__ == "__main__":
    raise SystemExit(main())
