"""What every step of `compd fit`'s choice shares: the term a model to write
is made of (`FitTerm`) and the rows every loss may count (`usable_rows`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from compd.offline.fit_request import FitRun

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class FitTerm:
    """One term of the model to write: a channel combination, its input as
    fitted, its transfer function."""

    name: str
    inputs: dict[str, float]
    u: FloatArray
    num: tuple[float, ...]
    den: tuple[float, ...]
    relative: bool


def usable_rows(args: FitRun) -> npt.NDArray[np.bool_] | None:
    """The rows of the records (concatenated) that every loss, fold and
    prefilter may count, or None (every row): the calibration window
    (``args.fit_window``, set from ``--from``) less the rows held out
    (``args.request.exclude_rows``: no flag sets it; a caller that scores the whole
    procedure on rows it holds out, benchmarks/bench_real_record.py, sets it).
    The rows outside still run through every model from each record's start,
    as the daemon runs it; they are never fitted nor validated on."""
    window = getattr(args, "fit_window", None)
    ex = args.request.exclude_rows
    masks: list[npt.NDArray[np.bool_]] = []
    if window is not None:
        masks.append(np.asarray(window, dtype=np.bool_))
    if ex is not None:
        masks.append(~np.asarray(ex, dtype=np.bool_))
    if not masks:
        return None
    return np.logical_and.reduce(masks) if len(masks) > 1 else masks[0]
