"""The bundled simulated-machine model carries the simulated plant's rest state as its
reference (derived from drivers.sim, not typed in): `compd sim` then `compd run`
starts from it on a machine that is already warm, instead of from rest."""

from __future__ import annotations

import pytest

from compd.infiles import load_model
from drivers.sim.plant import ThermalPlant


def test_sim_machine_reference_is_the_plants_rest_state_for_compd_sims_default_seed(
        ) -> None:
    model = load_model("sim_machine")
    plant = ThermalPlant(seed=0)  # compd sim --seed's default
    rest = plant.sensors()
    assert set(model.calibration_reference) == model.reference_channels
    for ch, ref in model.calibration_reference.items():
        assert ref == pytest.approx(float(plant._x_ref[0]), abs=1e-9), ch
        assert ref == pytest.approx(rest[ch], abs=0.5), ch  # the sensors' noise only
