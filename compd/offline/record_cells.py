"""The cells of a calibration record and the error that refuses one.

`RecordError` names the file, row and column of what is wrong; `parse_float`
and `parse_iso` read one cell each and refuse an empty, non-numeric or
non-finite number and a malformed timestamp (`compd.offline.records` explains
the rules). Shared by the record readers (`compd.offline.records`) and the
streaming CSV parse under them (`compd.offline.csvstream`).
"""

from __future__ import annotations

import math
from datetime import UTC, datetime

from compd.errors import CompdError


class RecordError(CompdError):
    """A calibration record cannot be used as it is. The message names the
    file, the row and/or the column, and what is wrong."""


def parse_iso(text: str, where: str) -> float:
    """An ISO 8601 timestamp as POSIX seconds; without a zone it is read as UTC."""
    t = text.strip()
    if t.endswith(("Z", "z")):
        t = t[:-1] + "+00:00"
    try:
        stamp = datetime.fromisoformat(t)
    except ValueError:
        raise RecordError(f"{where}: {text!r} is not an ISO 8601 timestamp") from None
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=UTC)
    return stamp.timestamp()


def parse_float(cell: str, where: str, line_no: int, column: str) -> float:
    """A cell's finite number; RecordError naming the row and column otherwise."""
    text = cell.strip()
    if not text:
        raise RecordError(f"{where}: row {line_no}, column {column!r}: empty cell "
                          "(a missing sample is not filled in; cut the record or repair it)")
    try:
        v = float(text)
    except ValueError:
        raise RecordError(f"{where}: row {line_no}, column {column!r}: {text!r} is not a "
                          "number") from None
    if not math.isfinite(v):
        raise RecordError(f"{where}: row {line_no}, column {column!r}: {text!r} is not finite "
                          "(NaN/inf rows are not skipped silently)")
    return v
