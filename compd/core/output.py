"""The output stage: the one place that decides what the machine gets.

Per cycle, from the target δZ in µm (the model, the held value, or 0 while
ramping down):

1. a non-finite target is ignored (the output holds);
2. clamp to ±limit_um;
3. deadband (tracking only): a target within deadband_um of the current
   output leaves it unchanged;
4. slew limit: the output moves at most slew_um_s·Δt toward the target
   (Δt capped at `max_dt_s`, so a stalled loop never earns a big step);
5. an integer offset address (``quantum_um`` > 0, e.g. a FOCAS long of
   0.1 µm) holds only multiples of its quantum: the slew-limited value is
   kept exactly (so a slew below one quantum per cycle still moves) and the
   output is the nearest grid point, back toward the previous output by
   whole quanta when it would step past the slew limit (the controller then
   holds exactly what the stage believes, and a step at the slew limit
   stays within it; a single quantum is the least step when R·Δt is below);
6. sign and unit conversion to controller units: value = sign·scale·µm.

`current_um` is what the controller is believed to hold. After a write the
controller refused, the shell calls `revert()` and the stage falls back to
the last value the controller confirmed, so that the next write never moves
faster than the slew limit from what the machine really has.

Read-back (`observe()`): what the controller holds, against what it last
confirmed:

- within the read-back tolerance: the stage steps from what it really holds;
- unknown before (start-up without a checkpoint): adopted, ramps from there;
- any other value within ±limit_um is *foreign* (a second writer, a
  restarted controller that forgot the offset and reads 0): the shell raises
  an alarm and the output ramps from the controller's value at the slew
  limit, never a step;
- beyond ±limit_um (by more than float32 rounding, `LIMIT_ROUNDING`) or not
  a number: the stage is `held`: no offset is written (one step of slew·Δt
  from there would still be beyond the limit, and a write inside it a step),
  until the controller's value is back within ±limit_um (an operator cleared
  it); then it ramps from there.

Status word (written each cycle, so a PLC can drop a stale compensation):
"""

from __future__ import annotations

import enum
import math


class Status(enum.IntFlag):
    """Status word bits (uint16; bit 15 unused so an INT address holds it)."""

    OK = 1 << 0               #: complete valid cycle, offset tracks the model
    HOLDING = 1 << 1          #: invalid input: last offset held
    RAMPING = 1 << 2          #: invalid longer than hold_s: ramping to zero
    ALARM = 1 << 3            #: an alarm: ramping on a fault, or writing stopped
    READBACK_MISMATCH = 1 << 4  #: the controller's offset differed from our last write
    WRITE_STOPPED = 1 << 5    #: the controller refused the offset permanently
    MODEL_INVALID = 1 << 6    #: the model produced a non-finite value (re-initialised)
    SLEWING = 1 << 7          #: the output is slew-limited, catching up with its target
    SHUTDOWN = 1 << 8         #: the daemon is shutting down (ramp to zero)
    OFFSET_HELD = 1 << 9      #: the controller holds an offset beyond ±limit: none written
    WRITE_FAULT = 1 << 10     #: offset writes keep failing (transient, repeated)
    MODEL_RANGE = 1 << 11     #: the model's output is far beyond ±limit: held/ramped
    OPERATOR_HOLD = 1 << 12   #: an operator switched compensation to hold (OPC UA SetHold)


__doc__ = (__doc__ or "") + "\n".join(
    f"    bit {int(b).bit_length() - 1:2d}  {b.name}" for b in Status) + "\n"


class Readback(enum.Enum):
    """What a read-back of the offset told (`OutputStage.observe`)."""

    MATCH = "match"              #: what the controller last confirmed (within tolerance)
    ADOPTED = "adopted"          #: nothing confirmed yet (start-up): ramp from it
    FOREIGN = "foreign"          #: a value compd did not write, within ±limit: ramp from it
    OUT_OF_RANGE = "out_of_range"  #: beyond ±limit or not a number: offset writes held


#: a read-back this far beyond ±limit_um (relative) is still "at the limit":
#: the float32 rounding of a limit written to the controller (2^-23 ≈ 1.2e-7)
LIMIT_ROUNDING = 1e-6


def _clamp(x: float, limit: float) -> float:
    return max(-limit, min(limit, x))


class OutputStage:
    """Clamp, deadband, slew limit, sign and scale (see module docstring)."""

    def __init__(self, *, limit_um: float, slew_um_s: float, deadband_um: float = 0.0,
                 sign: int = 1, units_per_um: float = 1.0, max_dt_s: float = math.inf,
                 initial_um: float = 0.0, quantum_um: float = 0.0) -> None:
        if not (math.isfinite(limit_um) and limit_um > 0.0):
            raise ValueError("limit_um must be > 0")
        if not (math.isfinite(slew_um_s) and slew_um_s > 0.0):
            raise ValueError("slew_um_s must be > 0")
        if sign not in (1, -1) or not (math.isfinite(units_per_um) and units_per_um != 0.0):
            raise ValueError("sign must be ±1 and units_per_um finite non-zero")
        self.limit_um = limit_um
        self.slew_um_s = slew_um_s
        self.deadband_um = deadband_um
        self.sign = sign
        self.units_per_um = units_per_um
        self.max_dt_s = max_dt_s
        self.quantum_um = quantum_um if math.isfinite(quantum_um) and quantum_um > 0.0 else 0.0
        self.current_um = self._safe(initial_um)
        #: the slew-limited value before the grid (quantised outputs only)
        self._exact_um = self.current_um
        #: the last value the controller confirmed (a successful write or a read-back)
        self.confirmed_um: float | None = None
        self.slewing = False
        #: the controller holds an offset beyond ±limit (or not a number): no write
        self.held = False

    def _safe(self, x: float) -> float:
        return _clamp(x, self.limit_um) if math.isfinite(x) else 0.0

    def step(self, target_um: float, dt_s: float, *, deadband: bool = True) -> float:
        """Move toward `target_um`; returns the new output in µm (always finite,
        within ±limit, within slew·Δt of the previous output). Held: unchanged."""
        if self.held:
            self.slewing = False
            return self.current_um
        if not math.isfinite(target_um):
            target_um = self.current_um
        target = _clamp(target_um, self.limit_um)
        if deadband and abs(target - self.current_um) <= self.deadband_um:
            target = self.current_um
        dt = min(max(dt_s, 0.0), self.max_dt_s) if math.isfinite(dt_s) else 0.0
        max_step = self.slew_um_s * dt
        base = self._exact_um if self.quantum_um else self.current_um
        delta = target - base
        self.slewing = abs(delta) > max_step
        delta = max(-max_step, min(max_step, delta))
        new = _clamp(base + delta, self.limit_um)
        self._exact_um = new
        if self.quantum_um:
            new = self._on_grid(new, self.current_um, max_step)
        self.current_um = new
        return self.current_um

    def _on_grid(self, x: float, prev: float, max_step: float) -> float:
        """`x` as a multiple of the quantum, within the limit and (when one
        quantum allows it) within `max_step` of `prev`."""
        q = self.quantum_um
        g = round(x / q) * q
        if abs(g) > self.limit_um:
            g -= math.copysign(q, g)
        d = g - prev
        if abs(d) > max_step and abs(d) > q:
            # back toward prev by whole quanta, to within max(max_step, q) of it
            m = math.ceil((abs(d) - max(max_step, q)) / q - 1e-9)
            g -= math.copysign(m * q, d)
        return g

    def to_controller(self, um: float) -> float:
        return self.sign * self.units_per_um * um

    def from_controller(self, value: float) -> float:
        return value / (self.sign * self.units_per_um)

    def confirm(self) -> None:
        """The controller accepted the last output."""
        self.confirmed_um = self.current_um

    def revert(self) -> None:
        """The write failed: the controller still holds the last confirmed value."""
        if self.confirmed_um is not None:
            self.current_um = self.confirmed_um
            self._exact_um = self.current_um

    def align(self, um: float) -> None:
        """The controller holds `um`, a hair from what we wrote (its encoding,
        within the read-back tolerance): step from what it really holds,
        keeping any sub-quantum progress of the exact value."""
        um = self._safe(um)
        self._exact_um += um - self.current_um
        self.current_um = um
        self.confirmed_um = um

    def observe(self, um: float, tolerance_um: float) -> Readback:
        """The controller holds `um` (read back, µm): see the module docstring."""
        if not math.isfinite(um) or abs(um) > self.limit_um * (1.0 + LIMIT_ROUNDING):
            self.held = True
            return Readback.OUT_OF_RANGE
        self.held = False
        confirmed = self.confirmed_um
        if confirmed is not None and abs(um - confirmed) <= tolerance_um:
            if um != confirmed:
                # not a mismatch, but the next step is measured from what the
                # machine has, so the slew limit holds against it
                self.align(um)
            return Readback.MATCH
        self.adopt(um)
        return Readback.ADOPTED if confirmed is None else Readback.FOREIGN

    def adopt(self, um: float) -> None:
        """The controller holds `um` (read back): ramp from there."""
        self.current_um = self._safe(um)
        self._exact_um = self.current_um
        self.confirmed_um = self.current_um
