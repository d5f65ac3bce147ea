"""A bounded record of a simulated run: fixed columns, float rows."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np


class History:
    """Rows of floats under fixed column names, the oldest dropped past `max_rows`."""

    def __init__(self, columns: Sequence[str], max_rows: int | None = None) -> None:
        self.columns = tuple(columns)
        self._rows: deque[tuple[float, ...]] = deque(maxlen=max_rows)

    def append(self, row: Sequence[float]) -> None:
        self._rows.append(tuple(row))

    def __len__(self) -> int:
        return len(self._rows)

    def rows(self) -> list[dict[str, float]]:
        return [dict(zip(self.columns, row, strict=True)) for row in self._rows]

    def arrays(self) -> dict[str, np.ndarray]:
        """float64 columns keyed by name (copies)."""
        data = np.array(self._rows, dtype=np.float64).reshape(-1, len(self.columns))
        return {name: data[:, i].copy() for i, name in enumerate(self.columns)}
