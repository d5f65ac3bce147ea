"""`compd refine` on hostile probes: a value beyond any offset compd accepts is refused
naming its row (residuals of ±1e300 or ±1e7 µm ended in a traceback, exit 1), and
every refined setting is held within the bounds `compd check` holds a model's
[adaptation] table to, naming those that met one."""

from __future__ import annotations

import json
import sqlite3
import tomllib
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.config.schema import MAX_LIMIT_UM, learnt_bounds
from compd.sysexits import EX_DATAERR
from tests.compd.offline.test_refine import _MODEL, _walk
from tests.compd.store.test_recorder_hostile import _recorder


def _csv(path: Path, rows: list[tuple[float, float, float]]) -> Path:
    path.write_text("time_s,measured_um,model_um\n"
                    + "".join(f"{t!r},{m!r},{p!r}\n" for t, m, p in rows))
    return path


@pytest.mark.parametrize(("value", "model_um", "words"), [
    (1e300, 0.0, "row 5: measured_um 1e+300 µm is beyond ±10000 µm"),
    (-1e300, 0.0, "row 5: measured_um -1e+300 µm is beyond ±10000 µm"),
    (1e7, 0.0, "row 5: measured_um 1e+07 µm is beyond ±10000 µm"),
    (0.0, -1e7, "row 5: model_um -1e+07 µm is beyond ±10000 µm"),
    (9000.0, -9000.0, "row 5: measured − model 18000 µm is beyond ±10000 µm"),
    (1.7e308, -1.7e308, "row 5: measured_um 1.7e+308 µm"),  # (its difference overflows)
])
def test_a_probe_beyond_any_offset_is_refused_naming_its_row(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], value: float, model_um: float,
        words: str) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    rows = [(3600.0 * k, 1.0, 0.0) for k in range(20)]
    rows[3] = (rows[3][0], value, model_um)  # the 4th probe: line 5 of the file
    log = _csv(tmp_path / "probes.csv", rows)
    out = tmp_path / "o.toml"
    assert main(["refine", str(model), str(log), "-o", str(out)]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"compd refine: {log}: {words}"), err
    assert not out.exists()


def test_the_bound_is_the_largest_offset_check_accepts(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    rows = [(3600.0 * k, MAX_LIMIT_UM * (-1) ** k, 0.0) for k in range(20)]
    assert main(["refine", str(model), str(_csv(tmp_path / "edge.csv", rows)), "-o",
                 str(tmp_path / "o.toml"), "--json"]) == 0
    capsys.readouterr()


def test_a_recorders_probe_beyond_any_offset_is_refused_naming_its_seq(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = _recorder(tmp_path / "samples.sqlite")
    with sqlite3.connect(db) as conn:
        conn.execute("UPDATE probes SET measured_um = -2e7 WHERE seq = 13")
    conn.close()
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    assert main(["refine", str(model), str(db), "-o", str(tmp_path / "o.toml")]) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "probe seq 13: measured_um -2e+07 µm is beyond" in err, err


def _wild(path: Path) -> Path:
    """Probes a minute apart swinging ±2 mm: a drift and a step far past any bound."""
    return _csv(path, [(60.0 * k, 2000.0 * (-1) ** k, 0.0) for k in range(20)])


def test_refined_settings_are_held_at_checks_bounds_and_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    out = tmp_path / "refined.toml"
    log = _wild(tmp_path / "wild.csv")
    assert main(["refine", str(model), str(log), "-o", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    bounds = learnt_bounds()
    assert set(figures["at_bound"]) == {"bias_rw_um_per_sqrt_h", "max_step_um"}
    assert figures["at_bound"]["bias_rw_um_per_sqrt_h"] > 1e4
    assert figures["at_bound"]["max_step_um"] == pytest.approx(16000.0)
    table = tomllib.loads(out.read_text())["adaptation"]
    assert table["bias_rw_um_per_sqrt_h"] == bounds["bias_rw_um_per_sqrt_h"][1] == 100.0
    assert table["max_step_um"] == bounds["max_step_um"][1] == MAX_LIMIT_UM
    for key, value in figures["after"].items():
        lo, hi = bounds[key]
        assert lo <= value <= hi and table[key] == value, key
    # the refined model is one check takes
    assert main(["check", str(out)]) == 0
    capsys.readouterr()
    assert main(["refine", str(model), str(log), "-o", str(out), "--force"]) == 0
    lines = capsys.readouterr().out.splitlines()
    held = [line for line in lines if "held at the bound" in line]
    assert len(held) == 2 and "bias_rw_um_per_sqrt_h" in held[0] and "→ 100 " in held[0]
    assert "max_step_um" in held[1] and "→ 10000 " in held[1] and "1.6e+04" in held[1]


def test_the_bounds_are_checks_not_a_copy(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    from compd.config import schema

    monkeypatch.setitem(schema.ADAPTATION_BOUNDS, "bias_rw_um_per_sqrt_h", (0.0, 42.0))
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    out = tmp_path / "refined.toml"
    assert main(["refine", str(model), str(_wild(tmp_path / "wild.csv")), "-o", str(out),
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["after"]["bias_rw_um_per_sqrt_h"] == 42.0


def test_a_drift_within_the_bounds_is_written_as_measured(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "m.toml"
    model.write_text(_MODEL)
    t = np.arange(50) * 3600.0
    log = _csv(tmp_path / "drift.csv",
               [(float(ti), float(r), 0.0) for ti, r in zip(t, _walk(1, t, 50.0, 0.2),
                                                             strict=True)])
    out = tmp_path / "refined.toml"
    assert main(["refine", str(model), str(log), "-o", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["at_bound"] == {}
    assert figures["after"]["bias_rw_um_per_sqrt_h"] == pytest.approx(50.0, rel=0.3)
