"""`compd plan`: the calibration experiment as a G-code program.

- `schedule`     the experiment: speeds, steps, rests and measuring times (no G-code)
- `dialects`     each controller's words: LinuxCNC, FANUC, SINUMERIK
- `program`      the program: header, modal state, the schedule's blocks, end
- `calls`        the user's measuring cycle (`--probe-call`) parsed into a value
- `comments`     the text of a comment, plain for every dialect
- `recorder`     the recorder config that records the run for `compd fit`
"""
