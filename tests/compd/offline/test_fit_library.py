"""The fit is a library call on a typed, frozen request (`compd.offline.fit`):
without argparse it identifies the same model `compd fit` writes, and writes no
file itself; the command only turns its options into the request."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from compd.cli import build_parser, main
from compd.commands.fit import fit_request
from compd.offline.fit import fit_model, save_model
from compd.offline.fit_request import FitRequest


def _record(path: Path) -> None:
    rng = np.random.default_rng(5)
    n = 600
    k = np.arange(n)
    heat = np.where((k // 100) % 2 == 0, 1.0, 0.0)
    t1 = np.zeros(n)
    for i in range(1, n):
        t1[i] = 0.96 * t1[i - 1] + 0.04 * heat[i]
    y = 3.0 * t1 + 0.02 * rng.standard_normal(n)
    path.write_text("time_s,t1_degC,dz_um\n" + "".join(
        f"{60 * i},{20 + t1[i]:.5f},{y[i]:.5f}\n" for i in range(n)))


def _without_date(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if not ln.startswith("date =")]


def test_the_library_fit_without_argparse_is_the_model_the_command_writes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "rec.csv"
    _record(data)
    request = FitRequest(data=(str(data),), output="dz_um", term=("t1_degC",), orders=(2, 2))
    fit = fit_model(request)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv"]  # nothing written
    assert [t.name for t in fit.model.terms] == ["t1_degC"]
    assert fit.info[0]["kind"] == "tf" and fit.info[0]["selection"]["structure"]
    assert fit.search_table is None and fit.records[0].path == str(data)
    assert fit.model.provenance["command_line"] == f"compd fit {data} --column dz_um"
    save_model(fit.model, tmp_path / "lib.toml", data.name)

    assert main(["fit", str(data), "--column", "dz_um", "--term", "t1_degC", "--orders", "2-2",
                 "-o", str(tmp_path / "cmd.toml")]) == 0
    capsys.readouterr()
    lib = _without_date((tmp_path / "lib.toml").read_text())
    cmd = _without_date((tmp_path / "cmd.toml").read_text())
    assert lib == cmd and any(ln.startswith("a =") for ln in lib)


def test_the_request_is_frozen_and_every_field_is_an_option_of_the_command(
        tmp_path: Path) -> None:
    request = FitRequest(data=("a.csv",), output="dz_um", term=("bearing",))
    with pytest.raises(dataclasses.FrozenInstanceError):
        request.force = True  # type: ignore[misc]
    args = build_parser().parse_args(["fit", "a.csv", "b.csv", "--column", "dz_um", "--term",
                                      "bearing", "--orders", "1-3", "--folds", "5", "--force",
                                      "--validation-record", "c.csv", "-o", "m.toml"])
    built = fit_request(args)
    # no option sets these two: a caller's mask, and the command line the shell gave
    only_callers = {"exclude_rows", "command_line"}
    for f in dataclasses.fields(FitRequest):
        if f.name not in only_callers:
            given = getattr(args, f.name)
            assert getattr(built, f.name) == (tuple(given) if isinstance(given, list) else given)
    assert built.data == ("a.csv", "b.csv") and built.orders == (1, 3) and built.folds == 5
    assert built.input_paths() == ["a.csv", "b.csv", "c.csv"]


@pytest.mark.parametrize(("change", "field"), [
    ({"kind": "spline"}, "kind"), ({"structure": "best"}, "structure"),
    ({"orders": (3, 2)}, "orders"), ({"folds": 1}, "folds"), ({"max_terms": 0}, "max_terms"),
    ({"data": ()}, "data")])
def test_a_request_out_of_its_domain_names_the_field(change: dict[str, object],
                                                      field: str) -> None:
    good = FitRequest(data=("a.csv",), output="dz_um", term=("bearing",))
    with pytest.raises(ValueError, match=f"^{field}: "):
        dataclasses.replace(good, **change)  # type: ignore[arg-type]
