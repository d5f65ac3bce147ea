"""`compd plan`: the calibration experiment as a G-code program.

- `schedule`     the experiment: speeds, steps, rests and measuring times (no G-code)
- `dialects`     each controller's words: LinuxCNC, FANUC, SINUMERIK
- `program`      the program: header, safe start, the schedule's blocks, end
- `recorder`     the recorder config that records the run for `compd fit`
"""
