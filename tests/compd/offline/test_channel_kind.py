"""One rule tells a record column's kind from its name (compd.offline.channel_kind),
for fit, replay, the figures and the record checks. Before, four places guessed
with three rules; these tests pin what each caller answers now where they
differed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from compd.infiles import load_model
from compd.offline.channel_kind import ChannelKind, channel_kind, is_rate_channel
from compd.offline.model_replay import plot_inputs
from compd.offline.plots import replay_figure
from compd.offline.records import read_csv_record, speed_warnings

T, S, P = ChannelKind.TEMPERATURE, ChannelKind.SPEED, ChannelKind.POWER


@pytest.mark.parametrize(("name", "kind"), [
    ("bearing", T), ("t01_degC", T), ("ambient", T), ("T_Spindle", T), ("dz_um", T),
    ("speed_rpm", S), ("spindle_rpm", S), ("SpindleSpeed", S), ("rpm_s1", S), ("n_RPM", S),
    ("power_kw", P), ("p_kW", P), ("kw_drive", P), ("DrivePower", P),
    ("kwall_temp", T),  # "kw" inside a word is not the unit
])
def test_the_rule(name: str, kind: ChannelKind) -> None:
    assert channel_kind(name) is kind
    assert is_rate_channel(name) is (kind is not T)


def _record(tmp_path: Path, columns: dict[str, list[float]], name: str = "r.csv") -> Path:
    n = len(next(iter(columns.values())))
    header = ",".join(["time_s", *columns])
    rows = [",".join([str(10 * k), *(f"{columns[c][k]:g}" for c in columns)]) for k in range(n)]
    path = tmp_path / name
    path.write_text(header + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_fit_takes_kw_as_a_word_for_a_power() -> None:
    """fit's rule was the marker "_kw" anywhere: `kw_drive` was a temperature
    (entered relative to its first sample, checked for a mK slip); a power now."""
    assert is_rate_channel("kw_drive") and is_rate_channel("power_kw")
    assert not is_rate_channel("bearing")


def test_speed_warnings_see_a_column_that_starts_with_rpm(tmp_path: Path) -> None:
    """The record check's rule was "speed" or a name ending in rpm: `rpm_s1`
    ran at one speed for hours unnoticed; a constant power is no speed."""
    heat = [9000.0] * 200
    temp = [20 + k / 100 for k in range(200)]
    rec = read_csv_record(_record(tmp_path, {"rpm_s1": heat, "bearing": temp,
                                             "dz_um": [float(k) for k in range(200)]}))
    assert any("'rpm_s1'" in w and "constant-speed" in w for w in speed_warnings(rec))
    rec = read_csv_record(_record(tmp_path, {"power_kw": [12.0] * 200, "bearing": temp,
                                             "dz_um": [float(k) for k in range(200)]}, "p.csv"))
    assert speed_warnings(rec) == []


def test_the_figure_draws_a_power_beside_the_speed_not_as_a_temperature(tmp_path: Path) -> None:
    """The figure's rule put every non-speed on the °C axis: `power_kw (°C)`;
    and `rpm_s1` (not ending in rpm) was drawn as a temperature too."""
    t = np.arange(100.0)
    inputs = {n: 20.0 + t / 50 for n in ("bearing", "power_kw", "rpm_s1")}
    upper, _ = replay_figure(tmp_path / "f.png", t, inputs, t / 10, t / 11, title="t")
    assert upper == ["bearing (°C)", "power_kw", "rpm_s1 (rpm)"]


def test_replay_shows_the_spindle_speed_of_a_shop_record(tmp_path: Path) -> None:
    """replay's rule was "speed" in the name: the shop record's `spindle_rpm`
    (drivers/sim/shop.py) was left out of the figure; it is shown now, and a
    column the model uses is listed once."""
    model = tmp_path / "one.toml"
    model.write_text('[model]\nname = "one"\nperiod_s = 10.0\nchannels = ["bearing"]\n\n'
                     '[[terms]]\nname = "spindle"\ninputs = { bearing = 1.0 }\n'
                     'a = ["0.1", "0"]\nb = ["1", "-0.9"]\n', encoding="utf-8")
    rec = read_csv_record(_record(tmp_path, {
        "spindle_rpm": [9000.0] * 50, "bearing": [20 + k / 10 for k in range(50)],
        "t02_degC": [21.0] * 50, "dz_um": [float(k) for k in range(50)]}))
    assert list(plot_inputs(load_model(model), rec)) == ["bearing", "spindle_rpm"]
