"""The recorder config that goes with a `compd plan` program, written beside it
(``warmup.ngc`` → ``warmup.recorder.toml``): a recorder-only daemon config
(``[output] enabled = false``: read, validate, record, nothing written to the
controller; compd.config.schema) that records the run in a database of its own,
so that `compd fit` takes that database whole (docs/calibration.md §2: one daemon
run per record, every row kept).

Given the machine's config (`compd plan --config`), the file is complete: that
config's [machine], [controller] and [channels] (already checked against the
machine), the rest recorder-only, so `compd run` takes it as it is. Without one,
the file says that [controller] and [channels] are the user's to add: compd cannot
guess a controller's addresses.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import PurePath
from typing import Any

from compd.offline.plan.dialects import num
from compd.offline.plan.schedule import Experiment
from drivers.sim.ballscrew import position_column
from models import tomltext

#: the displacement channel's name in the fragment and the fit command it suggests
COLUMN = "dz_um"


def _where(dialect: str) -> str:
    if dialect == "linuxcnc":
        return "the HAL pin netted from motion.analog-out-00 (M68 E0 in the program)"
    return "where the measuring cycle leaves the displacement (a macro variable or PMC address)"


def database_name(program: PurePath) -> str:
    return f"{program.stem}.sqlite"


def _fit_lines(db: str, positions_mm: Sequence[float]) -> list[str]:
    """The fit command(s) the header suggests: one displacement column, or the value
    and the slope of the line through the positions (`compd fit --positions`)."""
    if not positions_mm:
        return [f"#   compd fit {db} --column {COLUMN} --candidates 't*' --max-terms 3 "
                "-o plant.toml"]
    x0 = num(min(positions_mm))
    return [f"#   compd fit {db} --positions --reference-position-mm {x0} --column value_um",
            "#       --candidates 't*' --max-terms 3 -o value.toml",
            f"#   compd fit {db} --positions --reference-position-mm {x0} --column slope_um_m",
            "#       --candidates 't*' --max-terms 3 -o slope.toml"]


def _header(program: PurePath, exp: Experiment, dialect: str, time_scale: float,
            source: str | None, positions_mm: Sequence[float] = ()) -> list[str]:
    db = database_name(program)
    hours = exp.duration_ms / 3_600_000
    every = ("no measuring cycle" if exp.probe_every_ms is None else
             f"{exp.measurements} measuring {'passes' if positions_mm else 'cycles'}, every "
             f"{exp.probe_every_ms / 60_000:g} min")
    if source is None:
        what = [
            "# NOT YET RUNNABLE: add your machine's [controller] and [channels] tables (as in",
            "# the config compd runs with), or write this file with compd plan --config",
            "# YOUR-CONFIG.toml, which copies them. The rest is complete.",
        ]
    else:
        what = [
            f"# [machine], [controller] and [channels] are copied from {source}; paths in",
            "# them are relative to this file's folder. Run it as it is:",
            "#",
            f"#   compd run {program.stem}.recorder.toml",
        ]
    return [
        f"# compd plan: the recorder config for the calibration run of {program.name}",
        f"# ({dialect}; {hours:g} h of schedule, {every}).",
        "#",
        *what,
        "#",
        "# Recorder only ([output] enabled = false, no [model]): the daemon reads, validates",
        "# and records every channel and writes nothing at all to the controller (no offset,",
        "# heartbeat or status), so the run is not compensated. Start it before the program",
        "# and stop it after the program's end; then fit on the database (path relative to",
        "# this file):",
        "#",
        *_fit_lines(db, positions_mm),
        "#",
        "# (name your temperature channels in --candidates or --term). One daemon run, one",
        "# database: compd fit refuses a record with a restart inside. [machine] period_s",
        "# must be the period the model will run at (its coefficients are per period).",
        *([] if time_scale == 1.0 else [
            "#",
            f"# The program's dwells are divided by {time_scale:g} (compd plan --time-scale): a",
            f"# simulated machine's run. Run the daemon with [machine] time_scale = {time_scale:g}",
            "# and the plant at the same speed-up, or the record will not be the schedule."]),
        "",
    ]


def recorder_config(program: PurePath, exp: Experiment, dialect: str,
                    time_scale: float = 1.0, *, machine: Mapping[str, Any] | None = None,
                    source: str | None = None, positions_mm: Sequence[float] = ()) -> str:
    """The recorder config's text; `program` is the program file it belongs to,
    written with every dwell divided by `time_scale`. `machine`: the [machine],
    [controller] and [channels] tables of the machine's config (`source`, its
    name), copied in; None: left for the user to add. `positions_mm`: the
    traverse experiment's measuring positions, one displacement channel each
    (``dx_at_<x>mm_um``) in place of the one `COLUMN`."""
    db = database_name(program)
    doc: dict[str, Any] = dict(machine or {})
    doc["output"] = {"enabled": False}
    doc["recorder"] = {"enabled": True, "path": db, "commit_every": 10, "retention_days": 0}
    doc["state"] = {"dir": f"{program.stem}.state"}
    columns = [position_column(x) for x in sorted(positions_mm)] or [COLUMN]
    has_column = all(c in (machine or {}).get("channels", {}) for c in columns)
    lines = [
        *_header(program, exp, dialect, time_scale, source if machine else None,
                 positions_mm),
        tomltext.dumps(doc, header_depth=3).rstrip("\n"),
        "",
        "# retention_days = 0 keeps every row (the whole run is the record); [state] is",
        "# the run's own, apart from the compensating daemon's checkpoint.",
    ]
    if not has_column:
        lines += ["#", "# The displacement the measuring cycle leaves, as a channel (the "
                       "record's column)" + (",\n# one per position:" if positions_mm else ":")]
        for column in columns:
            lines += [
                f"# [channels.{column}]" if column == COLUMN else f'# [channels."{column}"]',
                f"# address = ...          # {_where(dialect)}",
                '# unit = "um"',
                "# range = [-1000.0, 1000.0]",
            ]
    return "\n".join(lines) + "\n"
