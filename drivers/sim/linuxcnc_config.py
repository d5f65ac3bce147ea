"""The test mill's LinuxCNC configuration, as text and as files: compd's HAL lines
(`hal_lines`, `HAL_LINES`: the file a user adds, docs/protocols.md), the HAL lines that
let G-code permit offset changes and re-zero (`mcode_hal_lines`), and the INI of a small
XYZ mill with simulated joints and external offsets on X, Y and Z (`write_config` writes
them all; `axis_eoffset_hal_lines`: X's or Y's).
The machine that runs it is `drivers.sim.linuxcnc_machine`."""

from __future__ import annotations

from pathlib import Path

#: µm per count of axis.z.eoffset-counts (axis.z.eoffset-scale 0.0001 mm)
COUNT_UM = 0.1
#: the sensor channels the plant drives (signals compd-<name>)
SENSORS: tuple[str, ...] = ("bearing", "motor", "column", "table", "ambient", "power_kw",
                            "growth_um", "error_um")



def hal_lines(prefix: str = "compd") -> str:
    """The HAL file's lines for compd, its signals named ``<prefix>-...``."""
    return f"""\
# compd: external offset of Z in counts of {COUNT_UM} µm
setp axis.z.eoffset-scale {COUNT_UM / 1000.0:g}
net {prefix}-eoffset-counts => axis.z.eoffset-counts
net {prefix}-eoffset-enable => axis.z.eoffset-enable
# compd's heartbeat and status word, for a ladder or HAL logic to watch
newsig {prefix}-heartbeat s32
newsig {prefix}-status s32
# the sensors (here the simulated plant's component drives them)
""" + "".join(f"newsig {prefix}-{name} float\n" for name in SENSORS)


#: the HAL file of docs/protocols.md
HAL_LINES = hal_lines()


def axis_eoffset_hal_lines(axis: str, prefix: str = "compd") -> str:
    """The HAL lines for an external offset of `axis` (``x`` or ``y``) too (an
    ``[output.axes.<axis>]``, docs/protocols.md): its own signals
    ``<prefix>-<axis>-eoffset-...``, in the counts of Z's."""
    return f"""\
# compd: external offset of {axis.upper()} in counts of {COUNT_UM} µm
setp axis.{axis}.eoffset-scale {COUNT_UM / 1000.0:g}
net {prefix}-{axis}-eoffset-counts => axis.{axis}.eoffset-counts
net {prefix}-{axis}-eoffset-enable => axis.{axis}.eoffset-enable
"""


def x_eoffset_hal_lines(prefix: str = "compd") -> str:
    """The HAL lines for an external offset of X (`axis_eoffset_hal_lines`)."""
    return axis_eoffset_hal_lines("x", prefix)


#: motion's digital outputs G-code sets (``M64 P<n>`` on, ``M65 P<n>`` off) that the
#: test machine's HAL joins to compd's ``[output] update_permitted`` and ``rezero``
PERMIT_DOUT = 0
REZERO_DOUT = 1


def mcode_hal_lines(prefix: str = "compd") -> str:
    """The HAL lines that let G-code permit offset changes and re-zero (docs/protocols.md)."""
    return f"""\
# compd's update_permitted and rezero, set by G-code: M64/M65 P{PERMIT_DOUT} permits
# offset changes, an M64 P{REZERO_DOUT} ... M65 P{REZERO_DOUT} pulse re-zeroes at touch-off
net {prefix}-permit <= motion.digital-out-{PERMIT_DOUT:02d}
net {prefix}-rezero <= motion.digital-out-{REZERO_DOUT:02d}
"""

INI = """\
[EMC]
MACHINE = compd-test-mill
VERSION = 1.1

[DISPLAY]
DISPLAY = dummy
POSITION_OFFSET = RELATIVE
POSITION_FEEDBACK = ACTUAL

[HAL]
HALFILE = LIB:basic_sim.tcl -no_use_hal_manualtoolchange
HALFILE = compd.hal

[TASK]
TASK = milltask
CYCLE_TIME = 0.010

[RS274NGC]
PARAMETER_FILE = sim.var

[EMCIO]
TOOL_TABLE = tool.tbl
EMCIO = io
CYCLE_TIME = 0.100

[EMCMOT]
EMCMOT = motmod
SERVO_PERIOD = 1000000

[TRAJ]
COORDINATES = XYZ
LINEAR_UNITS = mm
ANGULAR_UNITS = degree
MAX_LINEAR_VELOCITY = 50

[KINS]
JOINTS = 3
KINEMATICS = trivkins coordinates=XYZ
""" + "".join(f"""
[AXIS_{a}]
OFFSET_AV_RATIO = 0.2
MAX_VELOCITY = 50
MAX_ACCELERATION = 500
MIN_LIMIT = -100
MAX_LIMIT = 100

[JOINT_{j}]
TYPE = LINEAR
HOME_SEQUENCE = 0
MAX_VELOCITY = 50
MAX_ACCELERATION = 500
""" for j, a in enumerate("XYZ"))


def write_config(folder: Path, prefix: str = "compd") -> Path:
    """The machine's configuration in `folder` (compd's signals ``<prefix>-...``);
    returns the INI file."""
    (folder / "compd.hal").write_text(
        hal_lines(prefix) + axis_eoffset_hal_lines("x", prefix)
        + axis_eoffset_hal_lines("y", prefix) + mcode_hal_lines(prefix),
        encoding="utf-8")
    (folder / "tool.tbl").write_text("T1 P1 D6.0 Z0 ;\n", encoding="utf-8")
    (folder / "sim.var").write_text("", encoding="utf-8")
    ini = folder / "compd-test.ini"
    ini.write_text(INI, encoding="utf-8")
    return ini
