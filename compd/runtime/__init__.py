"""The asyncio shell around the pure core: deadlines, controller I/O, state on
disk and the service manager.

- `daemon`        one machine: the loop and its sinks composed; lock, start-up, signals
- `loop`          one cycle per deadline, the tick to the sinks, the shutdown policy
- `cycle_io`      one cycle's I/O (`Cycle.plan`, write, `Cycle.commit`), and every
                  call the shell makes into the cycle
- `sinks`         what each cycle feeds: recorder, telemetry, status page, OPC UA face,
                  checkpoint (one module each, one `CycleSink` protocol)
- `journal`       events to the log at their level and to the page's alarms, rate-limited
- `clock`         the one injected clock (monotonic, wall, sleep)
- `reloading`     SIGHUP: prepared beside the loop, swapped in between two cycles
- `reload`        what a reload may change, and the cycle that carries over
- `fleet`         several machines in one process (`compd run DIR`)
- `startup`       how the cycle starts: from a fresh checkpoint, an old one, or nothing
- `checkpoint`    atomic checkpoints of the cycle's state
- `recorder`      every cycle's row in one SQLite database (WAL)
- `statelock`     one daemon per state directory (flock)
- `sdnotify`      systemd's notify protocol and watchdog
- `heap`          glibc's mmap threshold, pinned for a process that runs for months
- `driver_setup`  the configured driver, built and connected
- `certcheck`     certificate expiry at start and after a reload
"""
