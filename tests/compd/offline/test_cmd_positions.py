"""`compd sim --machine ballscrew --record` and `compd fit --positions`: a record
with the displacement at several positions, and value and slope fitted from it."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.offline.position_record import read_position_record, with_line_columns
from compd.sysexits import EX_DATAERR, EX_USAGE

HEAD = ["time_s", "spindle_rpm", "axis_duty", "axis_speed_mm_min", "nut", "screw_bearing",
        "column", "ambient"]


def _header(path: Path) -> list[str]:
    with path.open(encoding="ascii") as f:
        return next(csv.reader(f))


def test_record_has_the_documented_columns_one_row_per_measuring_pass(tmp_path: Path) -> None:
    out = tmp_path / "bs.csv"
    assert main(["sim", "--machine", "ballscrew", "--record", str(out), "--hours", "2"]) == 0
    assert _header(out) == [*HEAD, "dx_at_0mm_um", "dx_at_200mm_um", "dx_at_400mm_um",
                            "dx_at_600mm_um", "dx_at_800mm_um"]
    pr = read_position_record(out)
    assert len(pr.record) == 25  # 2 h every 300 s, and the row at rest
    assert pr.record.period_s == 300.0
    assert pr.positions_mm == (0.0, 200.0, 400.0, 600.0, 800.0)


def test_positions_option_names_the_columns(tmp_path: Path) -> None:
    out = tmp_path / "bs.csv"
    assert main(["sim", "--machine", "ballscrew", "--record", str(out), "--hours", "1",
                 "--positions=-50,12.5,300"]) == 0
    assert _header(out)[len(HEAD):] == ["dx_at_-50mm_um", "dx_at_12.5mm_um", "dx_at_300mm_um"]


@pytest.mark.parametrize("argv", [
    ["--machine", "ballscrew", "--positions", "5"],
    ["--machine", "ballscrew", "--positions", "5,5"],
    ["--machine", "ballscrew", "--positions", "5,5.0001"],  # one column name
    ["--machine", "ballscrew", "--positions", "0,nan"],
    ["--machine", "ballscrew", "--positions", ",".join(str(x) for x in range(101))],
    ["--positions", "0,100"],  # the bench machine measures Z at one place
])
def test_bad_positions_are_a_usage_error(tmp_path: Path, argv: list[str],
                                         capsys: pytest.CaptureFixture[str]) -> None:
    code: int | str | None
    try:
        code = main(["sim", "--record", str(tmp_path / "x.csv"), *argv])
    except SystemExit as exc:  # argparse's own refusal
        code = exc.code
    assert code == EX_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "positions" in err[0]
    assert not (tmp_path / "x.csv").exists()


def test_line_columns_match_the_simulated_truth(tmp_path: Path) -> None:
    out = tmp_path / "bs.csv"
    assert main(["sim", "--machine", "ballscrew", "--record", str(out), "--hours", "6",
                 "--probe-noise-um", "0"]) == 0
    from drivers.sim.ballscrew import simulate_ballscrew

    truth = simulate_ballscrew(6.0, probe_noise_um=0.0)
    rec = with_line_columns(read_position_record(out).record, 0.0)
    # the CSV keeps 0.001 µm: the line through it is the truth to that
    np.testing.assert_allclose(rec.columns["value_um"], truth["value_um"], atol=2e-3)
    np.testing.assert_allclose(rec.columns["slope_um_m"], truth["slope_um_m"], atol=5e-3)
    shifted = with_line_columns(read_position_record(out).record, 400.0)
    np.testing.assert_allclose(shifted.columns["value_um"],
                               truth["value_um"] + 0.4 * truth["slope_um_m"], atol=3e-3)


def test_fit_positions_fits_the_slope_from_the_screw_temperatures(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "bs.csv"
    assert main(["sim", "--machine", "ballscrew", "--record", str(rec), "--hours", "24",
                 "--seed", "1"]) == 0
    capsys.readouterr()
    model = tmp_path / "slope.toml"
    assert main(["fit", str(rec), "--positions", "--column", "slope_um_m", "--term", "nut",
                 "--term", "screw_bearing", "--no-fallbacks", "--json", "-o", str(model)]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["fit_percent"] > 80.0
    assert model.exists()


def test_fit_positions_on_one_position_is_one_line_and_a_data_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "one.csv"
    rows = [f"{300 * k},20.{k % 10},{0.5 * k:.3f}" for k in range(20)]
    rec.write_text("time_s,nut,dx_at_0mm_um\n" + "\n".join(rows) + "\n", encoding="ascii")
    code = main(["fit", str(rec), "--positions", "--column", "value_um", "--term", "nut",
                 "-o", str(tmp_path / "m.toml")])
    assert code == EX_DATAERR
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "1 position(s) (dx_at_0mm_um)" in err[0] and "two or more" in err[0]
    assert not (tmp_path / "m.toml").exists()


def test_reference_position_needs_positions(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["fit", str(tmp_path / "none.csv"), "--column", "dz_um", "--term", "nut",
                 "--reference-position-mm", "100", "-o", str(tmp_path / "m.toml")])
    assert code == EX_USAGE
    assert "--positions" in capsys.readouterr().err


def test_positions_fits_only_the_value_or_the_slope(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from compd.commands.fit import POSITIONS_COLUMNS
    from compd.offline.position_record import SLOPE_COLUMN, VALUE_COLUMN

    assert POSITIONS_COLUMNS == (VALUE_COLUMN, SLOPE_COLUMN)
    code = main(["fit", str(tmp_path / "none.csv"), "--positions", "--column",
                 "dx_at_0mm_um", "--term", "nut", "-o", str(tmp_path / "m.toml")])
    assert code == EX_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "value_um or slope_um_m" in err[0]


def test_a_measured_displacement_is_never_an_input(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "bs.csv"
    assert main(["sim", "--machine", "ballscrew", "--record", str(rec), "--hours", "12"]) == 0
    capsys.readouterr()
    for term in ("dx_at_800mm_um", "value_um"):  # a position, the line's other half
        code = main(["fit", str(rec), "--positions", "--column", "slope_um_m", "--term", term,
                     "-o", str(tmp_path / "m.toml")])
        assert code == EX_DATAERR
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and term in err[0]
    # and --candidates cannot pick one either: they are not among the record's columns
    from compd.offline.position_record import line_record, read_position_record

    fitted = line_record(read_position_record(rec).record, 0.0, "slope_um_m")
    assert sorted(fitted.columns) == sorted([*HEAD[1:], "slope_um_m"])
