"""The data a structure search works on (`_Data`): the records, their folds
(`models.identify.validate.usable_splits`), whether initial conditions are
estimated, the rows any loss may count, and the memo of the least squares
asked for again; `make_data` lays them out.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from models.identify.checks import implausible
from models.identify.output_error import OeModel
from models.identify.segments import Segments
from models.identify.validate import usable_splits

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: cross-validation folds: each record in DEFAULT_FOLDS + 1 blocks, the first
#: always training (shop machine, day-2 verification of the inputs chosen on
#: day 1, seeds 2 / 1: 3 folds 89.7 / 88.0 %, 4 folds 93.7 / 93.3 %)
DEFAULT_FOLDS = 4
#: how candidates are validated (`models.identify.validate.split_masks`): forward,
#: each held-out block predicted by a model trained on the rows before it. On
#: the real record's forward split (benchmarks/bench_real_record.py) blocked
#: folds chose ch4 inputs with DC gains 46x and 64x the output's span (14.3 µm
#: MAE on the unseen 5000 rpm step), forward ones 7.8 µm; pooling both 7.1 µm
#: but ch5 14.5 µm instead of 2.9
DEFAULT_VALIDATION = "forward"


def rows_key(rows: BoolArray) -> bytes:
    """A digest of a mask of rows: equal masks, equal keys (the memo of `arx_fit`,
    the fold models a verdict may take again: `models.identify.structures.Candidate`)."""
    return hashlib.blake2b(np.packbits(rows).tobytes(), digest_size=16).digest()


@dataclass
class _Data:
    y: FloatArray
    us: list[FloatArray]
    seg: Segments
    radius: float
    #: (training rows, held-out rows) per fold
    splits: list[tuple[BoolArray, BoolArray]]
    #: initial conditions estimated (a record that starts warm) or rest at the start
    initial: bool = True
    #: the validation figure of the orders `choose_orders` found
    best_order_fit: float = -math.inf
    #: blocked folds deciding whether the initial conditions are estimated
    #: (None: the validation folds decide)
    blocked: list[tuple[BoolArray, BoolArray]] | None = None
    #: held-out records (y, inputs, segments) scoring instead of the folds
    holdout: tuple[FloatArray, list[FloatArray], Segments] | None = None
    #: the rows a loss may count: the calibration window less any rows held out
    #: (`validate.usable_splits`); None: every row. The simulation always runs
    #: over every row from each record's start; the rows outside are only never
    #: fitted nor scored
    usable: BoolArray | None = None
    #: why a final estimate is refused besides `implausible` (the caller's own
    #: diagnostics: `compd fit` vetoes a model `compd check` would warn about)
    veto: Callable[[OeModel], str | None] | None = None
    #: `arx_fit`'s estimates by (na, nb, iterations, initial, digest of the
    #: training rows): the order searches and the fold models ask for the same
    #: least squares on the same rows again (a deterministic function of them)
    arx_memo: dict[tuple[int, int, int, bool, bytes], OeModel | None] = field(
        default_factory=dict, repr=False)

    @property
    def every(self) -> BoolArray:
        """The rows a final estimate is fitted on: every usable row."""
        return self.usable if self.usable is not None else np.ones(self.y.size, dtype=bool)

    def labels(self, names: Sequence[str] | None) -> list[str]:
        """The inputs' names in messages: `names`, else "input 1", "input 2", …"""
        return list(names) if names is not None else [f"input {i + 1}" for i in range(len(self.us))]

    def refused(self, m: OeModel, labels: Sequence[str], quietly: bool = False) -> str:
        """Why the final estimate `m` is never chosen ("" when it may be); the
        output span is that of the rows it was fitted on. `quietly`: asked
        ahead, the veto's own ``quietly`` when it has one (a veto that counts
        what it refuses, `compd.offline.fit_checks.CheckVeto`, does not count it)."""
        why = implausible(m.nums, m.term_dens(), self.us, labels,
                          float(np.ptp(self.y[self.every])), self.y.size)
        if why is None and self.veto is not None:
            veto = getattr(self.veto, "quietly", self.veto) if quietly else self.veto
            why = veto(m)
        return why or ""


def make_data(y: FloatArray, inputs: Sequence[FloatArray], seg: Segments, radius: float,
              folds: int, validation: str, usable: BoolArray | None = None,
              veto: Callable[[OeModel], str | None] | None = None, blocked: bool = True
              ) -> _Data:
    """The data and folds of a validation `scheme`. `usable`: the only rows any
    loss counts (a calibration window less the rows a benchmark holds out): the
    folds are laid over them (`validate.usable_splits`), the final estimates
    fitted on them, while every model is still simulated from each record's
    start through the others. None or every row: no mask. Without `blocked`
    the blocked folds that decide the initial conditions (`choose_orders`) are
    not laid (a caller that searches no orders: two masks of every row a fold)."""
    if usable is not None:
        usable = np.asarray(usable, dtype=bool)
        if usable.shape != (seg.total,) or not usable.any():
            raise ValueError("the usable rows must mark some rows of the records")
        if usable.all():
            usable = None
    return _Data(np.asarray(y, dtype=np.float64), [np.asarray(u, dtype=np.float64)
                                                   for u in inputs],
                 seg, radius, usable_splits(seg, folds, validation, usable),
                 blocked=_blocked(seg, folds, validation, usable) if blocked else None,
                 usable=usable, veto=veto)


def _blocked(seg: Segments, folds: int, validation: str, usable: BoolArray | None = None
             ) -> list[tuple[BoolArray, BoolArray]] | None:
    return None if validation == "blocked" else usable_splits(seg, folds, "blocked", usable)
