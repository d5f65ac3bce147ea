"""The asyncio shell around the pure core: deadlines, controller I/O, state on
disk and the service manager.

- `daemon`        the sample loop: read, `Cycle.plan`, write, `Cycle.commit`, record, checkpoint
- `startup`       how the cycle starts: from a fresh checkpoint, an old one, or nothing
- `checkpoint`    atomic checkpoints of the cycle's state
- `recorder`      every cycle's row in one SQLite database (WAL)
- `statelock`     one daemon per state directory (flock)
- `sdnotify`      systemd's notify protocol and watchdog
- `heap`          glibc's mmap threshold, pinned for a process that runs for months
- `driver_setup`  the configured driver, built
- `certcheck`     certificate expiry at start
"""
