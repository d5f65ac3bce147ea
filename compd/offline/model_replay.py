"""A record replayed through the bare model: the papers' figures.

`replay_model` steps a `CompensationModel` over every row of a record as the
daemon steps it (`set_references` at the first sample, then `step(sample)`
once per row), from rest or from the steady state of the first sample: no
validation, fault policy or output stage (`compd.offline.cycle_replay` replays
through the daemon's own cycle for those).

A record rarely starts cold, so `replay_with_init` says the model's starting
state (`InitMode`), never assumes it silently:

- ``estimate``: the output level and each transfer-function term's initial
  state (steady for an input level) are estimated by least squares on the
  first half of the measured displacement (`models.initial_state`), as
  system-identification tools compare a model with data;
- ``steady``: every term at steady state for the first sample (speed and
  power terms at their first value), at the displacement measured there (the
  mean of the first `STEADY_LEVEL_SAMPLES` samples);
- ``rest``: every filter at rest at the first sample (the machine cold).

A model whose sample period differs from the record's is refused
(`check_period`): its coefficients would mean something else.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Literal, get_args

if TYPE_CHECKING:  # numpy and the model load when a replay runs: `compd --help` stays light
    import numpy as np
    import numpy.typing as npt

    from compd.offline.records import Record, Samples
    from models.compensation import CompensationModel

    FloatArray = npt.NDArray[np.float64]

#: the model's state at a record's first sample (see the module docstring)
InitMode = Literal["estimate", "steady", "rest"]
INIT_MODES: tuple[InitMode, ...] = get_args(InitMode)
#: samples averaged for the displacement level of ``steady``
STEADY_LEVEL_SAMPLES = 5


def check_period(model: CompensationModel, record: Record) -> None:
    """RecordError unless the model was identified at the record's period."""
    from compd.offline.records import RecordError

    if not math.isclose(model.period_s, record.period_s, rel_tol=1e-6):
        raise RecordError(f"{record.path}: sampled every {record.period_s:g} s but the model "
                          f"{model.name!r} was identified at {model.period_s:g} s; its "
                          "coefficients do not apply (refit it at this period)")


def _started(model: CompensationModel, record: Record, steady: bool) -> Samples:
    """`record`'s samples, `model` reset and referenced to the first (at its steady
    state there with `steady`), as the daemon starts it."""
    check_period(model, record)
    record.require(model.channels)
    samples = record.samples()
    model.reset()
    model.set_references(samples[0])
    if steady:
        model.steady_state(samples[0])
    return samples


def replay_model(model: CompensationModel, record: Record, *, steady: bool = False
                 ) -> FloatArray:
    """δZ predicted at every row, stepping the model as the daemon does
    (from rest, or from the steady state of the first sample). The model's
    state is reset first and left as the last row left it."""
    import numpy as np

    samples = _started(model, record, steady)
    step = model.step
    return np.fromiter((step(s) for s in samples), dtype=np.float64, count=len(samples))


def replay_terms(model: CompensationModel, record: Record, *, steady: bool = False
                 ) -> FloatArray:
    """Each term's contribution at every row (rows × terms), from the replay
    `replay_model` steps (the same start, one step per row)."""
    import numpy as np

    samples = _started(model, record, steady)
    out = np.empty((len(samples), len(model.terms)))
    for k, s in enumerate(samples):
        model.step(s)
        out[k] = model.contributions
    return out


def replay_with_init(model: CompensationModel, record: Record, measured: FloatArray,
                     init: InitMode) -> FloatArray:
    """The replay from the starting state `init` (see the module docstring);
    `measured` is the record's displacement (µm), which ``estimate`` and
    ``steady`` read the starting level from."""
    import numpy as np

    from models.initial_state import default_window, estimate_initial_state, relaxation_basis

    simulated = replay_model(model, record, steady=init == "steady")
    if init == "steady":
        k = min(STEADY_LEVEL_SAMPLES, simulated.size)
        return simulated + float(np.mean(measured[:k] - simulated[:k]))
    if init == "rest":
        return simulated
    gains = [record.column(t.gain_channel) if t.gain_channel else t.gain for t in model.terms]
    basis, names = relaxation_basis(model, gains, simulated.size)
    est = estimate_initial_state(measured - simulated, basis, names,
                                 default_window(simulated.size))
    return simulated + est.response


def plot_inputs(model: CompensationModel, record: Record) -> dict[str, FloatArray]:
    """The channels a replay figure shows above the displacement: the model's,
    then any spindle speed the record holds."""
    from compd.offline.channel_kind import ChannelKind, channel_kind

    names = [c for c in record.columns if c in model.channels]
    names += [c for c in record.columns
              if channel_kind(c) is ChannelKind.SPEED and c not in names]
    return {c: record.columns[c] for c in names}
