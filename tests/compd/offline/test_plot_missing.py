"""`--plot` without matplotlib (the `plot` extra): `compd replay`, `demo` and `step`
end before their work in one line naming the extra, exit 69, as `export` does for
Parquet without pyarrow (they ended in a traceback after the work). matplotlib is
hidden from a child interpreter by an import hook, never uninstalled."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from compd.sysexits import EX_UNAVAILABLE

#: run compd with every import of `module` (and its submodules) failing as a missing
#: package does
_HIDDEN = """
import sys

class Hide:
    def find_spec(self, name, path=None, target=None):
        if name == {module!r} or name.startswith({module!r} + "."):
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None

sys.meta_path.insert(0, Hide())
from compd.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _compd(argv: list[str], hidden: str = "matplotlib") -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", _HIDDEN.format(module=hidden), *argv],
                          capture_output=True, text=True, timeout=120, check=False)


def _replay_inputs(tmp_path: Path) -> list[str]:
    model = tmp_path / "one.toml"
    model.write_text('[model]\nname = "one"\nperiod_s = 1.0\nchannels = ["bearing"]\n\n'
                     '[[terms]]\nname = "spindle"\ninputs = { bearing = 1.0 }\n'
                     'a = ["0.1", "0"]\nb = ["1", "-0.9"]\n', encoding="utf-8")
    rec = tmp_path / "one.csv"
    rec.write_text("time_s,bearing,dz_um\n" + "".join(
        f"{k},{25 + k / 100:.2f},{k / 100:.3f}\n" for k in range(300)), encoding="utf-8")
    return ["replay", str(model), str(rec), "--column", "dz_um"]


@pytest.mark.parametrize("command", ["replay", "demo", "step"])
def test_plot_without_matplotlib_is_one_line_and_69_before_the_work(
        tmp_path: Path, command: str) -> None:
    figure = tmp_path / "f.png"
    argv = {"replay": _replay_inputs(tmp_path),
            "demo": ["demo", "--hours", "0.5", "--seconds", "2"],
            "step": ["step", "sp2"]}[command]
    done = _compd([*argv, "--plot", str(figure)])
    assert done.returncode == EX_UNAVAILABLE, done.stderr
    assert done.stderr == (f"compd {command}: a figure (--plot) needs matplotlib: "
                           "pip install 'compd[plot]'\n")
    assert done.stdout == ""  # no figures printed: the work never began
    assert not figure.exists()
    # without --plot the same command needs no matplotlib
    if command == "step":
        assert _compd(argv).returncode == 0


def test_a_missing_dependency_of_matplotlib_is_named(tmp_path: Path) -> None:
    done = _compd(["step", "sp2", "--plot", str(tmp_path / "f.png")], hidden="kiwisolver")
    assert done.returncode == EX_UNAVAILABLE, done.stderr
    assert done.stderr == ("compd step: a figure (--plot) needs matplotlib ('kiwisolver', "
                           "which it needs, is missing): pip install 'compd[plot]'\n")
