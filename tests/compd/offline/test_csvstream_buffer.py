"""The CSV reader's column buffer gives back the capacity its guess of the
row count left unused, in place: the columns read, no more memory."""

from __future__ import annotations

import numpy as np
import pytest

from compd.offline.csvstream import _Grower


@pytest.mark.parametrize(("ncols", "capacity", "rows"),
                         [(7, 100, 60), (3, 20, 19), (2, 16, 1), (4, 50, 50), (5, 1000, 100),
                          (3, 16, 40)])  # the last grows past its guess
def test_the_result_is_the_rows_read_with_no_capacity_left(ncols: int, capacity: int,
                                                           rows: int) -> None:
    values = np.random.default_rng(rows).standard_normal((rows, ncols))
    buf = _Grower(ncols, capacity)
    for row in values:
        buf.append(list(row))
    out = buf.result()
    assert out.shape == (ncols, rows) and np.array_equal(out, values.T)
    assert out.flags.c_contiguous and out.flags.owndata  # no view of a longer buffer
    assert out.nbytes == ncols * rows * 8
