"""What the daemon tests share: `sim`, the simulated Modbus controller on
127.0.0.1 publishing a machine at rest (20 °C), and `shop_record`, 48 h of the
shop machine per seed, simulated once per session."""

from __future__ import annotations

import stat
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest

from compd.cli import main
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


@pytest.fixture(scope="session")
def shop_record(tmp_path_factory: pytest.TempPathFactory) -> Callable[[int], Path]:
    """`shop_record(seed)`: the CSV of `compd sim --record --machine shop --hours 48
    --period-s 60 --seed SEED`, written on first use and shared by every test of
    the session (of the xdist worker) that asks for the same seed. Read-only: a
    test that needs a changed copy writes it into its own tmp_path."""
    made: dict[int, Path] = {}

    def record(seed: int) -> Path:
        if seed not in made:
            path = tmp_path_factory.mktemp(f"shop-seed{seed}") / "shop.csv"
            assert main(["sim", "--record", str(path), "--machine", "shop", "--hours", "48",
                         "--period-s", "60", "--seed", str(seed)]) == 0
            path.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
            made[seed] = path
        return made[seed]

    return record
