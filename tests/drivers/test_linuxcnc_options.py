"""LinuxCNC's addresses and driver construction (no LinuxCNC needed): what a
config may say, and what the driver refuses before it starts its HAL side."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from drivers.errors import BadAddress
from drivers.linuxcnc import LinuxCncDriver
from drivers.linuxcnc_options import LinuxCncEoffset, LinuxCncGet, LinuxCncOptions, LinuxCncPin
from drivers.protocols import spec_of

ROOT = Path(__file__).resolve().parents[2]


def test_a_pin_is_the_default_kind_and_joins_a_net() -> None:
    addr = spec_of("linuxcnc").address_adapter().validate_python(
        {"kind": "pin", "pin": "bearing", "net": "compd-bearing"})
    assert addr == LinuxCncPin(pin="bearing", net="compd-bearing")
    assert addr.type == "float" and addr.describe() == "bearing<->compd-bearing:float"


@pytest.mark.parametrize("doc", [
    {"pin": "a b", "net": "x"},                      # a space is no HAL name
    {"pin": "a", "net": "x" * 48},                   # longer than HAL_NAME_LEN
    {"pin": "a", "net": "x", "invert": True},        # invert on a float
    {"pin": "a", "net": "x", "scale": 0.0},
])
def test_bad_pins_are_refused(doc: dict[str, object]) -> None:
    with pytest.raises(ValidationError):
        LinuxCncPin.model_validate(doc)


def test_eoffset_defaults_and_bounds() -> None:
    eo = LinuxCncEoffset(kind="eoffset")
    assert (eo.axis, eo.counts_net, eo.enable_net, eo.type) == (
        "z", "compd-eoffset-counts", "compd-eoffset-enable", "s32")
    with pytest.raises(ValidationError):
        LinuxCncEoffset(kind="eoffset", axis="q")  # type: ignore[arg-type]
    with pytest.raises(ValidationError):
        LinuxCncEoffset(kind="eoffset", scale=-1.0)


def test_options_want_an_absolute_python() -> None:
    assert LinuxCncOptions().driver_options() == {"component": "compd",
                                                  "python": "/usr/bin/python3"}
    with pytest.raises(ValidationError, match="absolute path"):
        LinuxCncOptions(python="python3")


def test_gets_are_read_only() -> None:
    with pytest.raises(BadAddress, match="read only"):
        LinuxCncDriver("linuxcnc://localhost", {},
                       {"offset": LinuxCncGet(kind="get", hal="axis.z.eoffset")})


def test_one_eoffset_per_axis_and_only_as_an_output() -> None:
    eo = LinuxCncEoffset(kind="eoffset")
    with pytest.raises(BadAddress, match="output only"):
        LinuxCncDriver("linuxcnc://localhost", {"x": eo}, {})
    x = LinuxCncEoffset(kind="eoffset", axis="x", counts_net="x-counts", enable_net="x-en")
    y = LinuxCncEoffset(kind="eoffset", axis="y", counts_net="y-counts", enable_net="y-en")
    driver = LinuxCncDriver("linuxcnc://localhost", {}, {"z_off": eo, "x_off": x, "y_off": y})
    spec = driver._spec()
    assert [(e["name"], e["axis"], e["counts_pin"], e["counts_net"])
            for e in spec["eoffsets"]] == [
        ("z_off", "z", "eoffset-counts", "compd-eoffset-counts"),
        ("x_off", "x", "eoffset-x-counts", "x-counts"),
        ("y_off", "y", "eoffset-y-counts", "y-counts")]
    # two writers of X's offset: refused, naming the second and the first
    x2 = LinuxCncEoffset(kind="eoffset", axis="x", counts_net="x2-counts", enable_net="x2-en")
    with pytest.raises(BadAddress, match=r"'x_again' and 'x_off'.*axis X") as info:
        LinuxCncDriver("linuxcnc://localhost", {}, {"x_off": x, "x_again": x2})
    assert info.value.channels == ("x_again",)


def test_hal_is_local() -> None:
    with pytest.raises(ValueError, match="this machine only"):
        LinuxCncDriver("linuxcnc://mill-3.shop", {}, {})


async def test_no_hal_module_is_a_lost_link_naming_the_python(tmp_path: object) -> None:
    """A Python without LinuxCNC's hal module (here: this venv's, isolated) cannot
    be the HAL side: connect fails with the reason, as a lost link (backoff)."""
    import sys

    from drivers.errors import ConnectionLost

    driver = LinuxCncDriver("linuxcnc://localhost", {}, {}, python=sys.executable,
                            connect_timeout_s=60.0)
    try:
        with pytest.raises(ConnectionLost, match="hal"):
            await driver.connect()
    finally:
        await driver.close()


def test_check_warns_of_a_linuxcnc_config_without_machine_on(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Without output.machine_on compd cannot see LinuxCNC switch off (it would
    fight it): `compd check` says so, and passes the shipped example silently."""
    from compd.cli import main

    example = (ROOT / "compd" / "examples" / "linuxcnc.toml").read_text("utf-8")
    assert main(["check", str(ROOT / "compd" / "examples" / "linuxcnc.toml")]) == 0
    assert "warning" not in capsys.readouterr().err
    text = "\n".join(line for line in example.splitlines()
                     if not line.startswith("machine_on = "))
    path = tmp_path / "compd.toml"
    path.write_text(text,  # its relative state directory lands in tmp_path
                    encoding="utf-8")
    assert main(["check", str(path)]) == 0
    err = capsys.readouterr().err
    assert "output.machine_on is not set" in err and err.count("\n") == 1


@pytest.mark.parametrize("name", ["spindle", "motion", "Axis", "joint.compd", "iocontrol",
                                  "halui"])
def test_linuxcncs_own_names_are_refused(name: str) -> None:
    """A component named like LinuxCNC's own components and pins (``spindle`` beside
    motion's ``spindle.0.speed-out``) is refused by the options and the driver."""
    with pytest.raises(ValidationError, match="LinuxCNC uses"):
        LinuxCncOptions(component=name)
    with pytest.raises(ValueError, match="LinuxCNC uses"):
        LinuxCncDriver("linuxcnc://localhost", {}, {}, component=name)


def test_pins_longer_than_hal_allows_are_refused() -> None:
    """HAL's names hold 47 characters: ``<component>.<pin>`` as a restarted HAL side
    names it (``<component>-21.<pin>``) must fit, or HAL refuses it at every start."""
    fits = LinuxCncPin(pin="p" * (47 - len("compd-21.")), net="x")
    LinuxCncDriver("linuxcnc://localhost", {"a": fits}, {})
    long = LinuxCncPin(pin="p" * (48 - len("compd-21.")), net="x")
    with pytest.raises(BadAddress, match="too long") as info:
        LinuxCncDriver("linuxcnc://localhost", {"a": long}, {})
    assert info.value.channels == ("a",)
    with pytest.raises(BadAddress, match="eoffset"):  # the offset's own pins
        LinuxCncDriver("linuxcnc://localhost", {}, {"offset": LinuxCncEoffset(kind="eoffset")},
                       component="c" * 30)
    with pytest.raises(ValidationError, match="at most 44"):
        LinuxCncOptions(component="c" * 45)


async def test_a_hal_side_that_dies_at_start_says_why(tmp_path: Path) -> None:
    """The HAL side's stderr is kept: a start that ends without a word reports its
    last error line (HAL's own message), not only its exit status."""
    from drivers.errors import ConnectionLost

    fake = tmp_path / "python3"
    fake.write_text("#!/bin/sh\necho 'starting' >&2\n"
                    "echo \"HAL: ERROR: pin name 'x' is too long\" >&2\nexit 1\n")
    fake.chmod(0o755)
    driver = LinuxCncDriver("linuxcnc://localhost", {}, {}, python=str(fake),
                            connect_timeout_s=60.0)
    try:
        with pytest.raises(ConnectionLost, match=r"status 1\): HAL: ERROR: pin name 'x'"):
            await driver.connect()
    finally:
        await driver.close()


def test_an_unhomed_machine_is_controller_off() -> None:
    """[output] homed reading 0: the controller takes no offset (held, CONTROLLER_OFF),
    as for machine off and E-stop, not a write refused into a write fault."""
    from compd.runtime.cycle_io import _controller_off
    from drivers.base import Quality, Sample

    def states(**bits: float) -> dict[str, Sample]:
        return {n: Sample(v, 0.0, Quality.GOOD) for n, v in bits.items()}

    assert _controller_off(states(machine_on=1, estop=0, homed=0)) == "not_homed"
    assert _controller_off(states(machine_on=0, homed=0)) == "machine_off"
    assert _controller_off(states(machine_on=1, estop=0, homed=1)) is None


def test_check_warns_of_a_linuxcnc_config_without_homed(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from compd.cli import main

    example = (ROOT / "compd" / "examples" / "linuxcnc.toml").read_text("utf-8")
    assert "\nhomed = " in example
    text = "\n".join(line for line in example.splitlines() if not line.startswith("homed = "))
    path = tmp_path / "compd.toml"
    path.write_text(text,  # its relative state directory lands in tmp_path
                    encoding="utf-8")
    assert main(["check", str(path)]) == 0
    err = capsys.readouterr().err
    assert "output.homed is not set" in err and err.count("\n") == 1


def test_the_examples_commented_x_axis_checks_and_joins_the_test_machines_signals(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The shipped example compensates Z alone; its commented-out X axis, uncommented,
    passes `compd check`, and the signals it names (X's, and Y's likewise) are those the
    test machine's HAL file makes, with X's and Y's external offsets on in its INI."""
    from compd.cli import main
    from drivers.sim.linuxcnc_config import write_config

    example = (ROOT / "compd" / "examples" / "linuxcnc.toml").read_text("utf-8")
    lines, on = [], False
    for line in example.splitlines():
        on = (on or line.startswith("# [channels.x_pos]")) \
            and not line.startswith("# [output.axes.y]")
        lines.append(line.removeprefix("# ").removeprefix("#") if on else line)
    path = tmp_path / "compd.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    assert main(["check", str(path)]) == 0
    assert "output.axes.x" in "\n".join(lines)
    capsys.readouterr()
    ini = write_config(tmp_path)
    hal = (tmp_path / "compd.hal").read_text("utf-8")
    for axis in "xy":
        assert f"net compd-{axis}-eoffset-counts => axis.{axis}.eoffset-counts" in hal
        assert f"net compd-{axis}-eoffset-enable => axis.{axis}.eoffset-enable" in hal
        assert f'counts_net = "compd-{axis}-eoffset-counts"' in example
    assert ini.read_text("utf-8").count("OFFSET_AV_RATIO = 0.2") == 3


def test_sim_write_config_for_linuxcnc_names_the_example(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`compd sim --protocol linuxcnc --write-config` writes nothing (LinuxCNC runs
    itself) and says, on one line, where to start: the example with its X axis."""
    from compd.cli import main
    from compd.sysexits import EX_USAGE

    out = tmp_path / "c.toml"
    assert main(["sim", "--protocol", "linuxcnc", "--write-config", str(out)]) == EX_USAGE
    err = capsys.readouterr().err
    assert "compd/examples/linuxcnc.toml" in err and "X and Y" in err
    assert err.count("\n") == 1 and not out.exists()
