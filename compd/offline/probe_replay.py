"""`compd replay --probe-every-min` as a library: the probes replayed beside a
model's replay over a record (`compd.offline.probes.run_probes`, the daemon's
own probe stage) from a typed, frozen request (`ProbeRequest`), and the
figures of the adapted and the crude correction. The command
(`compd.commands.replay_probes`) builds the request from its options and
prints the lines."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from compd.offline.model_replay import InitMode
    from compd.offline.probes import ProbeRun
    from compd.offline.records import Record
    from models.adaptation import AdaptationParams
    from models.compensation import CompensationModel
    from models.quality import CompensationFigures

    FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ProbeRequest:
    """Probes replayed beside a model (docs/adaptation.md §4); each field is the
    `compd replay` option of that name."""

    #: a probe every this many minutes of the record
    every_min: float
    #: seeded Gaussian noise added to each probe value (µm), and its seed
    noise_um: float = 0.0
    seed: int = 0
    #: also estimate a slow gain correction of each term
    gains: bool = False
    #: the library's defaults, not the model file's [adaptation] table
    defaults_only: bool = False
    #: `AdaptationParams` fields given as options: (field, value), winning over both
    settings: tuple[tuple[str, float], ...] = ()
    #: the model's starting state in the replay (the terms' contributions start as it)
    init: InitMode = "estimate"
    #: the measured column (µm), for the messages
    output: str = "dz_um"


def probe_params(request: ProbeRequest,
                 learnt: Mapping[str, Any] | None = None) -> AdaptationParams:
    """The estimator's settings: the request's over the model's learnt table (unless
    `defaults_only`) over the defaults (ValueError when bad)."""
    from models.adaptation import AdaptationParams, mark_unproven, with_probe_noise

    table = {} if request.defaults_only or learnt is None else dict(learnt)
    changes: dict[str, Any] = dict(request.settings)
    if "probe_noise_um" in changes:
        table = with_probe_noise(table, float(changes["probe_noise_um"]),
                                 request.every_min * 60.0)
    elif request.noise_um > 0:
        # the probe's added noise, on top of what the model's own residual does fast
        table = with_probe_noise(table, math.hypot(float(table.get("probe_noise_um", 0.0)),
                                                   request.noise_um), request.every_min * 60.0)
    gains = {"gains": True} if request.gains else {}
    # as the daemon: settings not learnt for the model start stood down
    return dataclasses.replace(AdaptationParams(),
                               **{**mark_unproven(table), **gains, **changes})


def replay_probes(request: ProbeRequest, model: CompensationModel, record: Record,
                  measured: FloatArray, simulated: FloatArray, first: int
                  ) -> tuple[ProbeRun, dict[str, Any]]:
    """Run the probes over the replay `simulated` of `record`, scored from row
    `first`; the run and the JSON keys "adapted", "crude", "adaptation" and
    "adaptation_from". InputError (64) for a probe interval shorter than the
    record's period, RecordError when the figures mean nothing."""
    import numpy as np

    from compd.offline.model_replay import replay_terms
    from compd.offline.probes import run_probes
    from compd.offline.quality_check import checked_quality

    every_s = 60.0 * request.every_min
    if every_s < record.period_s:  # a probe at every row is the most there can be
        from compd.infiles import InputError
        from compd.sysexits import EX_USAGE

        raise InputError(f"--probe-every-min {request.every_min:g}: shorter than the "
                         f"record's period of {record.period_s:g} s (at most one probe per "
                         "row)", EX_USAGE)
    params = probe_params(request, model.adaptation)
    terms = None
    if params.gains:
        terms = replay_terms(model, record, steady=request.init == "steady")
    run = run_probes(simulated, measured, record.time_s, terms, every_s=every_s,
                     noise_um=request.noise_um, seed=request.seed, params=params)
    adapted = checked_quality(measured[first:], run.adapted[first:], record.path,
                              request.output)
    crude = checked_quality(measured[first:], run.crude[first:], record.path, request.output)
    rms = {name: float(np.sqrt(np.mean((measured[first:] - pred[first:]) ** 2)))
           for name, pred in (("plain", simulated), ("adapted", run.adapted),
                              ("crude", run.crude))}
    return run, figures(run, adapted, crude, first, params, rms,
                        request.defaults_only or not model.adaptation)


def figures(run: ProbeRun, adapted: CompensationFigures, crude: CompensationFigures,
            first: int, params: AdaptationParams, rms: dict[str, float],
            args_defaults: bool = True) -> dict[str, Any]:
    """The JSON keys "adapted", "crude" and "adaptation" (the settings used); `rms`
    the residue's RMS (µm, scored rows) of "plain", "adapted" and "crude"."""
    scored = int((run.rows >= first).sum())
    return {
        "adapted": {**adapted.as_dict(), "probes": int(run.rows.size),
                    "probes_scored": scored, "probes_used": int(run.accepted.sum()),
                    "probes_refused": int((~run.accepted).sum()),
                    "applied_moves": run.adapter.applied_moves,
                    "stand_downs": run.adapter.stand_downs,
                    "standing_down": run.adapter.standing_down,
                    "bias_um": run.adapter.bias_um,
                    "estimated_bias_um": run.adapter.estimated_bias_um,
                    "bias_sigma_um": run.adapter.bias_sigma_um,
                    "residue_rms_um": rms["adapted"],
                    "plain_residue_rms_um": rms["plain"]},
        "crude": {**crude.as_dict(), "probes": int(run.rows.size),
                  "residue_rms_um": rms["crude"]},
        "adaptation": dataclasses.asdict(params),
        "adaptation_from": "defaults" if args_defaults else "model",
    }
