"""The pure sample cycle: samples and the time in; the offset, the events and
the record row out. No asyncio, no clock, no logging, no I/O, so hours of
machine time are tested in milliseconds.

- `cycle`       one cycle as plan (read-back, validation, model, health, output)
                and commit (the write's outcome, the final row)
- `params`      what a cycle is built with, and how the config gives it
- `plan`        what a cycle hands the shell: Plan, Outcome, Row, Snapshot
- `health`      the output's one state machine (fault policy, write fault,
                stopped, held...) and the status word as a pure function of it
- `modelstep`   the live and shadow models as the cycle steps them
- `validation`  per-channel input checks (missing, bad quality, range, rate, stuck)
- `faults`      the output's states
- `events`      what a cycle reports: one `EventName` per kind, with its log level
- `output`      the output stage: clamp, deadband, slew limit, the status bits
- `record`      the row a cycle leaves for the recorder
- `schedule`    absolute deadlines, skipped periods, the shutdown ramp's budget
"""
