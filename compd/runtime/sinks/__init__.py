"""What the loop feeds after each cycle: one `CycleSink` per concern, each in
its own module, none of which may stop the cycle (the offset is written
already: `compd.runtime.journal.Journal.guard`).

- `base`        the `CycleSink` protocol and the `Tick` each is fed
- `recorder`    the SQLite recorder (`compd.runtime.recorder`)
- `telemetry`   Prometheus metrics, sd_notify READY/WATCHDOG/STATUS, complete cycles
- `status`      the operator status page's snapshot (`compd.faces.status`)
- `opcua`       compd's own OPC UA server face (`compd.faces.opcua_face`)
- `checkpoint`  the model state, atomically, every N cycles and on an alarm change
"""

from compd.runtime.sinks.base import CycleSink, Tick

__all__ = ["CycleSink", "Tick"]
