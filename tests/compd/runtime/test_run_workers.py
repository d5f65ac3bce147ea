"""`compd run DIR --workers N` (compd.runtime.workers): the machines of a directory
over N worker processes, each a failure domain, one endpoint across them.

One real run (a parent and two workers against four simulated Modbus
controllers on 127.0.0.1) goes through what a user sees: systemd's READY only
after both workers, every machine writing its offset, one /metrics with every
machine once, a worker killed with SIGKILL restarted while the other's
machines keep cycling, SIGHUP reaching every machine, SIGTERM stopping all
with their checkpoints. Every wait is on an event with a generous bound (a
loaded machine makes it slower, never red). The merge of the expositions
and the dealing of machines are checked in-process."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import socket
import sys
import urllib.request
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.faces.fleet_metrics import FleetMetrics
from compd.faces.telemetry import Metrics
from compd.faces.worker_metrics import PoolMetrics, WorkerView, merge_expositions
from compd.runtime.startup import checkpoint_path
from compd.runtime.workers import assign
from drivers.sim.modbus_server import ModbusSimController
from drivers.sim.ports import free_tcp_port
from tests.compd.runtime.test_run_dir import _write_machine
from tests.harness import modbus_sims, until

NAMES = ("mill-a", "mill-b", "mill-c", "mill-d")
#: real seconds any one condition may take on a loaded machine
BOUND_S = 120.0


@pytest.fixture
async def sims4() -> AsyncIterator[list[ModbusSimController]]:
    async with modbus_sims(len(NAMES)) as controllers:
        yield controllers


def _events(log: Path) -> list[dict[str, Any]]:
    out = []
    for line in log.read_text(errors="replace").splitlines():
        with contextlib.suppress(ValueError):
            doc = json.loads(line[line.find("{"):]) if "{" in line else None
            if isinstance(doc, dict):
                out.append(doc)
    return out


def _scrape(port: int, path: str = "/metrics") -> str:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=30) as r:
        return str(r.read().decode())


async def test_two_workers_share_the_fleet_and_each_is_a_failure_domain(
        sims4: list[ModbusSimController], tmp_path: Path) -> None:
    d = tmp_path / "machines.d"
    d.mkdir()
    port = free_tcp_port("127.0.0.1")
    for name, sim in zip(NAMES, sims4, strict=True):
        # a 500 ms period, checkpoints only at the stop
        path = _write_machine(d, name, sim.endpoint, metrics_port=port, time_scale=2.0,
                              timeout_s=0.25, checkpoint_every=1_000_000)
        if name != "mill-d":  # the page shows the machines that ask for it
            path.write_text(path.read_text() + "\n[faces.http]\nenabled = true\n")
    sim_of = dict(zip(NAMES, sims4, strict=True))
    paths = {n: checkpoint_path(load_config(d / f"{n}.toml")) for n in NAMES}
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify_path = tmp_path / "notify.sock"
    notify.bind(str(notify_path))
    notify.setblocking(False)
    log = tmp_path / "compd.log"
    env = {**os.environ, "NOTIFY_SOCKET": str(notify_path)}
    env.pop("WATCHDOG_USEC", None)
    with log.open("wb") as err:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "compd", "run", str(d), "--workers", "2", env=env,
            stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.DEVNULL, stderr=err)
    loop = asyncio.get_running_loop()
    try:
        # systemd hears READY=1 from the parent once, after both workers were ready
        datagram = await asyncio.wait_for(loop.sock_recv(notify, 4096), BOUND_S)
        assert datagram.startswith(b"READY=1") and f"MAINPID={proc.pid}".encode() in datagram
        events = _events(log)
        ready = [e for e in events if e.get("event") == "worker_ready"]
        assert sorted(e["worker"] for e in ready) == [0, 1]
        pid_of = {e["worker"]: e["pid"] for e in ready}
        shares = assign(NAMES, 2)
        assert shares == [["mill-a", "mill-c"], ["mill-b", "mill-d"]]

        async def beats(names: list[str] | tuple[str, ...]) -> dict[str, float]:
            return {n: (await sim_of[n].outputs())["heartbeat"] for n in names}

        async def all_beating(since: dict[str, float], by: float = 3) -> bool:
            now = await beats(list(since))
            return all(now[n] >= since[n] + by for n in since)

        start = dict.fromkeys(NAMES, 0.0)
        await until(lambda: all_beating(start), what="every machine writes its heartbeat",
                    every_s=0.02)
        # warm every machine: each one's own model moves its own offset
        before = {n: (await s.outputs())["offset"] for n, s in sim_of.items()}
        for s in sims4:
            await s.publish({"bearing": 45.0})

        async def offsets_moved() -> bool:
            now = {n: (await sim_of[n].outputs())["offset"] for n in NAMES}
            return all(abs(now[n] - before[n]) > 0.05 for n in NAMES)

        await until(offsets_moved, what="every machine writes its offset", every_s=0.02)

        async def every_machine_cycled() -> bool:
            body = await asyncio.to_thread(_scrape, port)
            return all(f'compd_cycles_complete_total{{machine="{n}"}}' in body
                       for n in NAMES)

        await until(every_machine_cycled, what="one /metrics with every machine", every_s=0.02)
        body = await asyncio.to_thread(_scrape, port)
        for n in NAMES:  # each machine's series once
            assert body.count(f'compd_cycles_complete_total{{machine="{n}"}}') == 1
            assert f'compd_machine_running{{machine="{n}"}} 1.0' in body
        types = [line for line in body.splitlines() if line.startswith("# TYPE ")]
        assert len(types) == len(set(types))  # one family per name
        assert 'compd_worker_running{worker="0"} 1.0' in body
        assert 'compd_worker_running{worker="1"} 1.0' in body
        # one status page: every worker's machines that enable it, in name order
        status = json.loads(await asyncio.to_thread(_scrape, port, "/status.json"))
        assert [m["machine"] for m in status["machines"]] == ["mill-a", "mill-b", "mill-c"]
        assert all(m["state"] != "off" for m in status["machines"])

        # SIGKILL worker 0: it is started again; worker 1's machines never stop
        os.kill(pid_of[0], signal.SIGKILL)
        others = await beats(shares[1])
        await until(lambda: all_beating(others, by=5),
                    what="the other worker's machines keep cycling", every_s=0.02)

        async def restarted() -> bool:
            again = [e for e in _events(log) if e.get("event") == "worker_ready"
                     and e.get("worker") == 0 and e.get("pid") != pid_of[0]]
            return bool(again)

        await until(restarted, what="worker 0 started again", every_s=0.02)
        exited = [e for e in _events(log) if e.get("event") == "worker_exited"]
        assert [(e["worker"], e["signal"]) for e in exited] == [(0, "SIGKILL")]
        mine = await beats(shares[0])
        await until(lambda: all_beating(mine), what="its machines cycle again", every_s=0.02)
        body = await asyncio.to_thread(_scrape, port)
        assert 'compd_worker_restarts_total{worker="0"} 1.0' in body
        assert 'compd_worker_restarts_total{worker="1"} 0.0' in body
        os.kill(pid_of[1], 0)  # worker 1 is the same process all along

        # SIGHUP reaches every machine through its worker
        proc.send_signal(signal.SIGHUP)

        async def reloaded() -> bool:
            done = {e.get("machine") for e in _events(log)
                    if e.get("event") == "reload_succeeded"}
            return done >= set(NAMES)

        await until(reloaded, what="every machine reloaded its file", every_s=0.02)
        written = {n: p.stat().st_mtime_ns if p.exists() else 0 for n, p in paths.items()}

        # SIGTERM stops every machine with its checkpoint, and the parent exits 0
        proc.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(proc.wait(), BOUND_S) == 0
        assert all(p.exists() and p.stat().st_mtime_ns > written[n]
                   for n, p in paths.items())  # each machine's own, at its stop
        stopped = [str(e.get("machine")) for e in _events(log)
                   if e.get("event") == "daemon_stopped"]
        # (worker 0's first process, killed, wrote none)
        assert sorted(stopped) == sorted(NAMES)
        for pid in pid_of.values():
            with pytest.raises(ProcessLookupError):
                os.kill(pid, 0)
    finally:
        notify.close()
        if proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()


def test_machines_are_dealt_round_robin_in_name_order() -> None:
    assert assign(["c", "a", "b"], 2) == [["a", "c"], ["b"]]
    assert assign(["a", "b"], 8) == [["a"], ["b"]]  # never an idle worker
    assert assign(["a", "b", "c"], 1) == [["a", "b", "c"]]


def test_expositions_merge_by_family() -> None:
    a = ('# HELP x_total X\n# TYPE x_total counter\nx_total{machine="a"} 1.0\n'
         '# HELP compd_http_connections C\n# TYPE compd_http_connections gauge\n'
         'compd_http_connections 3.0\n')
    b = '# HELP x_total X\n# TYPE x_total counter\nx_total{machine="b"} 2.0\n'
    merged = merge_expositions([a, b], drop=frozenset({"compd_http_connections"}))
    assert merged == ('# HELP x_total X\n# TYPE x_total counter\nx_total{machine="a"} 1.0\n'
                      'x_total{machine="b"} 2.0\n')


def test_the_parent_serves_each_workers_machines_and_shows_a_down_ones_as_stopped() -> None:
    servers = []
    for name in ("mill-a", "mill-b"):
        m = Metrics()
        m.overruns.inc()
        fleet = FleetMetrics(lambda n=name, mm=m: {n: mm})  # type: ignore[misc]
        fleet.running.labels(machine=name).set(1)
        fleet.start_http(0, "127.0.0.1")
        servers.append(fleet)
    views = [WorkerView(0, ("mill-a",), servers[0].port),
             WorkerView(1, ("mill-b",), servers[1].port),
             WorkerView(2, ("mill-c", "mill-e"), None)]
    pool = PoolMetrics(lambda: views)
    try:
        text = pool.exposition()
    finally:
        pool.stop()
        for s in servers:
            s.stop()
    assert 'compd_overruns_total{machine="mill-a"} 1.0' in text
    assert 'compd_overruns_total{machine="mill-b"} 1.0' in text
    assert 'compd_machine_running{machine="mill-a"} 1.0' in text
    assert 'compd_machine_running{machine="mill-c"} 0.0' in text
    assert 'compd_machine_running{machine="mill-e"} 0.0' in text
    assert text.count("# TYPE compd_machine_running gauge") == 1
    assert "compd_http_connections" not in text  # the workers' own link is theirs


@pytest.mark.parametrize("argv", [["--workers", "0"], ["--workers", "two"]])
def test_a_bad_worker_count_is_refused_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["run", str(tmp_path), *argv])
    assert exc.value.code == 64
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--workers" in err


def test_workers_take_a_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write_machine(tmp_path, "mill-a", "modbus://127.0.0.1:1502")
    assert main(["run", str(path), "--workers", "2"]) == 64
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--workers" in err


def test_the_status_page_lists_a_down_workers_machines_as_off() -> None:
    pool = PoolMetrics(lambda: [WorkerView(0, ("mill-b", "mill-a"), None,
                                           paged=("mill-b", "mill-a")),
                                WorkerView(1, ("mill-c",), None)])  # no [faces.http]
    try:
        doc = pool.status_document(1.0, history=True)
    finally:
        pool.stop()
    assert [m["machine"] for m in doc["machines"]] == ["mill-a", "mill-b"]
    assert {m["state"] for m in doc["machines"]} == {"off"}
    assert all("restarting" in m["why"] for m in doc["machines"])


class _Proc:
    """A worker process as the pool sees it: killed or not."""

    pid = 4242
    returncode = None
    killed = False

    def kill(self) -> None:
        self.killed = True


@pytest.mark.parametrize(("watchdog_s", "silent_s", "killed", "event"), [
    (5.0, 4.0, False, None),           # within systemd's period
    (5.0, 6.0, True, "worker_hung"),   # past it: killed, as systemd would
    (None, 59.0, False, None),
    (None, 61.0, False, "worker_silent"),  # no watchdog: logged, never killed
])
async def test_a_silent_worker_is_killed_only_under_systemds_watchdog(
        watchdog_s: float | None, silent_s: float, killed: bool, event: str | None) -> None:
    from structlog.testing import capture_logs

    from compd.runtime.workers import WorkerPool

    pool = WorkerPool([], 1)
    pool.watchdog_s = watchdog_s
    w = pool.workers[0]
    proc = _Proc()
    w.proc, w.ready, w.last_ping = proc, True, 100.0  # type: ignore[assignment]
    try:
        with capture_logs() as logs:
            pool._check_silence(w, 100.0 + silent_s)
            pool._check_silence(w, 100.0 + silent_s + 1.0)  # logged once
    finally:
        pool.close()
        pool.metrics.stop()
    assert proc.killed is killed
    assert [e["event"] for e in logs] == ([event] if event else [])


async def test_a_worker_refusing_its_files_before_the_pool_is_ready_refuses_the_start(
        tmp_path: Path) -> None:
    """A file edited between the parent's check and the worker's load: 78, as a
    bad file at the start, rather than a pool that never becomes ready."""
    from compd.runtime.fleet import load_machines
    from compd.runtime.sdnotify import Notifier
    from compd.runtime.workers import WorkerPool

    for name, port in (("mill-a", 1502), ("mill-b", 1503)):
        _write_machine(tmp_path, name, f"modbus://127.0.0.1:{port}")
    refuse = [sys.executable, "-c", "import sys; sys.stdin.readline(); sys.exit(78)"]
    pool = WorkerPool(load_machines(tmp_path), 2, notifier=Notifier(None), command=refuse)
    assert await asyncio.wait_for(pool.run(), BOUND_S) == 78
    assert not pool.ready
