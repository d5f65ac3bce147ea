"""A refused combined write is counted once per output it carried: the label
values are output names, never the names joined."""

from __future__ import annotations

import asyncio
from pathlib import Path

from compd.config.loader import load_config
from drivers.errors import WriteRejected
from tests.configs import write_config
from tests.harness import memory_daemon


async def test_each_output_of_a_refused_write_is_its_own_label(tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, "127.0.0.1:1", time_scale=1.0, timeout_s=0.4))
    daemon, clock, driver = memory_daemon(cfg)
    task = asyncio.create_task(daemon.run())
    try:
        await clock.cycle_done(1)
        driver.fail_next_write = WriteRejected("busy", channel=("offset", "heartbeat", "status"))
        clock.tick()
        await clock.cycle_done(2)
    finally:
        daemon.request_stop()
        assert await task == 0

    def count(output: str) -> float | None:
        return daemon.metrics.registry.get_sample_value("compd_write_errors_total",
                                                        {"output": output})

    assert [count(o) for o in ("offset", "heartbeat", "status")] == [1.0, 1.0, 1.0]
    assert count("offset,heartbeat,status") is None
    # the offset did not arrive: a transient failure, retried (not stopped)
    assert daemon.running.cycle is not None and not daemon.running.cycle.health.write_stopped
