"""Disk full for the recorder and the logs: `compd run` with its recorder
database and its stderr (structlog JSON lines, every cycle at debug level) on
a 1 MiB tmpfs that the test fills up (a real ENOSPC; skipped when mounting is
not permitted). The daemon keeps compensating (offset and heartbeat writes
go on), counts the dropped records (compd_records_dropped), raises the
recorder alarm (compd_recorder_alarm and a recorder_failing event), and when
space returns, records and logs again and clears the alarm."""

from __future__ import annotations

import asyncio
import re
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from compd.runtime.recorder import read_samples
from drivers.sim.ports import free_tcp_port
from tests.configs import write_config
from tests.faults.daemon_run import RecordingSim, heartbeat, kill_and_wait, start_daemon
from tests.harness import tail, until
from tests.tmpfs import fill, small_tmpfs


@pytest.fixture
def small_fs(tmp_path: Path) -> Iterator[Path]:
    """A 1 MiB tmpfs: a file system that really runs out of space."""
    with small_tmpfs(tmp_path, "1m") as mnt:
        yield mnt


def _metrics(port: int) -> dict[str, float]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as resp:
        text = resp.read().decode()
    out: dict[str, float] = {}
    for line in text.splitlines():
        m = re.match(r"^(compd_[a-z_]+)(\{[^}]*\})? ([-+0-9.eEinfa]+)$", line)
        if m:  # labelled series under their full name: 'name{label="v"}'
            out[m.group(1) + (m.group(2) or "")] = float(m.group(3))
    return out


async def _metric(port: int, name: str) -> float:
    return (await asyncio.to_thread(_metrics, port)).get(name, 0.0)


async def test_disk_full_for_recorder_and_logs(rec: RecordingSim, small_fs: Path,
                                              tmp_path: Path) -> None:
    port = free_tcp_port("127.0.0.1")
    config = write_config(tmp_path, rec.sim.endpoint, time_scale=50.0)
    text = config.read_text()
    text = text.replace("[recorder]\ncommit_every = 10",
                        f'[recorder]\ncommit_every = 5\npath = "{small_fs / "rec.sqlite"}"')
    text = text.replace('[telemetry]\nlog_format = "json"',
                        f'[telemetry]\nlog_format = "json"\nlog_level = "debug"\n'
                        f"metrics_port = {port}")
    config.write_text(text)
    log = small_fs / "daemon.log"
    proc = await start_daemon(config, log)
    try:
        await until(lambda: _hb_past(rec, 10), proc, log, "daemon cycling")
        await until(lambda: _positive(_metric(port, "compd_offset_micrometres") ,
                                      accept_zero=True), proc, log, "metrics served")
        assert await _metric(port, "compd_records_dropped_total") == 0.0

        filler = await asyncio.to_thread(fill, small_fs)
        log_size_full = log.stat().st_size
        hb = await heartbeat(rec.sim)
        writes = len(rec.writes)
        await until(lambda: _positive(_metric(port, "compd_records_dropped_total")), proc,
                    log, "dropped records counted")
        await until(lambda: _positive(_metric(port, "compd_recorder_alarm")), proc, log,
                    "recorder alarm raised")
        # compensation goes on while neither the recorder nor the log can write
        await until(lambda: _hb_past(rec, hb + 30), proc, log, "cycling on a full disk")
        assert len(rec.writes) >= writes + 30
        assert proc.returncode is None
        dropped_full = await _metric(port, "compd_records_dropped_total")

        # space returns
        await asyncio.to_thread(filler.unlink)
        await until(lambda: _zero(_metric(port, "compd_recorder_alarm")), proc, log,
                    "recorder alarm cleared")
        hb = await heartbeat(rec.sim)
        await until(lambda: _hb_past(rec, hb + 20), proc, log, "cycling after recovery")
        dropped_after = await _metric(port, "compd_records_dropped_total")
        # fifteen more cycles (three commits of 5) counted by the controller: none dropped
        hb = await heartbeat(rec.sim)
        await until(lambda: _hb_past(rec, hb + 15), proc, log, "commits after recovery")
        assert await _metric(port, "compd_records_dropped_total") == dropped_after
        assert dropped_after >= dropped_full > 0
        proc.terminate()
        assert await asyncio.wait_for(proc.wait(), 120.0) == 0, await asyncio.to_thread(
            tail, log)
    finally:
        await kill_and_wait(proc)
    assert log.stat().st_size > log_size_full  # logging again after the disk had room
    logged = log.read_text(errors="replace")
    assert "recorder_recovered" in logged
    assert "Traceback" not in logged
    cols = read_samples(small_fs / "rec.sqlite")
    assert len(cols["seq"]) > 0
    assert cols["seq"].tolist() == list(range(1, len(cols["seq"]) + 1))
    print(f"disk full: dropped {dropped_after:g} records, offset writes went on "
          f"({len(rec.writes)} in all), {len(cols['seq'])} recorded rows")


async def _hb_past(rec: RecordingSim, n: float) -> bool:
    return await heartbeat(rec.sim) >= n


async def _positive(value: object, *, accept_zero: bool = False) -> bool:
    try:
        got = await value  # type: ignore[misc]  # a coroutine of float
    except OSError:
        return False
    return bool(got >= 0.0) if accept_zero else bool(got > 0.0)


async def _zero(value: object) -> bool:
    return bool(await value == 0.0)  # type: ignore[misc]  # a coroutine of float
