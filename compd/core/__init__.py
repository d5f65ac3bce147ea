"""The pure sample cycle: samples and the time in; the offset, the events and
the record row out. No asyncio, no clock, no logging, no I/O, so hours of
machine time are tested in milliseconds.

- `cycle`       one cycle as plan (read-back, validation, model, health, output)
                and commit (the write's outcome, the cycle's report)
- `readback`    step 1: the controller's offset as read back, judged
- `stepping`    steps 2 and 3: the inputs validated, the models stepped
- `permit`      the controller's permission to change the offset, the re-zero edge
- `restore`     what a cycle keeps of a checkpoint's or a reload's state
- `snapshot`    what the faces read beyond the output, the recorded contributions
- `params`      what a cycle is built with, and how the config gives it
- `plan`        what a cycle hands the shell: Plan, Outcome, and Row, the
                cycle's report (one meaning per name), with its Snapshot
- `health`      the output's one state machine (fault policy, write fault,
                stopped, held...), each transition one of its methods
- `health_view` a cycle's health as told: the status word, the state, the cause
- `modelstep`   the live and shadow models as the cycle steps them
- `validation`  per-channel input checks (missing, bad quality, range, rate, stuck)
- `faults`      the output's states
- `events`      what a cycle reports: one `EventName` per kind, with its log level
- `output`      the output stage: clamp, deadband, slew limit, the status bits
- `record`      the row a cycle leaves for the recorder
- `schedule`    absolute deadlines, skipped periods, the shutdown ramp's budget
- `axes`        one per-axis output ([output.axes.<axis>]): its models, stages,
                read-back and health
- `axis_bank`   every axis of a cycle together, and the axes word
- `axis_params` what an axis is built with, and its part of the report
"""
