"""What the daemon tests share: `sim`, the simulated Modbus controller on
127.0.0.1 publishing a machine at rest (20 °C), `shop_record`, 48 h of the
shop machine per seed, simulated once per run, and `recipe_plant`, the
calibration recipe's records and the model fitted on them, once per run."""

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
from tests.run_shared import made_once


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
    the run (every xdist worker: `tests.run_shared`) that asks for the same seed.
    Read-only: a test that needs a changed copy writes it into its own tmp_path."""

    def record(seed: int) -> Path:
        def make(folder: Path) -> None:
            path = folder / "shop.csv"
            assert main(["sim", "--record", str(path), "--machine", "shop", "--hours", "48",
                         "--period-s", "60", "--seed", str(seed)]) == 0
            path.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)

        return made_once(tmp_path_factory, f"shop-seed{seed}", make) / "shop.csv"

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
    """The calibration recipe's fit, run once per run (every xdist worker:
    `tests.run_shared`) for the tests that only read it. Read-only files."""

    def make(d: Path) -> None:
        constant, etve, plant = d / "constant.csv", d / "etve.csv", d / "plant.toml"
        for argv in (["sim", "--record", str(constant), "--program", "constant",
                      "--period-s", "60", "--seed", "2"],
                     ["sim", "--record", str(etve), "--program", "etve", "--period-s", "60",
                      "--seed", "1"]):
            assert main(argv) == 0, argv
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            assert main(["fit", str(constant), str(etve), "--column", "dz_um", "--term",
                         "bearing", "--term", "motor", "--term", "column", "--term",
                         "ambient", "-o", str(plant)]) == 0
        (d / "fit_out.txt").write_text(out.getvalue(), encoding="utf-8")
        for path in (constant, etve, plant, d / "fit_out.txt"):
            path.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)

    d = made_once(tmp_path_factory, "recipe", make)
    return RecipePlant(d / "constant.csv", d / "etve.csv", d / "plant.toml",
                       (d / "fit_out.txt").read_text(encoding="utf-8"))
