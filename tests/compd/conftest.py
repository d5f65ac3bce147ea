"""What the daemon tests share: `sim`, the simulated Modbus controller on
127.0.0.1 publishing a machine at rest (20 °C), `shop_record`, 48 h of the
shop machine per seed, simulated once per session, and `recipe_plant`, the
calibration recipe's records and the model fitted on them, once per session."""

from __future__ import annotations

import contextlib
import io
import stat
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
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


@dataclass(frozen=True)
class RecipePlant:
    """calibration.md §3's records and model: `constant` (seed 2) and `etve`
    (seed 1) at 60 s, and `plant` fitted jointly on them with one term per
    sensor; `fit_out`, what that `compd fit` printed."""

    constant: Path
    etve: Path
    plant: Path
    fit_out: str


@pytest.fixture(scope="session")
def recipe_plant(tmp_path_factory: pytest.TempPathFactory) -> RecipePlant:
    """The calibration recipe's fit, run once per session (of the xdist worker)
    for the tests that only read it. Read-only files."""
    d = tmp_path_factory.mktemp("recipe")
    constant, etve, plant = d / "constant.csv", d / "etve.csv", d / "plant.toml"
    for argv in (["sim", "--record", str(constant), "--program", "constant", "--period-s",
                  "60", "--seed", "2"],
                 ["sim", "--record", str(etve), "--program", "etve", "--period-s", "60",
                  "--seed", "1"]):
        assert main(argv) == 0, argv
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["fit", str(constant), str(etve), "--column", "dz_um", "--term",
                     "bearing", "--term", "motor", "--term", "column", "--term", "ambient",
                     "-o", str(plant)]) == 0
    for path in (constant, etve, plant):
        path.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
    return RecipePlant(constant, etve, plant, out.getvalue())
