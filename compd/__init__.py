"""compd: the daemon that composes `models` and `drivers`: configuration, the
sample loop, the output stage and fault policy, checkpoints, the recorder,
telemetry and the command line."""

__version__ = "0.1.0"
