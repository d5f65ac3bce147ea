"""The simulated thermal plant: determinism, thermal sanity, sensors, cooler,
growth magnitudes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivers.sim import CHANNELS
from drivers.sim.plant import PlantParams, ThermalPlant

HOUR_S = 3600.0
#: a quiet room: no daily swing, no random walk
QUIET = PlantParams(ambient_day_amplitude_k=0.0, ambient_walk_std_k=0.0)
QUIET_NO_COOLER = dataclasses.replace(QUIET, cooler_enabled=False)


def run(plant: ThermalPlant, hours: float, speed_rpm: float, dt_s: float = 60.0) -> None:
    for _ in range(round(hours * HOUR_S / dt_s)):
        plant.step(dt_s, speed_rpm)


def trace(plant: ThermalPlant, hours: float, speed_rpm: float,
          dt_s: float = 60.0) -> dict[str, np.ndarray]:
    rows = []
    for _ in range(round(hours * HOUR_S / dt_s)):
        plant.step(dt_s, speed_rpm)
        rows.append({**plant.temperatures(), "growth_um": plant.growth_um()})
    return {k: np.array([r[k] for r in rows]) for k in rows[0]}


def sequence(seed: int) -> list[dict[str, float]]:
    plant = ThermalPlant(seed=seed)
    out = []
    for k in range(300):
        plant.step(10.0, 2_000.0 + 20.0 * k)
        out.append(plant.sensors())
    return out


def test_same_seed_same_numbers_other_seed_other_numbers() -> None:
    assert sequence(3) == sequence(3)
    assert sequence(3) != sequence(4)


def test_sensors_have_the_standard_names_and_start_at_equilibrium() -> None:
    plant = ThermalPlant(seed=1, params=QUIET)
    s = plant.sensors()
    assert set(s) == set(CHANNELS)
    assert s["growth_um"] == 0.0
    assert s["spindle_rpm"] == 0.0
    assert s["power_kw"] == 0.0
    for name in ("bearing", "motor", "column", "table", "ambient"):
        assert abs(s[name] - 20.0) <= 0.2


def test_room_is_a_function_of_time_not_of_step_size() -> None:
    fine, coarse = ThermalPlant(seed=9), ThermalPlant(seed=9)
    for _ in range(3600):
        fine.step(1.0, 6_000.0)
    for _ in range(60):
        coarse.step(60.0, 6_000.0)
    assert fine.time_s == pytest.approx(coarse.time_s)
    a, b = fine.temperatures(), coarse.temperatures()
    for name in a:
        assert a[name] == pytest.approx(b[name], abs=1e-9)
    assert fine.growth_um() == pytest.approx(coarse.growth_um(), abs=1e-9)


def test_temperatures_are_quantised_to_a_tenth_of_a_kelvin() -> None:
    plant = ThermalPlant(seed=5)
    for _ in range(50):
        plant.step(30.0, 8_000.0)
        s = plant.sensors()
        true = plant.temperatures()
        for name in ("bearing", "motor", "column", "table", "ambient"):
            tenths = s[name] * 10.0
            assert abs(tenths - round(tenths)) < 1e-9, (name, s[name])
            assert abs(s[name] - true[name]) <= 0.2  # 0.05 rounding + noise σ 0.03


def test_heat_up_rises_and_saturates_and_cool_down_decays() -> None:
    plant = ThermalPlant(seed=0, params=QUIET_NO_COOLER)
    heat = trace(plant, 8.0, 9_000.0)
    bearing = heat["bearing"] - 20.0
    assert np.all(np.diff(bearing) > 0.0)
    first_hour, last_hour = bearing[59] - bearing[0], bearing[-1] - bearing[-61]
    assert last_hour < 0.05 * first_hour  # saturating: the last hour adds little
    assert heat["motor"][-1] > heat["bearing"][-1] > heat["column"][-1] > 20.0
    # the shaft (growth) lags the bearing sensor
    assert heat["shaft"][30] - 20.0 < bearing[30]

    cool = trace(plant, 8.0, 0.0)
    rise = cool["bearing"] - 20.0
    assert np.all(np.diff(rise) < 0.0)
    assert rise[-1] < 0.1 * bearing[-1]
    assert cool["growth_um"][-1] < 0.2 * heat["growth_um"][-1]


def test_column_is_the_slow_node_and_spindle_nodes_are_fast() -> None:
    plant = ThermalPlant(seed=0, params=QUIET_NO_COOLER)
    heat = trace(plant, 12.0, 9_000.0)
    for name, lo_min, hi_min in (("bearing", 10, 60), ("motor", 10, 60), ("column", 120, 600)):
        rise = heat[name] - 20.0
        t63 = int(np.argmax(rise >= 0.632 * rise[-1]))  # minutes (dt = 60 s)
        assert lo_min <= t63 <= hi_min, (name, t63)


@pytest.mark.parametrize("cooler", [False, True])
def test_growth_of_a_9000_rpm_heat_up_is_tens_of_micrometres(cooler: bool) -> None:
    params = dataclasses.replace(QUIET, cooler_enabled=cooler)
    plant = ThermalPlant(seed=0, params=params)
    run(plant, 4.0, 9_000.0)
    assert 20.0 <= plant.growth_um() <= 60.0


def test_cooler_switches_with_hysteresis_and_limits_the_growth() -> None:
    p = QUIET
    plant = ThermalPlant(seed=0, params=p)
    switches: list[tuple[bool, float]] = []
    was_on = plant.cooler_on
    for k in range(2 * 8 * 360):
        before = plant.temperatures()["bearing"]
        plant.step(10.0, 9_000.0 if k < 8 * 360 else 0.0)
        if plant.cooler_on != was_on:
            switches.append((plant.cooler_on, before))
            was_on = plant.cooler_on
    assert switches, "the cooler never switched"
    assert switches[0][0] is True
    assert switches[-1][0] is False  # off again after the cool-down
    for on, bearing_c in switches:
        if on:
            assert bearing_c > p.cooler_on_c - 0.5
        else:
            assert bearing_c < p.cooler_off_c + 0.5

    hot = ThermalPlant(seed=0, params=QUIET_NO_COOLER)
    cooled = ThermalPlant(seed=0, params=QUIET)
    run(hot, 4.0, 9_000.0)
    run(cooled, 4.0, 9_000.0)
    assert cooled.temperatures()["bearing"] < hot.temperatures()["bearing"] - 5.0
    assert cooled.growth_um() < hot.growth_um() - 10.0


def test_room_swing_moves_the_column_and_the_growth() -> None:
    params = PlantParams(ambient_day_amplitude_k=3.0, ambient_walk_std_k=0.0)
    plant = ThermalPlant(seed=2, params=params)
    day = trace(plant, 24.0, 0.0)
    assert np.ptp(day["ambient"]) == pytest.approx(6.0, abs=0.1)
    assert 1.0 < np.ptp(day["column"]) < np.ptp(day["ambient"])
    assert int(np.argmax(day["column"])) > int(np.argmax(day["ambient"]))  # it lags
    assert 3.0 <= np.ptp(day["growth_um"]) <= 40.0


def test_default_room_drifts_a_few_micrometres_over_a_day() -> None:
    plant = ThermalPlant(seed=11)
    day = trace(plant, 24.0, 0.0)
    assert 0.5 <= np.ptp(day["ambient"]) <= 5.0
    assert 1.0 <= np.ptp(day["growth_um"]) <= 20.0


def test_power_follows_speed_and_load() -> None:
    plant = ThermalPlant(seed=0)
    q_b, q_m, idle = plant.losses_w(9_000.0, 0.0)
    assert q_b > 0.0 and q_m > 0.0
    assert 0.3 <= idle <= 2.0
    _, _, cutting = plant.losses_w(9_000.0, 0.5)
    assert cutting > idle + 5.0
    assert plant.losses_w(0.0, 0.0) == (0.0, 0.0, 0.0)
    assert plant.losses_w(10_000.0, 0.0)[2] > plant.losses_w(5_000.0, 0.0)[2]


def test_offset_turns_growth_into_error() -> None:
    plant = ThermalPlant(seed=0)
    run(plant, 1.0, 9_000.0)
    plant.offset_um = 12.5
    s = plant.sensors()
    assert s["error_um"] == pytest.approx(s["growth_um"] - 12.5)


@pytest.mark.parametrize(("dt_s", "speed", "load"),
                         [(0.0, 1_000.0, 0.0), (-1.0, 1_000.0, 0.0), (float("nan"), 0.0, 0.0),
                          (1.0, 10_001.0, 0.0), (1.0, -1.0, 0.0), (1.0, 1_000.0, 1.5)])
def test_step_refuses_impossible_inputs(dt_s: float, speed: float, load: float) -> None:
    with pytest.raises(ValueError):
        ThermalPlant(seed=0).step(dt_s, speed, load)
