"""The recorder's JSON columns are formatted by hand (`compd.runtime.recorder_rows`,
a row a cycle for every machine): the text must be what `json.dumps` makes, for
any names and values, non-finite numbers as null."""

from __future__ import annotations

import json
import math

from hypothesis import given
from hypothesis import strategies as st

from compd.runtime.recorder_rows import _json_numbers, _json_reasons

NAMES = st.text(min_size=1, max_size=12)
NUMBERS = st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True),
                    st.integers(-10**6, 10**6))


def _reference_numbers(values: dict[str, float | None]) -> str:
    def num(v: float | None) -> float | None:
        return None if v is None or not math.isfinite(float(v)) else float(v)

    return json.dumps({k: num(v) for k, v in values.items()}, allow_nan=False,
                      separators=(",", ":"))


@given(st.dictionaries(NAMES, NUMBERS, max_size=8))
def test_numbers_are_what_json_dumps_makes(values: dict[str, float | None]) -> None:
    text = _json_numbers(values)
    assert text == _reference_numbers(values)
    assert json.loads(text) == {k: (None if v is None or not math.isfinite(v) else float(v))
                                for k, v in values.items()}


@given(st.dictionaries(NAMES, st.one_of(st.none(), st.text(max_size=20)), max_size=8))
def test_reasons_are_what_json_dumps_makes(validity: dict[str, str | None]) -> None:
    assert _json_reasons(validity) == json.dumps(
        {k: v for k, v in validity.items() if v is not None}, separators=(",", ":"))
