"""A failure repeated every cycle is logged once, then as a summary a minute,
and its end as one `_recovered` line (an hour's outage wrote 3,600 lines)."""

from __future__ import annotations

from compd.runtime.repeats import RepeatLimiter


def test_an_hour_of_failures_at_1_hz_is_a_few_dozen_lines() -> None:
    lim = RepeatLimiter("write_failed", summary_every_s=60.0)
    lines = []
    for t in range(3600):
        line = lim.failed(float(t), {"reason": f"timeout {t}"})
        if line is not None:
            lines.append(line)
    assert lines[0] == ("write_failed", {"reason": "timeout 0"})
    summaries = [f for name, f in lines if name == "write_failed_summary"]
    assert len(lines) == 1 + len(summaries) and 55 <= len(summaries) <= 60
    assert summaries[-1]["failures"] == 3541 and summaries[-1]["reason"] == "timeout 3540"
    assert sum(f["held_back"] for f in summaries) == 3540
    rec = lim.succeeded(3600.0)
    assert rec == ("write_failed_recovered",
                   {"failures": 3600, "for_s": 3600.0, "last_error": "timeout 3599"})
    assert lim.succeeded(3601.0) is None  # nothing to recover from
    assert lim.failed(3602.0, {"reason": "again"}) == ("write_failed", {"reason": "again"})
