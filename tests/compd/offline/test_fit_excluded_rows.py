"""Rows masked from every loss of the fit (`FitRequest.exclude_rows`, set by
benchmarks/bench_real_record.py to hold a block out): whatever the
displacement does there, the model written is the same, and the simulation
still runs through them (the record is not cut)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from compd.infiles import load_model
from compd.offline.fit import fit_model, save_model
from compd.offline.fit_request import FitRequest


def _record(path: Path, spoil: bool) -> None:
    rng = np.random.default_rng(11)
    n = 800
    k = np.arange(n)
    heat = np.where((k // 100) % 2 == 0, 1.0, 0.0)
    t1 = np.zeros(n)
    for i in range(1, n):
        t1[i] = 0.97 * t1[i - 1] + 0.03 * heat[i]
    y = 4.0 * t1 + 0.02 * rng.standard_normal(n)
    if spoil:
        y[300:450] = 500.0
    path.write_text("time_s,t1_degC,dz_um\n" + "".join(
        f"{60 * i},{20 + t1[i]:.5f},{y[i]:.5f}\n" for i in range(n)))


def _fit(data: Path, out: Path, held: np.ndarray | None) -> None:
    # the spoiled record fitted whole: no model predicts its spoiled rows, and the
    # verdict of the inner held-out blocks refuses it; force writes it all the same
    fit = fit_model(FitRequest(data=(str(data),), output="dz_um", term=("t1_degC",),
                               orders=(2, 2), exclude_rows=held, force=held is None))
    save_model(fit.model, out)
    assert load_model(out).terms


def test_excluded_rows_change_nothing_they_are_only_not_fitted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    clean, spoiled = tmp_path / "clean.csv", tmp_path / "spoiled.csv"
    _record(clean, False)
    _record(spoiled, True)
    held = np.zeros(800, dtype=bool)
    held[300:450] = True
    for name, data, mask in (("a", clean, held), ("b", spoiled, held), ("c", spoiled, None)):
        _fit(data, tmp_path / f"{name}.toml", mask)
    a, b, c = (_coefficients(tmp_path / f"{n}.toml") for n in "abc")
    assert a and a == b
    # without the mask the spoiled rows are fitted, and the model differs
    assert c != a
    capsys.readouterr()


def _coefficients(model: Path) -> list[str]:
    return [ln for ln in model.read_text().splitlines() if ln.startswith(("a =", "b ="))]
