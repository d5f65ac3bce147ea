"""Absurd models and numbers in compd's own commands (and the model content
of the bad-input list): refused by `compd check`, `step`,
`replay` and `compd run` with one line and a sysexits code; a model output
far beyond the limit is a fault, not something to clamp quietly; a
ramp-to-zero shutdown is a finite number of cycles whatever the numbers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from compd.cli import main
from compd.config.loader import load_config
from compd.core.cycle import MODEL_RANGE_FACTOR, Cycle
from compd.core.output import Status
from compd.core.schedule import MAX_SHUTDOWN_CYCLES, SHUTDOWN_MARGIN_CYCLES, shutdown_ramp_cycles
from compd.errors import ConfigError
from compd.testing import FakeClock
from models.compensation import CompensationModel
from models.modelfile import parse_model
from tests.compd.core.cycle_helpers import LIMIT_UM, params, samples
from tests.configs import Toml, write_config

ROOT = Path(__file__).resolve().parents[3]
MODEL = """[model]
name = "m"
period_s = {period}
[[terms]]
name = "spindle"
inputs = {{ bearing = 1.0 }}
a = [{a}]
b = [{b}]
"""
ABSURD = {
    "huge_dc": ('"1e308", "-0.9e308"', '"1", "-0.5"', "1.0", "DC gain 2e+307"),
    "slow_pole": ('"0.5"', '"1", "-0.9999999999"', "1.0", "DC gain 5e+09"),
    "slow_tau": ('"0.0000000001"', '"1", "-0.9999999999"', "1.0", "slowest time constant"),
    "overflow": ('"1e999999999", "-1"', '"1", "-0.5"', "1.0", "outside the range of a float64"),
    "fast": ('"0.1"', '"1", "-0.9"', "1e-9", "outside 0.01 ... 3600 s"),
    "never": ('"0.1"', '"1", "-0.9"', "1e308", "outside 0.01 ... 3600 s"),
}


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "compd", *args], cwd=ROOT, check=False,
                          capture_output=True, text=True, timeout=120)


def _write(tmp_path: Path, case: str) -> tuple[Path, str]:
    a, b, period, reason = ABSURD[case]
    p = tmp_path / f"{case}.toml"
    p.write_text(MODEL.format(a=a, b=b, period=period), encoding="utf-8")
    return p, reason


@pytest.mark.parametrize("case", sorted(ABSURD))
def test_check_step_replay_refuse_with_one_line(tmp_path: Path, case: str) -> None:
    path, reason = _write(tmp_path, case)
    data = tmp_path / "data.csv"
    data.write_text("time_s,bearing,dz_um\n" + "".join(f"{k},{20 + k / 100},0\n"
                                                        for k in range(50)))
    for args, codes in ((["check", str(path)], {78}), (["step", str(path)], {65, 78}),
                        (["replay", str(path), str(data), "--column", "dz_um"], {65, 78})):
        if case in ("huge_dc", "slow_pole", "slow_tau") and args[0] != "check":
            continue  # step and replay show what a model does, absurd or not
        r = _cli(*args)
        lines = r.stderr.strip().splitlines()
        assert r.returncode in codes and len(lines) == 1, (args, r.returncode, r.stderr)
        assert reason in lines[0] and "Traceback" not in r.stderr


def _config(tmp_path: Path, *, model: str = 'file = "sp2"', period: str = "1.0",
            limit: str = "200.0", slew: str = "1.0", extra: str = "") -> Path:
    return write_config(tmp_path, base="modbus", file=Toml(model.removeprefix("file = ")),
                        period_s=Toml(period), time_scale=1.0, limit_um=Toml(limit),
                        slew_um_s=Toml(slew), swap=[("[model]\n", f"[model]\n{extra}")])


def test_run_refuses_an_absurd_model_with_78(tmp_path: Path) -> None:
    model, _ = _write(tmp_path, "huge_dc")
    cfg = _config(tmp_path, model=f'file = "{model.name}"')
    r = _cli("run", str(cfg))
    assert r.returncode == 78, r.stderr
    assert "model.file" in r.stderr and "term 'spindle': DC gain 2e+307" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_the_bounds_are_configurable(tmp_path: Path) -> None:
    model, _ = _write(tmp_path, "slow_tau")
    with pytest.raises(ConfigError, match="slowest time constant"):
        load_config(_config(tmp_path, model=f'file = "{model.name}"'))
    load_config(_config(tmp_path, model=f'file = "{model.name}"',
                        extra="max_time_constant_s = 2e10\n"))


@pytest.mark.parametrize(("kw", "key"), [
    ({"period": "1e-9"}, "machine.period_s"), ({"period": "1e308"}, "machine.period_s"),
    ({"limit": "1e308"}, "output.limit_um"), ({"slew": "1e-10"}, "output.slew_um_s"),
    ({"slew": "1e308"}, "output.slew_um_s")])
def test_absurd_period_limit_and_slew_are_refused(tmp_path: Path, kw: dict[str, str],
                                                  key: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path, **kw))
    assert err.value.key == key
    assert main(["check", str(_config(tmp_path, **kw))]) == 78


def test_shutdown_ramp_length_is_finite_whatever_the_numbers() -> None:
    assert shutdown_ramp_cycles(1e308, 1e-10, 1.0) == MAX_SHUTDOWN_CYCLES + SHUTDOWN_MARGIN_CYCLES
    assert shutdown_ramp_cycles(30.0, 1.0, 1.0) == 30 + SHUTDOWN_MARGIN_CYCLES


def _model(dc_um_per_k: float) -> CompensationModel:
    return parse_model({"model": {"period_s": 1.0}, "terms": [
        {"name": "spindle", "inputs": {"bearing": 1.0},
         "a": [str(dc_um_per_k * 0.1)], "b": ["1", "-0.9"]}]})


def test_model_output_far_beyond_the_limit_is_a_fault_not_a_clamp() -> None:
    cycle, clock = Cycle(params(slew_um_s=1000.0, hold_s=5.0), _model(1000.0)), FakeClock()
    t = clock.tick()
    cycle.plan(t, samples(t, 20.0))
    cycle.commit()
    seen = []
    for _ in range(40):
        t = clock.tick()
        cycle.plan(t, samples(t, 21.0))  # +1 K: the model heads for 1000 µm
        r = cycle.commit()
        seen.append(r)
    faulted = [r for r in seen if r.model_um is not None
               and abs(r.model_um) > MODEL_RANGE_FACTOR * LIMIT_UM]
    assert faulted
    first = seen.index(faulted[0])
    assert "model_out_of_range" in [e.name for e in faulted[0].events]
    for r in faulted:
        assert r.status & Status.MODEL_RANGE and r.status & Status.ALARM
        assert not r.inputs_valid and r.state in ("hold", "ramp")
    # held where it was, then ramped to zero: not left clamped at the limit
    assert seen[first].stage_um == seen[first - 1].stage_um
    assert seen[-1].state == "ramp" and seen[-1].stage_um == 0.0
