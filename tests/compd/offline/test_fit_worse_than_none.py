"""No model worse than none: `compd fit` scores the chosen
model on rows it was not calibrated on and refuses (exit 65, one line) to
write one whose error there exceeds the displacement itself, unless
--force; `compd check` flags implausible models."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.sysexits import EX_DATAERR


def _betraying_record(path: Path) -> None:
    """t1 explains the displacement for the first 40 % of the rows; then the
    displacement is back at its start while t1 climbs 6 K more (the sensor
    follows a heat source the tool does not feel)."""
    rng = np.random.default_rng(4)
    n = 1000
    t1 = 20.0 + np.repeat(rng.uniform(0.0, 2.0, n // 50), 50)
    t1[400:] = 22.0 + np.linspace(0.0, 6.0, n - 400)
    y = 2.0 * (t1 - t1[0])
    y[400:] = 0.0
    y = y + 0.05 * rng.standard_normal(n)
    rows = ["time_s,t1_degC,dz_um"] + [f"{60 * i},{a:.4f},{b:.4f}"
                                       for i, (a, b) in enumerate(zip(t1, y, strict=True))]
    path.write_text("\n".join(rows) + "\n")


def test_a_model_worse_than_none_is_not_written(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    data, out = tmp_path / "rec.csv", tmp_path / "m.toml"
    _betraying_record(data)
    argv = ["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "--orders", "1-1",
            "-o", str(out)]
    assert main(argv) == EX_DATAERR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    # refused by the forward folds, or first by the inner held-out blocks (an
    # equal part of the rows where t1 climbs and the tool does not move)
    assert ("exceeds the displacement itself there" in err
            or "no model is safer than no compensation" in err) and "--force" in err
    assert not out.exists()
    assert main([*argv, "--force", "--json"]) == 0
    captured = capsys.readouterr()
    assert "written all the same (--force)" in captured.err
    sel = json.loads(captured.out)["terms"][0]["selection"]
    assert sel["heldout_rms_um"] > sel["displacement_rms_um"] > 0.0
    assert out.exists()


def test_a_good_model_says_its_held_out_error(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(5)
    t1 = 20.0 + np.repeat(rng.uniform(0.0, 3.0, 20), 50)
    y = 2.0 * (t1 - t1[0]) + 0.05 * rng.standard_normal(t1.size)
    data = tmp_path / "good.csv"
    data.write_text("time_s,t1_degC,dz_um\n" + "".join(
        f"{60 * i},{a:.4f},{b:.4f}\n" for i, (a, b) in enumerate(zip(t1, y, strict=True))))
    assert main(["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "--orders", "1-1",
                 "-o", str(tmp_path / "g.toml")]) == 0
    text = capsys.readouterr().out
    assert "on rows it was not calibrated on: residue RMS" in text


def _model(path: Path, terms: list[tuple[str, float, list[str]]], prov: str = "") -> None:
    body = ['[model]', 'name = "hand"', 'period_s = 15.0', ""]
    for name, k, den in terms:
        a = f'["{k * sum(float(d) for d in den):.6g}"]'
        body += ["[[terms]]", f'name = "{name}"', f"inputs = {{ {name} = 1.0 }}",
                 f"a = {a}", f"b = [{', '.join(repr(d) for d in den)}]", ""]
    path.write_text("\n".join(body) + prov)


def test_check_flags_cancelling_gains_out_of_proportion_and_negative_poles(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    m = tmp_path / "bad.toml"
    # the ch4 model: -36 and +213 µm/K
    _model(m, [("t2", -36.0, ["1", "-0.9"]), ("t4", 213.0, ["1", "-0.9"]),
               ("t15", 1.0, ["1", "0.5"])])
    assert main(["check", str(m), "--json"]) == 0
    flags = json.loads(capsys.readouterr().out)["implausible"]
    assert any("term 't4': DC gain 213 µm/K is out of proportion" in f for f in flags)
    assert any("term 't15': a negative real pole -0.5" in f for f in flags)
    # with the spans `compd fit` records: 12.5 and 21.7 µm/K over 3 K on a 20 µm record
    _model(m, [("t4", -12.5, ["1", "-0.9"]), ("t6", 21.7, ["1", "-0.9"])],
           "[provenance]\nt4_input_span = 3.0\nt6_input_span = 3.0\noutput_span_um = 20.0\n")
    assert main(["check", str(m)]) == 0
    err = capsys.readouterr().err
    assert "terms 't4' and 't6' cancel" not in err  # -12.5 + 21.7 is no small difference
    assert "term 't6': DC gain 21.7 µm/K over its recorded span 3 K" not in err
    _model(m, [("t4", -30.0, ["1", "-0.9"]), ("t6", 32.0, ["1", "-0.9"])],
           "[provenance]\nt4_input_span = 3.0\nt6_input_span = 3.0\noutput_span_um = 20.0\n")
    assert main(["check", str(m)]) == 0
    err = capsys.readouterr().err
    assert "terms 't4' and 't6' cancel: DC gains -30 and +32 µm/K" in err
    assert "term 't6': DC gain 32 µm/K over its recorded span 3 K is 96 µm, out of " \
           "proportion" in err


def test_check_leaves_a_plausible_model_alone(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "sp2"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_static_fallback_is_written_and_its_json_is_strict(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Poles bounded to a 1-minute time constant on a record whose lag is
    longer: the dynamic orders fail (said), the static model is written, and
    the JSON holds no NaN (what no figure exists for is null)."""
    rng = np.random.default_rng(6)
    t1 = 20.0 + np.repeat(rng.uniform(0.0, 3.0, 20), 50)
    from scipy.signal import lfilter

    y = lfilter([0.1], [1.0, -0.95], t1 - t1[0]) + 0.05 * rng.standard_normal(t1.size)
    data = tmp_path / "lag.csv"
    data.write_text("time_s,t1_degC,dz_um\n" + "".join(
        f"{60 * i},{a:.4f},{b:.4f}\n" for i, (a, b) in enumerate(zip(t1, y, strict=True))))
    assert main(["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "--orders", "1-2",
                 "--max-time-constant-days", str(60 / 86400), "-o", str(tmp_path / "s.toml"),
                 "--json"]) == 0

    def no_nan(text: str) -> float:
        raise AssertionError(f"{text} in the JSON")

    fit = json.loads(capsys.readouterr().out, parse_constant=no_nan)
    sel = fit["terms"][0]["selection"]
    assert sel["structure"] == "static"
    assert any(n.startswith("failed: denominator orders 1-2") for n in sel["notes"])
    assert main(["check", str(tmp_path / "s.toml")]) == 0
