"""A record as plain columns for the simulator's tests, read by the one CSV
reader compd has (`compd.offline.records`): what the simulator writes is what
`compd fit` reads, row checks and all (drivers/sim only writes records)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

from compd.offline.records import read_csv_record


def read_columns(path: str | Path) -> dict[str, npt.NDArray[np.float64]]:
    """time_s first (as the simulator writes it, from 0), then every column."""
    rec = read_csv_record(path)
    return {"time_s": rec.time_s, **rec.columns}
