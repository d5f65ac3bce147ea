"""What the fault tests share: `rec`, the simulated Modbus controller that
records every offset the daemon writes (`daemon_run.RecordingSim`)."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from .daemon_run import RecordingSim


@pytest.fixture
async def rec() -> AsyncIterator[RecordingSim]:
    r = RecordingSim()
    await r.start()
    try:
        yield r
    finally:
        await r.stop()
