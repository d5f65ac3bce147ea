"""Test programs (ISO 230-3 heat-up/cool-down, speed spectrum, ETVE)."""

from __future__ import annotations

import pytest

from drivers.sim.plant import PlantParams
from drivers.sim.programs import PROGRAM_NAMES, constant, etve, make_program, spectrum

H = 3600.0


def test_constant_heats_then_cools_then_stands() -> None:
    p = constant()
    assert p.duration_s == 8 * H
    assert p(0.0) == p(4 * H - 1.0) == 9_000.0
    assert p(4 * H) == p(8 * H - 1.0) == 0.0
    assert p(8 * H) == p(100 * H) == p(-1.0) == 0.0
    short = make_program("constant", hours=2.0)
    assert short.duration_s == 2 * H
    assert short(H - 1.0) == 9_000.0 and short(H) == 0.0


def test_spectrum_holds_a_level_for_30_minutes_within_the_speed_range() -> None:
    p = spectrum(seed=4)
    assert p.duration_s == 12 * H
    block = 30 * 60.0
    levels = [p(k * block) for k in range(24)]
    for k, level in enumerate(levels):
        assert 500.0 <= level <= 10_000.0
        assert level % 100.0 == 0.0
        assert p(k * block + block - 1.0) == level
    assert len(set(levels)) > 12
    assert max(levels) - min(levels) > 5_000.0
    assert p(12 * H) == 0.0


def test_spectrum_is_seeded() -> None:
    t = [k * 1800.0 for k in range(24)]
    assert [spectrum(seed=1)(x) for x in t] == [spectrum(seed=1)(x) for x in t]
    assert [spectrum(seed=1)(x) for x in t] != [spectrum(seed=2)(x) for x in t]
    assert make_program("spectrum", seed=1, hours=3.0).duration_s == 3 * H


def test_etve_rests_the_spindle_and_swings_the_room() -> None:
    p = etve()
    assert p.duration_s == 24 * H
    assert all(p(k * 600.0) == 0.0 for k in range(144))
    params = p.plant_params(PlantParams(ambient_day_amplitude_k=1.0))
    assert params.ambient_day_amplitude_k == 3.0
    assert constant().plant_params(params) is params


def test_lookup_by_name() -> None:
    assert set(PROGRAM_NAMES) == {"constant", "spectrum", "etve"}
    for name in PROGRAM_NAMES:
        assert make_program(name).name == name
    with pytest.raises(ValueError, match="unknown program"):
        make_program("warmup")
