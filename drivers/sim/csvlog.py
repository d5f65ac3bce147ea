"""Calibration records as CSV: one row per sample, a fixed header.

    time_s,spindle_rpm,bearing,motor,column,table,ambient,power_kw,dz_um

``time_s`` machine time (s); temperatures in °C as the controller shows them
(0.1 K); ``power_kw`` drive power; ``dz_um`` the Z growth a probe measured (µm).
This is what `compd sim --record` writes and what `compd fit` reads. The
simulator only writes records: they are read (and checked: sampling, cells,
units) by the one reader, `compd.offline.records`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

RECORD_COLUMNS: tuple[str, ...] = ("time_s", "spindle_rpm", "bearing", "motor", "column",
                                   "table", "ambient", "power_kw", "dz_um")
#: printf formats per column (temperatures keep their 0.1 K, growth 0.001 µm)
_FORMATS: dict[str, str] = {"time_s": "{:.3f}", "spindle_rpm": "{:.0f}", "bearing": "{:.1f}",
                            "motor": "{:.1f}", "column": "{:.1f}", "table": "{:.1f}",
                            "ambient": "{:.1f}", "power_kw": "{:.3f}", "dz_um": "{:.3f}"}


def write_record(path: str | os.PathLike[str], columns: Mapping[str, np.ndarray]) -> int:
    """Write the columns (all of `RECORD_COLUMNS`, equal length) to `path`;
    return the number of data rows. The file is written to a temporary name
    and renamed, so a reader never sees half a record."""
    missing = [c for c in RECORD_COLUMNS if c not in columns]
    if missing:
        raise ValueError(f"record lacks columns {missing}")
    lengths = {len(columns[c]) for c in RECORD_COLUMNS}
    if len(lengths) != 1:
        raise ValueError(f"record columns differ in length: {sorted(lengths)}")
    target = Path(path)
    tmp = target.with_name(target.name + ".part")
    row_fmt = ",".join(_FORMATS[c] for c in RECORD_COLUMNS) + "\n"
    rows = zip(*(np.asarray(columns[c], dtype=np.float64).tolist() for c in RECORD_COLUMNS),
               strict=True)
    n = 0
    with tmp.open("w", encoding="ascii", newline="") as f:
        f.write(",".join(RECORD_COLUMNS) + "\n")
        for row in rows:
            f.write(row_fmt.format(*row))
            n += 1
    os.replace(tmp, target)
    return n
