"""`compd fit`'s records: read and checked (one period, the units of the
temperatures, only the columns the fit reads), cut to the calibration rows
(``until``, ``fit_from``), the folds checked against the shortest; and, for a
long record, the memory its freed columns held given back."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from compd.offline.fit_request import DEFAULT_FOLDS, MIN_FOLD_ROWS
from compd.sysexits import EX_USAGE

if TYPE_CHECKING:
    from compd.offline.fit_request import FitRequest, FitRun
    from compd.offline.records import Record


def check_folds(run: FitRun, records: list[Record]) -> None:
    """--folds as given, if each of its K + 1 blocks of the shortest record
    holds MIN_FOLD_ROWS rows (else a usage error, 64, naming the flag); the
    default when not given."""
    from compd.infiles import InputError

    if run.request.folds is None:
        run.folds = DEFAULT_FOLDS
        return
    run.folds = run.request.folds
    shortest = min(int((r.time_s >= (run.request.fit_from or 0.0) - 1e-9).sum()) for r in records)
    most = shortest // MIN_FOLD_ROWS - 1
    if run.folds > most:
        hint = f"give --folds {most} or fewer" if most >= 2 else "the record is too short"
        raise InputError(f"--folds {run.folds}: the shortest record has {shortest} rows, too "
                         f"few for {run.folds + 1} blocks of {MIN_FOLD_ROWS} rows; {hint}",
                         EX_USAGE)


def read_records(paths: list[str], request: FitRequest, channels: set[str],
                  first: Record | None = None) -> list[Record]:
    """Read and check records; all must share `first`'s (or the first one's) period."""
    import math

    from compd.offline.channel_kind import ChannelKind, channel_kind, is_rate_channel
    from compd.offline.records import RecordError, check_units, columns_named, read_record

    records: list[Record] = []
    wanted = [request.output, *sorted(channels), *([request.switch] if request.switch else [])]
    only = bool(channels) and not request.fixed and not request.candidates \
        and not request.positions
    for p in paths:
        # the reader holds only what fit reads (every cell still checked)
        r = read_record(p, columns_named(wanted, speeds=True) if only else None)
        if request.positions:  # the line through the positions: value or slope
            from compd.offline.position_record import line_record

            r = line_record(r, request.reference_position_mm, request.output)
        r.require(wanted)
        temps = sorted(c for c in channels if not is_rate_channel(c))
        check_units(r, temps if request.kind != "greybox" else [], request.output)
        # (--candidates keeps every column: it chooses among them, and the hedge's
        # textbook and other members may read inputs the choice left out; a --fixed
        # term reads its own channels)
        if channels and not request.fixed and not request.candidates:
            # and the speeds, of which speed_warnings speaks
            r = _only_columns(r, {*wanted, *(c for c in r.columns
                                             if channel_kind(c) is ChannelKind.SPEED)})
        records.append(r)
        ref = first if first is not None else records[0]
        if not math.isclose(r.period_s, ref.period_s, rel_tol=1e-6):
            raise RecordError(f"{r.path}: sampled every {r.period_s:g} s but {ref.path} "
                              f"every {ref.period_s:g} s; records fitted together "
                              "need one sample period")
    return records


def _only_columns(record: Record, names: set[str]) -> Record:
    """`record` with only the columns `names` (and its time), copied so that the rest
    of the block the reader parsed is freed: a month at 1 s is 21 MB a column."""
    import dataclasses

    if set(record.columns) <= names:  # nothing to drop (the reader kept only these)
        return record
    return dataclasses.replace(record, time_s=record.time_s.copy(),
                               columns={k: v.copy() for k, v in record.columns.items()
                                        if k in names})


def calibration_rows(run: FitRun, records: list[Record]) -> list[Record]:
    """--until: each record up to that time (the model is causal: nothing after it
    changes what it predicts before, so the rows after are cut, not masked);
    --from: ``run.fit_window``, the rows each loss may count (the rows before run
    through the model from the record's start). InputError (64) naming the flag."""
    import dataclasses

    import numpy as np

    from compd.infiles import InputError
    from compd.sysexits import EX_USAGE

    start, until = run.request.fit_from, run.request.fit_until
    run.fit_window = None
    if start is None and until is None:
        return records
    if until is not None and start is not None and until < start:
        raise InputError(f"--until {until:g} s is before --from {start:g} s", EX_USAGE)
    if start and (run.request.kind != "tf" or run.request.structure == "search"):
        raise InputError("--from goes with --kind tf, without --structure search (the "
                         "greedy order search masks no rows)", EX_USAGE)
    out: list[Record] = []
    for whole in records:
        r = whole
        if until is not None:
            n = int(np.searchsorted(whole.time_s, until + 1e-9, side="right"))
            r = dataclasses.replace(whole, time_s=whole.time_s[:n],
                                    columns={k: v[:n] for k, v in whole.columns.items()})
        first = int(np.searchsorted(r.time_s, (start or 0.0) - 1e-9))
        if len(r) - first < 2 * MIN_FOLD_ROWS:
            span = f"0 … {r.time_s[-1]:g} s" if len(r) else "nothing"
            window = f"--from {start or 0.0:g} s --until {math.inf if until is None else until:g} s"
            raise InputError(f"{window}: {r.path} has {max(0, len(r) - first)} rows there (it "
                             f"spans {span}); at least {2 * MIN_FOLD_ROWS} needed", EX_USAGE)
        out.append(r)
    if start:
        run.fit_window = np.concatenate([r.time_s >= start - 1e-9 for r in out])
    return out


#: arrays at least this large are mapped on their own and given back on free (a
#: month's columns at 1 s are 21 MB; the identification's blocks, a few MB, stay on
#: the heap and are reused: at 1 MB the month spent 99 s more in the kernel)
MMAP_THRESHOLD_BYTES = 8 << 20
#: ... for records longer than this (a day's arrays are 0.7 MB and its one block
#: 17 MB: mapped afresh each time, a day at 1 s spent 7 s more in the kernel)
LONG_RECORD_ROWS = 1 << 17


def return_freed_arrays() -> None:
    """glibc's malloc raises its mmap threshold each time a mapped block is freed
    (up to 32 MB): a month's 21 MB columns then come from the heap, and once freed
    stay in the process's resident memory beside what comes next (a month at 1 s
    peaked at 512-522 MB, 493 MB with this). A fixed threshold (mallopt
    M_MMAP_THRESHOLD) gives them back. Nothing where there is no glibc."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if not name:
        return
    try:
        ctypes.CDLL(name).mallopt(-3, MMAP_THRESHOLD_BYTES)  # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        return


#: a record up to LONG_RECORD_ROWS keeps its arrays (a day's 0.7 MB columns, its
#: 17 MB block) on the heap, and the heap keeps what is freed up to this much
#: rather than giving it back to be faulted in again: a day at 1 s made 240,000
#: page faults (0.7 s in the kernel) without, 29,000 (0.2 s) with, for 4 MB more
#: peak resident memory
KEEP_FREED_BYTES = 256 << 20


def keep_freed_arrays() -> None:
    """glibc's mmap threshold at its ceiling (32 MB) and its trim threshold at
    `KEEP_FREED_BYTES`, so that the identification's short-lived arrays are
    reused from the heap instead of mapped or trimmed and faulted in afresh
    each time. Nothing where there is no glibc."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if not name:
        return
    try:
        mallopt = ctypes.CDLL(name).mallopt
        mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD
        mallopt(-1, KEEP_FREED_BYTES)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        return
