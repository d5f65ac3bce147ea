"""The simulated machine's zero: the bundled model carries no reference of its own
(the plant's rest temperature is seeded, so no one value fits every `compd sim
--seed`); `compd sim --write-config` writes the plant's rest state for its seed as
`[model] reference`, so `compd sim` then `compd run` on a plant already warm
starts from that zero, not from the warm temperatures."""

from __future__ import annotations

import tomllib

import pytest

from compd.commands.sim_config import config_for
from compd.config.loader import load_config
from compd.infiles import load_model
from drivers.sim.plant import ThermalPlant
from drivers.sim.programs import make_program


def test_the_bundled_model_has_no_seeded_reference() -> None:
    assert load_model("sim_machine").calibration_reference == {}


@pytest.mark.parametrize("seed", [0, 7])
def test_the_written_config_takes_the_plants_rest_state_as_its_zero(
        seed: int, tmp_path: object) -> None:
    program = make_program("spectrum", seed=seed)
    plant = ThermalPlant(seed=seed, params=program.plant_params())
    text = config_for("modbus", "modbus://127.0.0.1:5020", 60.0, None, "test", plant.rest_c)
    ref = tomllib.loads(text)["model"]["reference"]
    assert set(ref) == {"bearing", "motor", "column", "ambient"}
    # the plant's growth is zero there: every node at rest, as its sensors read
    rest = plant.sensors()
    for ch, value in ref.items():
        assert value == plant.rest_c
        assert value == pytest.approx(rest[ch], abs=0.5), ch  # the sensors' noise only
    assert ThermalPlant(seed=seed + 1).rest_c != plant.rest_c  # seeded: per server
    path = tmp_path / "c.toml"  # type: ignore[operator]
    path.write_text(text, encoding="utf-8")
    cfg = load_config(path)
    assert cfg.model.calibration_reference == ref


def test_a_plantless_server_writes_no_reference() -> None:
    text = config_for("modbus", "modbus://127.0.0.1:5020", 60.0, None, "test", None)
    assert "reference" not in tomllib.loads(text)["model"]
