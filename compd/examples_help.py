"""The examples section (argparse epilog) of each `compd` command's --help.

Kept apart from the command modules so that each stays about what it does;
`compd.cli` attaches one block per subcommand, and a test fails when a
command has none.
"""

from __future__ import annotations

EXAMPLES: dict[str, str] = {
    "run": """\
examples:
  compd run /etc/compd/compd.toml             the daemon (systemd Type=notify)
  compd run compd.toml --dry-run --once       read, step and log one cycle, write nothing""",
    "check": """\
examples:
  compd check sp2                             a bundled model: poles, DC gain, sensitivity
  compd check plant.toml --json               a model file as one JSON object
  compd check /etc/compd/compd.toml --connect a config, then read each channel once""",
    "demo": """\
examples:
  compd demo                                  8 h of the spectrum program over OPC UA, ~1 min
  compd demo --protocol modbus --plot demo.png
  compd demo --json --seconds 20              the figures as JSON, a faster run""",
    "sim": """\
examples:
  compd sim --protocol opcua                  serve a simulated machine on 127.0.0.1
  compd sim --protocol s7 --speedup 60 --write-config s7.toml   and a config for compd run
  compd sim --record etve.csv --program etve --period-s 60 --seed 1
  compd sim --record s.csv --machine shop --period-s 60 --change ambient+3K,heat+30% --change-at-h 6
  compd sim --drive modbus://plc:502 --map map.toml   the plant as a client (HIL)""",
    "fit": """\
examples:
  compd fit constant.csv etve.csv --column dz_um --term bearing --term ambient -o plant.toml
  compd fit day.csv --column dz_um --term bearing --kind greybox -o gb.toml""",
    "replay": """\
examples:
  compd replay plant.toml spectrum.csv --column dz_um --plot replay.png
  compd replay sp2 /var/lib/compd/samples.sqlite --column dz_um --json
  compd replay plant.toml spectrum.csv --column dz_um --probe-every-min 120 --probe-noise-um 0.5
  compd replay x_value.toml held.csv --slope-model x_slope.toml
      (a record measured at several positions: the error at each, before and after the line)""",
    "report": """\
examples:
  compd report plant.toml constant.csv etve.csv spectrum.csv -o report.html
  compd report plant.toml shop.csv --column dz_um --held-out-from 86400 -o report.html""",
    "refine": """\
examples:
  compd refine plant.toml /var/lib/compd/samples.sqlite -o plant-refined.toml
  compd refine plant.toml probes.csv -o out.toml --json   (time_s, measured_um, model_um)""",
    "step": """\
examples:
  compd step sp2                              final value of each term's unit step
  compd step plant.toml --plot step.png""",
    "health": """\
examples:
  compd health                                exit 0 when the daemon on this host is healthy
  compd health --url http://127.0.0.1:9108/metrics --timeout-s 2""",
    "status": """\
examples:
  compd status                                the daemon on this host (port 9105)
  compd status --url http://10.0.0.5:9108/ --json""",
    "rezero": """\
examples:
  compd rezero /etc/compd/compd.toml          at tool touch-off: the prediction now is zero
  sudo compd rezero --state-dir /var/lib/compd --wait-s 10""",
    "export": """\
examples:
  compd export /var/lib/compd/samples.sqlite -o day.csv --since 2026-11-23T06:00 \\
      --until 2026-11-23T18:00
  compd export samples.sqlite -o week.parquet --format parquet   (pip install 'compd[parquet]')""",
    "plan": """\
examples:
  compd plan --hours 24 --speeds 1250,2500,5000 --dialect linuxcnc -o warmup.ngc
      (spindle only: no axis moves; writes warmup.ngc and warmup.recorder.toml)
  compd plan --hours 24 --speeds 1250,2500,5000 --dialect linuxcnc -o warmup.ngc \\
      --probe-every-min 10 --safe-position Z=100 --probe-at X=250,Y=40,Z=20
  compd plan --hours 24 --speeds 2000,4000,8000 --rest-h 3 --dialect fanuc -o O1000.nc \\
      --probe-every-min 15 --safe-position Z=150 --probe-call 'G65 P9810 Z-10. F500.'
  compd plan --hours 24 --speeds 2000,4000,8000 --dialect sinumerik -o WARMUP.MPF \\
      --probe-every-min 15 --safe-position Z=150 --probe-call 'CYCLE978(0,1,,1,-10,100,,3,1)'
  compd plan --traverse X --positions 0,250,500,750,1000 --duties 25,50,90 --hours 24 \\
      --probe-every-min 30 --safe-position Z=100 --dialect linuxcnc -o x_traverse.ngc
      (the axis moving as the heat source, a measuring pass stopping at every position)""",
    "schema": """\
examples:
  compd schema > compd.schema.json            the config's JSON Schema, for editors
  (Even Better TOML / Taplo: put  #:schema ./compd.schema.json  on the config's first line)""",
}
