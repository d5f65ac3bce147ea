"""What runs beside the daemon, not in it: calibration records, figures and the
demo's simulated machine.

- `records`  calibration records (CSV, or the recorder's database) read by fit and replay
- `plots`    figures like the papers' (matplotlib, files only)
- `demo`     the simulated machine on loopback and the real daemon against it
- `plan/`    the calibration experiment as a G-code program (`compd plan`) and the
             recorder settings that record its run
- `probes`   probes replayed from a record beside a model (`compd replay --probe-every-min`)
             and the adaptation settings a residual suggests (`compd fit --adaptation`)
"""
