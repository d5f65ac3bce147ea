"""The output stage: the one place that decides what the machine gets.

Per cycle, from the target δZ in µm (the model, the held value, or 0 while
ramping down):

1. a non-finite target is ignored (the output holds);
2. clamp to ±limit_um;
3. deadband (tracking only): a target within deadband_um of the current
   output leaves it unchanged;
4. slew limit: the output moves at most slew_um_s·Δt toward the target
   (Δt capped at `max_dt_s`, so a stalled loop never earns a big step);
5. an integer offset address (``quantum_um`` > 0: one count of the
   controller, e.g. an int16 at scale 10 holds 10 µm per count, a FOCAS long
   at scale 0.1 holds 0.1 µm) holds only whole counts, and the stage writes
   only whole counts. The slew-limited value of step 4 is
   kept exactly (the *wanted* value; its sub-count progress is kept, so a
   slew below one count per cycle still moves), and the count in force
   changes only when the wanted value is at least one count away from it
   (hysteresis of one count): it then moves toward the wanted value by
   whole counts, never past it, by at most ⌊R·Δt / count⌋ counts, and by
   one count when one count is more than R·Δt (never more per cycle). So
   a wanted value wobbling within a count (model noise across a rounding
   threshold) never flips the register, the offset reverses only after the
   wanted value has come back by a whole count, it stays within one count
   of the wanted value, on average no faster than R, and within ±limit_um;
6. sign and unit conversion to controller units: value = sign·scale·µm.

A lowered limit (a reload, or a restart with a lower ``limit_um``) finds the
offset compd last wrote beyond the new ±limit_um: the stage starts from that
value (`initial_um` is kept, not clamped) and ramps it into the limit at the
slew limit, the deadband aside, never further out (`beyond_limit` while it
does); its read-back is compd's own, not a foreign value beyond the limit.

`current_um` is what the controller is believed to hold. After a write the
controller refused, the shell calls `revert()` and the stage falls back to
the last value the controller confirmed, so that the next write never moves
faster than the slew limit from what the machine really has.

Read-back (`observe()`): what the controller holds, against what it last
confirmed:

- within the read-back tolerance (an integer offset address: half a count
  of the count it last confirmed, so the encoding is never taken for a
  foreign write, and a foreign count is): the stage steps from what it
  really holds;
- unknown before (start-up without a checkpoint): adopted, ramps from there;
- any other value within ±limit_um is *foreign* (a second writer, a
  restarted controller that forgot the offset and reads 0): the shell raises
  an alarm and the output ramps from the controller's value at the slew
  limit, never a step;
- beyond ±limit_um (by more than float32 rounding, `LIMIT_ROUNDING`) and not
  what compd last wrote (a lowered limit, above), or not a number: the stage
  is `held`: no offset is written (one step of slew·Δt
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
    MODEL_WORSE = 1 << 13     #: probes show the compensation worse than none: held/ramped
    CONTROLLER_OFF = 1 << 14  #: the controller takes no offset (machine off, E-stop): held


class AxesStatus(enum.IntFlag):
    """The axes word (uint16, ``[output] axes_status``; bit 15 unused so an INT
    holds it): one nibble per kind, one bit per axis in it (X, Y, Z), so a PLC
    reads axis i of a kind as bit 4·kind + i. LIFE toggles in every word compd
    writes (the cycle ran), whatever the inputs; an axis's IN_FORCE bit says its
    line the controller confirmed last cycle is the line its models want and is
    written again beside this word (`compd.core.axis_bank.AxisBank.status_word`)."""

    X_IN_FORCE = 1 << 0
    Y_IN_FORCE = 1 << 1
    Z_IN_FORCE = 1 << 2
    LIFE = 1 << 3             #: toggles every cycle compd writes this word
    X_ALARM = 1 << 4          #: the axis's own status word has ALARM
    Y_ALARM = 1 << 5
    Z_ALARM = 1 << 6
    X_HOLDING = 1 << 8        #: the axis's line is held (an invalid input, hold, off)
    Y_HOLDING = 1 << 9
    Z_HOLDING = 1 << 10
    X_RAMPING = 1 << 12       #: the axis's line ramps to 0 (a fault past hold_s, shutdown)
    Y_RAMPING = 1 << 13
    Z_RAMPING = 1 << 14


#: an axis's bit of a kind in `AxesStatus`: ``1 << (AXES_NIBBLE[kind] + AXIS_INDEX[axis])``
AXIS_INDEX: dict[str, int] = {"x": 0, "y": 1, "z": 2}
AXES_NIBBLE: dict[str, int] = {"in_force": 0, "alarm": 4, "holding": 8, "ramping": 12}


__doc__ = (__doc__ or "") + "\n".join(
    f"    bit {int(b).bit_length() - 1:2d}  {b.name}" for b in Status) + "\n" + (
    "\nAxes word (``[output] axes_status``, `AxesStatus`):\n") + "\n".join(
    f"    bit {int(b).bit_length() - 1:2d}  {b.name}" for b in AxesStatus) + "\n"


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


#: slack on count arithmetic: k counts read back are k·count to a few ulps
COUNT_SLACK = 1e-9

#: counts either side of 0 an integer address may hold at most (int32; a
#: quantum so fine that ±limit_um is more counts is taken as no grid at all)
MAX_COUNTS = 2**31


class OutputStage:
    """Clamp, deadband, slew limit, whole counts, sign and scale (see the
    module docstring)."""

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
        fine = not (math.isfinite(quantum_um) and quantum_um > 0.0
                    and limit_um / quantum_um <= MAX_COUNTS)
        #: one count of an integer offset address in µm; 0: a float address
        self.quantum_um = 0.0 if fine else quantum_um
        #: the most counts either side of 0 within ±limit_um (quantised outputs)
        self._max_count = 0
        if self.quantum_um:
            n = math.floor(limit_um / self.quantum_um)
            while n > 0 and n * self.quantum_um > limit_um:
                n -= 1
            self._max_count = n
        self.current_um = self._start(initial_um)
        #: the slew-limited value before the grid (quantised outputs only): the
        #: wanted value, within one count of `current_um` after each step
        self._exact_um = self.current_um
        #: the last value the controller confirmed (a successful write or a read-back)
        self.confirmed_um: float | None = None
        self.slewing = False
        #: the controller holds an offset beyond ±limit (or not a number): no write
        self.held = False

    def _safe(self, x: float) -> float:
        return _clamp(x, self.limit_um) if math.isfinite(x) else 0.0

    def _start(self, x: float) -> float:
        """The offset the stage starts from: `initial_um`, the value compd last
        wrote (a checkpoint's, or the running one across a reload). Beyond
        ±limit_um (the limit was lowered since) it is kept, not clamped, so that
        the output ramps into the limit at the slew limit instead of jumping to
        it (an integer address: the nearest whole count)."""
        if not math.isfinite(x):
            return 0.0
        if abs(x) <= self.limit_um:
            return self._on_grid(x)
        if not self.quantum_um:
            return x
        return round(x / self.quantum_um) * self.quantum_um

    @property
    def beyond_limit(self) -> bool:
        """The output is beyond ±limit_um: an offset compd wrote before the limit
        was lowered, ramping into it (never further out)."""
        return abs(self.current_um) > self.limit_um

    def _bound(self) -> float:
        """How far from 0 the output may be: limit_um, or where it is now while
        it ramps into a lowered limit (`_start`): it only ever comes in."""
        return max(self.limit_um, abs(self.current_um))

    def _count(self, k: int, bound_um: float | None = None) -> float:
        """Count `k` in µm, within ±limit_um (or ±`bound_um` when it is further)."""
        most = self._max_count
        if bound_um is not None and bound_um > self.limit_um:
            most = max(most, math.floor(bound_um / self.quantum_um + COUNT_SLACK))
        k = max(-most, min(most, k))
        return k * self.quantum_um

    def _on_grid(self, x: float, bound_um: float | None = None) -> float:
        """`x` (finite, within the limit or `bound_um`) as the nearest whole
        count (what an integer address holds); unchanged for a float address."""
        if not self.quantum_um:
            return x
        return self._count(round(x / self.quantum_um), bound_um)

    def step(self, target_um: float, dt_s: float, *, deadband: bool = True) -> float:
        """Move toward `target_um`; returns the new output in µm (always finite,
        within ±limit, or nearer to it than the previous output while ramping
        into a lowered limit, within slew·Δt of the previous output, or one
        count of it when a count is more). Held: unchanged."""
        if self.held:
            self.slewing = False
            return self.current_um
        # the arithmetic of `_bound`, `_clamp` and `beyond_limit` inline: it runs for
        # the offset and for each axis's value and slope every cycle
        current, limit = self.current_um, self.limit_um
        beyond = abs(current) > limit
        bound = abs(current) if beyond else limit
        if not math.isfinite(target_um):
            target_um = current
        target = max(-limit, min(limit, target_um))
        # beyond a lowered limit the output comes in, however close the target is
        if deadband and not beyond and abs(target - current) <= self.deadband_um:
            target = current
        dt = min(max(dt_s, 0.0), self.max_dt_s) if math.isfinite(dt_s) else 0.0
        max_step = self.slew_um_s * dt
        if self.quantum_um:
            self.current_um = self._quantise(target, max_step, bound)
            return self.current_um
        delta = target - current
        self.slewing = abs(delta) > max_step
        delta = max(-max_step, min(max_step, delta))
        self.current_um = max(-bound, min(bound, current + delta))
        self._exact_um = self.current_um
        return self.current_um

    def _quantise(self, target: float, max_step: float, bound: float) -> float:
        """The count in force after one step toward `target` (module docstring,
        step 5): the wanted value moves at most `max_step`; the count follows it
        with a hysteresis of one count, toward it, never past it, by at most
        ⌊max_step / count⌋ counts, and one count when a count is more."""
        q = self.quantum_um
        held = self.current_um
        exact = self._exact_um
        delta = target - exact
        behind = abs(delta) > max_step
        exact = max(-bound, min(bound, exact + max(-max_step, min(max_step, delta))))
        new = held
        if max_step > 0.0 and abs(exact - held) >= q * (1.0 - COUNT_SLACK):
            k_held = round(held / q)
            most = max(1, math.floor(min(max_step / q, MAX_COUNTS) + COUNT_SLACK))
            if exact > held:
                k = min(math.floor(exact / q + COUNT_SLACK), k_held + most)
            else:
                k = max(math.ceil(exact / q - COUNT_SLACK), k_held - most)
            new = self._count(k, bound)
        # the count could not keep up (more than one count left): still slewing
        self.slewing = behind or abs(exact - new) > q * (1.0 + COUNT_SLACK)
        # the wanted value stays within one count of the count in force, so
        # that a reversal of the target turns the count within one count
        self._exact_um = max(new - q, min(new + q, exact))
        return new

    def to_controller(self, um: float) -> float:
        return self.sign * self.units_per_um * um

    def from_controller(self, value: float) -> float:
        return value / (self.sign * self.units_per_um)

    def readback_tolerance_um(self, float_tolerance_um: float) -> float:
        """How far a read-back may be from the confirmed value and still be
        it: half a count for an integer address (it holds whole counts, so
        any other count is foreign), else `float_tolerance_um` (float32
        rounding of what was written)."""
        return 0.5 * self.quantum_um if self.quantum_um else float_tolerance_um

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
        # beyond the limit only as far as the value compd wrote (`observe`)
        bound = max(self._bound(), abs(self.confirmed_um or 0.0))
        um = self._on_grid(_clamp(um, bound), bound) if math.isfinite(um) else self.current_um
        self._exact_um += um - self.current_um
        self.current_um = um
        self.confirmed_um = um

    def observe(self, um: float, tolerance_um: float) -> Readback:
        """The controller holds `um` (read back, µm): see the module docstring.
        `tolerance_um` is a float address's (`readback_tolerance_um`)."""
        confirmed = self.confirmed_um
        tolerance = self.readback_tolerance_um(tolerance_um)
        own = (confirmed is not None and math.isfinite(um)
               and abs(um - confirmed) <= tolerance)
        # what compd wrote is its own even beyond a limit lowered since (it ramps in)
        if not own and (not math.isfinite(um)
                        or abs(um) > self.limit_um * (1.0 + LIMIT_ROUNDING)):
            self.held = True
            return Readback.OUT_OF_RANGE
        self.held = False
        if own:
            if um != confirmed:
                # not a mismatch, but the next step is measured from what the
                # machine has, so the slew limit holds against it
                self.align(um)
            return Readback.MATCH
        self.adopt(um)
        return Readback.ADOPTED if confirmed is None else Readback.FOREIGN

    def adopt(self, um: float) -> None:
        """The controller holds `um` (read back): ramp from there."""
        self.current_um = self._on_grid(self._safe(um))
        self._exact_um = self.current_um
        self.confirmed_um = self.current_um


def count_warnings(*, quantum_um: float, slew_um_s: float, period_s: float,
                   limit_um: float) -> list[str]:
    """What `compd check` warns of an integer offset address whose count
    (`quantum_um`, µm) is coarse against the output stage: more than the slew
    limit allows per period, or more than the limit itself (none for a float
    address, quantum 0)."""
    if not (math.isfinite(quantum_um) and quantum_um > 0.0):
        return []
    q, per_cycle = quantum_um, slew_um_s * period_s
    found: list[str] = []
    if q > limit_um:
        found.append(f"output.offset: one count of the offset address is {q:g} µm, more "
                     f"than limit_um ({limit_um:g} µm): the only offset it can hold within "
                     "the limit is 0, so compd will never compensate; use a finer encoding "
                     "(a smaller scale, or a float type)")
    elif q > per_cycle:
        found.append(f"output.offset: one count of the offset address is {q:g} µm, more "
                     f"than the slew limit allows per period ({slew_um_s:g} µm/s × "
                     f"{period_s:g} s = {per_cycle:g} µm): the offset will move in steps of "
                     f"one count ({q:g} µm at the tool, {q / per_cycle:.3g}× the slew step), "
                     "at most one count per cycle and on average no faster than the slew "
                     "limit; a new count is written only when the model is a whole count "
                     f"from the one in force (within {q:g} µm of the model); use a finer encoding "
                     "(a smaller scale, or a float type) for a smoother offset")
    return found
