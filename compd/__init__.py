"""compd: the daemon that composes `models` and `drivers`. One folder per room:

- `compd.core`      the pure sample cycle: validation, fault policy, output stage,
                    the schedule's arithmetic (no asyncio, clock, logging or I/O)
- `compd.runtime`   the asyncio shell: the loop, controller I/O, checkpoints,
                    the recorder, the state lock, sd_notify
- `compd.faces`     what people and tools see: logs and metrics
- `compd.config`    the config file: schema and loader
- `compd.offline`   beside the daemon: calibration records, figures, the demo
- `compd.commands`  one module per subcommand (`compd.cli` dispatches)
- `compd.testing`   test doubles for code built on compd
"""

#: the one version (pyproject reads it: `dynamic = ["version"]`); a release tag is v + this
__version__ = "0.1.0"
