"""The pure sample cycle: samples and the time in; the offset, the events and
the record row out. No asyncio, no clock, no logging, no I/O, so hours of
machine time are tested in milliseconds.

- `cycle`       one step: read-back check, validation, model, fault policy, output
- `validation`  per-channel input checks (missing, bad quality, range, rate, stuck)
- `faults`      the fault policy: what the output aims at when inputs go bad
- `output`      the output stage: clamp, deadband, slew limit, the status word
- `record`      the row a cycle leaves for the recorder
- `schedule`    absolute deadlines, skipped periods, the shutdown ramp's budget
"""
