"""The operator status page's data: a snapshot per cycle, the recorder's recent history.

`StatusBoard.publish` runs in the loop once per cycle and builds a small dict
from the cycle's result (the state in words and why, the offset and its
limit, each channel's value and validity); it replaces the last snapshot in
one assignment, so the HTTP threads (`compd.faces.status_http`) only ever
read a complete one and never make the loop wait. The last alarms (warning
and error events) are kept in a bounded deque. `read_history` reads the
recorder through its one reader (`compd.store.reader`, read-only; WAL: it
never blocks the recorder's writes) with a bound on the rows: the last
`hours` of offset and model output, thinned to at most `MAX_HISTORY_POINTS`
rows picked by stride on the recorder's contiguous ``seq`` (a bounded number
of primary-key look-ups, however long the window). Nothing here raises into
the cycle: a snapshot that cannot be built is logged once and the page keeps
the last one.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import structlog

from compd.config.loader import LoadedConfig
from compd.core.adaptation import DISAGREE_AFTER
from compd.core.faults import FaultState
from compd.core.health import Cause
from compd.core.plan import AdaptationView, Row
from compd.infiles import InputError
from compd.store.reader import RecorderReader
from compd.store.schema import RecorderError

__all__ = ["MAX_ALARMS", "MAX_HISTORY_POINTS", "StatusBoard", "operator_state",
           "read_history"]

#: the plot never reads more rows than this from the recorder, however long the window
MAX_HISTORY_POINTS = 1200
#: how many alarms the page lists
MAX_ALARMS = 20
#: how long a reader waits for a recorder another process has locked
LOCK_WAIT_S = 0.5

_WORDS: dict[FaultState, str] = {
    FaultState.OK: "on", FaultState.INIT: "holding", FaultState.HOLD: "holding",
    FaultState.RAMP: "ramping", FaultState.SHUTDOWN: "ramping",
    FaultState.STOPPED: "off", FaultState.HELD: "off", FaultState.WRITE_FAULT: "off"}

#: the word of a cause whatever the state (the others take the state's word)
_CAUSE_WORDS: dict[Cause, str] = {
    Cause.OPERATOR_HOLD: "holding", Cause.CONTROLLER_OFF: "holding", Cause.DEGRADED: "degraded",
    Cause.WRITE_FAILED: "holding", Cause.NO_READBACK: "holding",
    Cause.FOREIGN_OFFSET: "ramping", Cause.AT_LIMIT: "limited",
    Cause.WAITING_FOR_PERMISSION: "waiting", Cause.PERMIT_UNREADABLE: "holding",
    Cause.RECORDER_ONLY: "recording"}

_WHY: dict[Cause, str] = {
    Cause.IN_FORCE: "inputs valid, the model's offset is applied",
    Cause.OPERATOR_HOLD: "held by an operator (OPC UA SetHold): the offset stays put",
    Cause.SHUTTING_DOWN: "shutting down: the offset ramps to 0",
    Cause.WRITE_STOPPED: "the controller refused the offset: writes stopped (alarm)",
    Cause.FOREIGN_OFFSET_HELD: "the controller holds an offset beyond the limit that compd "
                               "did not write: nothing written (alarm)",
    Cause.CONTROLLER_OFF: "the machine is off or in E-stop: it takes no offset, compd holds "
                          "and writes none; it ramps from what the controller holds once "
                          "the machine is on",
    Cause.WRITE_FAULT: "offset writes keep failing (alarm)",
    Cause.WRITE_FAILED: "the offset write failed: the controller keeps the offset it last "
                        "confirmed; compd writes again next cycle",
    Cause.NO_READBACK: "the controller's offset could not be read back: nothing is written "
                       "until it can be",
    Cause.FOREIGN_OFFSET: "another writer changed the offset: compd ramps back from its "
                          "value to the model's at the slew limit (alarm)",
    Cause.AT_LIMIT: "the model asks for more than the limit: the offset is held at the limit",
    Cause.WAITING_FOR_PERMISSION: "waiting for permission ([output] update_permitted is 0): "
                                  "the offset in force is held while the model runs; the "
                                  "change ramps in at the slew limit once it permits",
    Cause.PERMIT_UNREADABLE: "[output] update_permitted cannot be read: taken as not "
                             "permitted, the offset in force is held",
    Cause.RECORDER_ONLY: "recorder only: inputs valid and recorded; nothing is written to "
                         "the controller (no offset, heartbeat or status)",
    Cause.DEGRADED: "a sensor is invalid: the fallback model on the remaining sensors is in "
                    "force (compensating, less well; replace the sensor)",
    # the faults: the policy's part ("the offset is held" ...) is added by `_fault_why`
    Cause.MODEL_WORSE_THAN_NONE: "recalibrate: the probes showed the compensation worse "
                                 "than none",
    Cause.CONTROLLER_NOT_ANSWERING: "the controller does not answer",
    Cause.INPUTS_INVALID: "inputs invalid",
    Cause.MODEL_NON_FINITE: "the model's output is not a number",
    Cause.MODEL_OUT_OF_RANGE: "the model's output is far beyond the limit (alarm)"}

#: what the fault policy does, by its state, after the cause of a fault
_POLICY: dict[FaultState, str] = {
    FaultState.INIT: "no valid sample yet since start: the offset is held",
    FaultState.HOLD: "the offset is held",
    FaultState.RAMP: "longer than hold_s: the offset ramps to 0 (alarm)"}


def _guard(adaptation: AdaptationView | None) -> str:
    """What the guard decided on: its accepted probes, and the refused ones left out."""
    if adaptation is None:
        return ""
    return (f" ({adaptation.guard_worse} accepted probes in a row; "
            f"{adaptation.probes_refused} refused probes since start not counted)")


def operator_state(state: FaultState, cause: Cause, validity: Mapping[str, str | None],
                   dry_run: bool = False, adaptation: AdaptationView | None = None,
                   ) -> tuple[str, str]:
    """(on | dry-run | holding | ramping | limited | off, why) for the fault state,
    the cycle's cause (`compd.core.health.Cause`: why the offset compd wants is
    not in force, or that it is) and the channels' validity; `adaptation` says
    what the guard decided on. A dry run that would compensate is "dry-run",
    not "on": nothing it computes reaches the machine."""
    word = _CAUSE_WORDS.get(cause, _WORDS[state])
    why = _WHY[cause]
    if cause is Cause.MODEL_WORSE_THAN_NONE:
        why += _guard(adaptation)
    if state in _POLICY and cause not in (Cause.CONTROLLER_OFF, Cause.SHUTTING_DOWN):
        why = f"{why}: {_POLICY[state]}"
    if cause is Cause.CONTROLLER_NOT_ANSWERING:
        # nothing can be written either: no ramp reaches the machine
        why = ("the controller does not answer: nothing can be read or written; the "
               "controller keeps the offset it last got"
               + (" (alarm: longer than hold_s)" if state is FaultState.RAMP else "")
               + "; compd resumes when it answers")
    bad = [f"{name}: {reason}" for name, reason in validity.items() if reason is not None]
    if bad and cause is Cause.INPUTS_INVALID:
        why += " (" + "; ".join(bad) + ")"
    if adaptation is not None and adaptation.model_worse \
            and cause is not Cause.MODEL_WORSE_THAN_NONE:
        why += ("; the probes showed the compensation worse than none (guard_action = "
                "\"report\": not acted on): recalibrate")
    if adaptation is not None and adaptation.gate_refusals >= DISAGREE_AFTER:
        why += (f"; the last {adaptation.gate_refusals} probes were all refused as outliers: "
                "the model or the probe source is wrong (check both)")
    if dry_run and word == "on":
        word, why = "dry-run", ("dry run: inputs valid, the model runs, nothing is written "
                                "to the controller (the offset shown is what would be written)")
    elif dry_run:
        why += "; dry run: nothing is written"
    return word, why


def _detail(value: Any) -> str:
    """An alarm's field as the page lists it: a float rounded to what a reader
    uses (``60.997285639999745`` → ``61``, ``0.012345678`` → ``0.01235``)."""
    if isinstance(value, float) and math.isfinite(value):
        return format(value, ".4g")
    return str(value)[:200]


def _num(x: float | None) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


class StatusBoard:
    """The last snapshot and alarms, written by the loop, read by the HTTP threads."""

    def __init__(self, *, history_h: float = 4.0, refresh_s: float = 5.0) -> None:
        self.history_h = history_h
        self.refresh_s = refresh_s
        self.snapshot: dict[str, Any] = {"state": "starting", "why": "no cycle yet",
                                         "channels": [], "alarms": []}
        self.recorder_path: Path | None = None
        self._alarms: collections.deque[dict[str, Any]] = collections.deque(maxlen=MAX_ALARMS)
        self._failed = False
        self._history: tuple[float, dict[str, Any]] | None = None
        self._dry_run = False
        self._history_lock = threading.Lock()

    def alarm(self, name: str, level: str, fields: Mapping[str, Any], *,
              wall_s: float) -> None:
        """A warning or error event of the cycle at `wall_s` (the caller's time: the
        daemon's clock, as the snapshot's is the report's), for the page's list."""
        self._alarms.append({"wall_s": wall_s, "event": name, "level": level,
                             "detail": {k: _detail(v) for k, v in fields.items()}})

    def publish(self, result: Row, cfg: LoadedConfig, *, dry_run: bool = False) -> None:
        """Build the snapshot from a committed `Row` and the running `LoadedConfig`.
        Never raises: a failure is logged once and the page keeps the last snapshot."""
        try:
            self.snapshot = self._build(result, cfg, dry_run)
            self._failed = False
        except Exception as exc:
            if not self._failed:
                structlog.get_logger("compd").error("status_snapshot_failed", error=str(exc))
            self._failed = True

    def _build(self, result: Row, cfg: LoadedConfig, dry_run: bool) -> dict[str, Any]:
        rec = result.record
        est = result.snapshot.adaptation
        word, why = operator_state(result.state, result.cause, rec.validity, dry_run, est)
        snap = result.snapshot
        if snap.pending_um is not None:
            why += f" ({snap.pending_um:+.3f} um pending)"
        raw = cfg.raw
        limit_um = float(raw.output.limit_um)
        if abs(result.stage_um) > limit_um:  # the only way beyond it: `OutputStage._start`
            why += ("; the offset compd wrote is beyond limit_um (lowered since it was "
                    "written): it ramps into the limit at the slew limit")
        self._dry_run = dry_run
        self.recorder_path = None if dry_run else cfg.recorder_path
        channels = [{"name": name, "value": _num(rec.channels.get(name)),
                     "unit": ch.unit, "valid": rec.validity.get(name) is None,
                     "reason": rec.validity.get(name)}
                    for name, ch in raw.channels.items()]
        if result.axes:
            why += "; axes in force: " + (", ".join(
                a for a, line in result.axes.items() if line.in_force) or "none")
        doc = {"machine": raw.machine.name, "state": word, "fault_state": str(result.state),
                "cause": str(result.cause), "healthy": result.healthy,
                # the output stage's value (sent this cycle, confirmed or not) and what
                # the controller confirmed holding (None: unknown); the history's
                # offset_um is the recorder's, the confirmed one
                "why": why, "offset_um": _num(result.stage_um),
                "confirmed_um": _num(result.confirmed_um),
                "limit_um": limit_um, "model_um": _num(rec.model_um),
                "sequence": result.sequence, "complete": result.in_force,
                "inputs_valid": result.inputs_valid,
                "status_word": result.status, "heartbeat": result.heartbeat,
                "model": cfg.model.name, "model_sha256": cfg.model_sha256,
                "fallback_for": result.snapshot.fallback_for,
                "fallbacks": sorted(cfg.model.fallbacks),
                "dry_run": dry_run, "wall_s": _num(result.wall_s),
                "period_s": float(cfg.real_period_s),
                "recorder_only": cfg.recorder_only,
                # waiting for permission: the change held back (µm), else None
                "pending_um": _num(snap.pending_um),
                # how the model started and the reference state in force (and whence)
                "model_start": snap.model_start or None,
                "reference": ({"source": snap.reference,
                               "temperatures_c": {k: _num(v) for k, v in
                                                  sorted(snap.references.items())}}
                              if snap.references else None),
                "zero_um": _num(snap.zero_um),
                "channels": channels,
                "alarms": list(self._alarms)}
        if est is not None:
            doc["probes"] = {"accepted": est.probes_accepted, "refused": est.probes_refused,
                             "guard_probes": est.guard_probes, "guard_worse": est.guard_worse,
                             "model_worse": est.model_worse,
                             "gate_refusals": est.gate_refusals}
        if result.axes:  # [output.axes]: each axis's line, state and whether it is in force
            doc["axes"] = {axis: {
                "in_force": line.in_force, "state": str(line.state), "cause": str(line.cause),
                "status_word": line.status, "inputs_valid": line.inputs_valid,
                "reference_mm": line.reference_mm,
                "value_um": _num(line.value.stage),
                "value_confirmed_um": _num(line.value.confirmed),
                "value_model_um": _num(line.value.model),
                "slope_um_m": _num(line.slope.stage),
                "slope_confirmed_um_m": _num(line.slope.confirmed),
                "slope_model_um_m": _num(line.slope.model),
                # an axis written as one offset at its position: where, and what
                **({"position_mm": _num(line.position_mm), "offset_um": _num(line.offset_um)}
                   if line.position_mm is not None else {})}
                for axis, line in result.axes.items()}
        return doc

    def history(self) -> dict[str, Any]:
        """The plot's data, read at most once per refresh period (many viewers, one read)."""
        if self._dry_run:  # a dry run records nothing: no plot, and says why
            return {"hours": self.history_h, "wall_s": [], "offset_um": [], "model_um": [],
                    "error": "dry run: nothing is recorded, so nothing is plotted"}
        now = time.monotonic()
        with self._history_lock:
            cached = self._history
            if cached is not None and now - cached[0] < self.refresh_s:
                return cached[1]
            data = read_history(self.recorder_path, self.history_h)
            self._history = (now, data)
            return data


def read_history(path: Path | None, hours: float, *, max_points: int = MAX_HISTORY_POINTS,
                 now_wall_s: float | None = None) -> dict[str, Any]:
    """The last `hours` of (wall_s, offset_um, model_um) from the recorder at `path`,
    at most `max_points` rows evenly spaced by ``seq``, the newest always included,
    oldest first; ``error`` says why when there are none."""
    out: dict[str, Any] = {"hours": hours, "wall_s": [], "offset_um": [], "model_um": []}
    if path is None:
        out["error"] = "no recorder configured"
        return out
    if not path.is_file():
        out["error"] = "no recorder file yet"
        return out
    cutoff = (time.time() if now_wall_s is None else now_wall_s) - hours * 3600.0
    try:
        with RecorderReader(path, timeout_s=LOCK_WAIT_S) as reader:
            rows = reader.history(cutoff, max(1, max_points))
    except RecorderError as exc:
        out["error"] = f"recorder unreadable: {exc.reason}"
        return out
    except InputError as exc:
        out["error"] = f"recorder unreadable: {exc}"
        return out
    if not rows:
        out["error"] = "no samples recorded in the window"
    for wall_s, offset_um, model_um in rows:
        out["wall_s"].append(wall_s)
        out["offset_um"].append(_num(offset_um))
        out["model_um"].append(_num(model_um))
    return out
