"""``[adaptation]``: the probe-assisted estimator's section and the physical bounds of its
settings (`ADAPTATION_BOUNDS`, `learnt_bounds`), each with the reason for it."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from compd.config.section import MAX_LIMIT_UM, Section, bounded

#: [adaptation]'s physical bounds. The estimator (models.adaptation.DOMAIN) stays finite
#: far beyond them; these are what a machine tool makes sensible, and a value outside is a
#: typo or an attack, refused by name at check, run and reload alike. The reasons:
_WHY_BIAS_RW = ("the model's error wanders some 0.1 ... 2 µm/√h on a machine; beyond "
                "100 µm/√h is more than a machine's whole thermal growth in an hour")
_WHY_PROBE_NOISE = ("a touch probe repeats within 1 µm, a tool setter within a few: no "
                    "probe repeats better than 10 nm, and one scattering over 100 µm "
                    "measures nothing a thermal correction can use")
_WHY_GATE = ("below 1 σ the gate refuses a third of the good probes; no good probe "
             "reaches 10 σ (p ≈ 1e-23), a wider gate only lets chips and wrong tools in")
_WHY_CORRECTION = ("1 nm ... 10 mm and at most output.limit_um: the output stage clamps "
                   "there, a larger bound only hides a runaway estimate")
_WHY_GAIN_RW = ("a term's gain that may wander by its whole size within an hour is not "
                "a slow drift but a wrong model")
_WHY_MAX_GAIN = ("a relative gain correction of ±1 removes or doubles a term: beyond "
                 "that the model is wrong, recalibrate")
#: the bounds (low, high) of [adaptation]'s estimator settings, by name: what `compd check`
#: and `run` hold the config's settings and a model file's [adaptation] table to
#: (`learnt_bounds`)
ADAPTATION_BOUNDS: dict[str, tuple[float, float]] = {
    "bias_rw_um_per_sqrt_h": (0.0, 100.0),
    "probe_noise_um": (0.01, 100.0),
    "gate_sigma": (1.0, 10.0),
    "max_step_um": (0.001, MAX_LIMIT_UM),
    "max_total_um": (0.001, MAX_LIMIT_UM),
    "gain_rw_per_sqrt_h": (0.0, 1.0),
    "max_gain": (0.0, 1.0),
    "score_window": (0, 100),
    "reacquire_after": (0, 100),
}
_B = ADAPTATION_BOUNDS
BiasRw = Annotated[float, *bounded(*_B["bias_rw_um_per_sqrt_h"], " µm/√h", _WHY_BIAS_RW)]
ProbeNoise = Annotated[float, *bounded(*_B["probe_noise_um"], " µm", _WHY_PROBE_NOISE)]
GateSigma = Annotated[float, *bounded(*_B["gate_sigma"], " σ", _WHY_GATE)]
Correction = Annotated[float, *bounded(*_B["max_step_um"], " µm", _WHY_CORRECTION)]
GainRw = Annotated[float, *bounded(*_B["gain_rw_per_sqrt_h"], " per √h", _WHY_GAIN_RW)]
MaxGain = Annotated[float, *bounded(*_B["max_gain"], "", _WHY_MAX_GAIN)]
_WHY_SCORE_WINDOW = ("probes the estimator scores itself over: 0 never stands down; beyond "
                     "100 probes a machine's error has long changed, the score only lags")
ScoreWindow = Annotated[int, *bounded(*_B["score_window"], " probes", _WHY_SCORE_WINDOW)]
_WHY_REACQUIRE = ("refusals in a row, agreeing in direction, after which the estimator "
                  "re-acquires: 0 never; beyond 100 probes a real change has long been "
                  "missed")
ReacquireAfter = Annotated[int, *bounded(*_B["reacquire_after"], " probes", _WHY_REACQUIRE)]
_WHY_GUARD = ("probes in a row showing the model worse than none before the alarm: 0 no "
              "guard; beyond 100 probes a wrong model would run for days")
GuardWindow = Annotated[int, *bounded(0, 100, " probes", _WHY_GUARD)]


class AdaptationSection(Section):
    """``[adaptation]``: learn from the machine's probe measurements
    (`compd.core.adaptation`; the estimator's settings default to
    `models.adaptation.AdaptationParams`). Every numeric setting has a physical
    bound (above); `max_step_um` and `max_total_um` are also at most
    `output.limit_um` (the loader)."""

    enabled: bool = False
    #: "shadow": the estimator's correction is estimated and recorded, not applied;
    #: "apply": added to the model output (the guard acts in both: guard_action)
    mode: Literal["shadow", "apply"] = "shadow"
    #: what the measuring cycle leaves: "residual" (the probe on a compensating
    #: machine: growth minus the offset in force) or "displacement"
    measures: Literal["residual", "displacement"] = "residual"
    #: controller address of the measured Z deviation (µm)
    probe_value: dict[str, Any] | None = None
    #: controller address of a counter (or timestamp) that changes with each measurement
    probe_counter: dict[str, Any] | None = None
    bias_rw_um_per_sqrt_h: BiasRw | None = None
    probe_noise_um: ProbeNoise | None = None
    gate_sigma: GateSigma | None = None
    max_step_um: Correction | None = None
    max_total_um: Correction | None = None
    gains: bool | None = None
    gain_rw_per_sqrt_h: GainRw | None = None
    max_gain: MaxGain | None = None
    #: accepted probes the estimator keeps score over; it stands down (applies nothing)
    #: while adapting loses to the plain model over them (models.adaptation)
    score_window: ScoreWindow | None = None
    #: gate refusals in a row agreeing in direction after which the estimator
    #: re-acquires (a real change, within max_total_um); 0: never
    reacquire_after: ReacquireAfter | None = None
    #: the guard "no model worse than none" (compd.core.adaptation): this many probes
    #: in a row each showing the compensation making the error larger than none would
    #: (by more than twice probe_noise_um) are an alarm and a fault (hold, then ramp
    #: to zero per [faults]) until another model is loaded; 0: no guard
    guard_window: GuardWindow = 3
    #: what the guard's verdict does, in either mode (it judges the compensation in
    #: force, which "shadow" does not change): "fault" holds, then ramps to zero;
    #: "report" raises the event, the status page's line and the metric only
    guard_action: Literal["fault", "report"] = "fault"

    def estimator_settings(self) -> dict[str, Any]:
        """The estimator settings given (the others keep their defaults)."""
        names = ("bias_rw_um_per_sqrt_h", "probe_noise_um", "gate_sigma", "max_step_um",
                 "max_total_um", "gains", "gain_rw_per_sqrt_h", "max_gain", "score_window",
                 "reacquire_after")
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}


def learnt_bounds() -> dict[str, tuple[float, float]]:
    """(low, high) of every numeric setting a model file's [adaptation] table may hold, as
    `compd check` and `run` hold it there: [adaptation]'s bound where the section has the
    setting (the loader validates the table's keys as the section's), else the
    estimator's domain (`models.adaptation.DOMAIN`, checked by `models.modelfile`)."""
    from models.adaptation import DOMAIN

    return {name: ADAPTATION_BOUNDS.get(name, domain) for name, domain in DOMAIN.items()}

