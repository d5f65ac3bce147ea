"""The recorder settings that go with a `compd plan` program: a TOML fragment
written beside it (``warmup.ngc`` → ``warmup.recorder.toml``) whose
``[recorder]`` table `compd run` accepts as it is (compd.config.schema's
RecorderSection), so that the daemon records the run in a database of its own
and `compd fit` takes that database whole (docs/calibration.md §2: one daemon
run per record, every row kept).
"""

from __future__ import annotations

from pathlib import PurePath

from compd.offline.plan.schedule import Experiment
from models import tomltext

#: the displacement channel's name in the fragment and the fit command it suggests
COLUMN = "dz_um"


def _where(dialect: str) -> str:
    if dialect == "linuxcnc":
        return "the HAL pin netted from motion.analog-out-00 (M68 E0 in the program)"
    return "where the measuring cycle leaves the displacement (a macro variable or PMC address)"


def database_name(program: PurePath) -> str:
    return f"{program.stem}.sqlite"


def recorder_fragment(program: PurePath, exp: Experiment, dialect: str,
                      time_scale: float = 1.0) -> str:
    """The fragment's text; `program` is the program file it belongs to,
    written with every dwell divided by `time_scale`."""
    db = database_name(program)
    hours = exp.duration_ms / 3_600_000
    every = ("no measuring cycle" if exp.probe_every_ms is None else
             f"{exp.measurements} measuring cycles, every {exp.probe_every_ms / 60_000:g} min")
    lines = [
        f"# compd plan: the recorder for the calibration run of {program.name}",
        f"# ({dialect}; {hours:g} h of schedule, {every}).",
        "#",
        "# Put the [recorder] table below in the config `compd run` uses for the run (in",
        "# place of its own), start the daemon before the program and stop it after the",
        "# program's end; then fit on the database (path relative to the config file):",
        "#",
        f"#   compd fit {db} --column {COLUMN} --candidates 't*' --max-terms 3 -o plant.toml",
        "#",
        "# (name your temperature channels in --candidates or --term). The run must not be",
        "# compensated: the displacement measured is the machine's own growth only while",
        "# the controller does not apply compd's offset (LinuxCNC: axis.z.eoffset-enable",
        "# stays 0 during the run). One daemon run, one database: compd fit refuses a",
        "# record with a restart inside. [machine] period_s must be the period the model",
        "# will run at (its coefficients are per period).",
        *([] if time_scale == 1.0 else [
            "#",
            f"# The program's dwells are divided by {time_scale:g} (compd plan --time-scale): a",
            f"# simulated machine's run. Run the daemon with [machine] time_scale = {time_scale:g}",
            "# and the plant at the same speed-up, or the record will not be the schedule."]),
        "",
        "[recorder]",
        "enabled = true",
        # a TOML string (JSON's escapes differ: a character past U+FFFF is a surrogate pair)
        f"path = {tomltext.value(db)}",
        "commit_every = 10",
        "retention_days = 0   # keep every row: the whole run is the record",
        "",
        "# The displacement the measuring cycle leaves, as a channel (the record's column):",
        f"# [channels.{COLUMN}]",
        f"# address = ...          # {_where(dialect)}",
        '# unit = "um"',
        "# range = [-1000.0, 1000.0]",
    ]
    return "\n".join(lines) + "\n"
