"""What the daemon tests share: `sim`, the simulated Modbus controller on
127.0.0.1 publishing a machine at rest (20 °C)."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from drivers.sim.modbus_server import ModbusSimController


@pytest.fixture
async def sim() -> AsyncIterator[ModbusSimController]:
    controller = ModbusSimController()
    await controller.start()
    await controller.publish({"bearing": 20.0, "ambient": 20.0})
    try:
        yield controller
    finally:
        await controller.stop()
