"""What a cycle is built from when it continues another: a checkpoint (a
restart) or the running cycle's exported state (a reload), as keyword
arguments for `compd.core.cycle.Cycle` (pure).

The state is `Cycle.export_state()`'s dict (the checkpoint's payload):
``offset_um`` (the last offset the controller confirmed), ``sequence``,
``heartbeat``, the model's state (``model`` with its ``terms`` and
``references``, ``shadow``, ``fallbacks``, ``zero``), ``adaptation`` and
``operator_hold``. Any part of it may be missing or of the wrong type (a
checkpoint from an older compd, or a damaged one): that part is not used.

Fresh (saved less than ``checkpoint_max_age_s`` ago, the same model): the
filters resume where they were. Too old (`age_s` machine seconds since it was
saved) and the same model: the filters are advanced from there over `age_s`
with the first valid sample's inputs held, or start at its steady state
(`compd.core.modelstep`). Another model: only the references and the last
confirmed offset are kept. The re-zero and the adaptation estimator resume
whenever the model is the same (`same_model`), fresh or not; another model
clears them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from compd.core.adaptation import AdaptationSettings, ProbeStage
from compd.core.events import Event, EventName
from compd.core.output import OutputStage
from compd.core.params import CycleParams

__all__ = ["output_stage", "probe_stage", "restore_arguments"]


def _mapping(value: Any) -> Mapping[str, Any] | None:
    return value if isinstance(value, Mapping) else None


def restore_arguments(state: Mapping[str, Any], *, fresh: bool, same_model: bool,
                      age_s: float | None) -> dict[str, Any]:
    """The `Cycle` keyword arguments that continue `state` (module docstring)."""
    model_state = _mapping(state.get("model"))
    refs: Mapping[str, float] | None = None
    if model_state is not None:
        r = _mapping(model_state.get("references"))
        refs = r if r else None
    else:
        refs = _mapping(state.get("references"))
    offset = state.get("offset_um")
    has_terms = model_state is not None and "terms" in model_state
    usable = fresh and has_terms
    return {
        "model_state": model_state if usable else None,
        "shadow_state": _mapping(state.get("shadow")) if usable else None,
        "fallback_states": _mapping(state.get("fallbacks")) if usable else None,
        "references": refs,
        "offset_um": float(offset) if isinstance(offset, int | float) else None,
        "sequence": int(state.get("sequence", 0)),
        "heartbeat": int(state.get("heartbeat", 0)),
        "adaptation_state": _mapping(state.get("adaptation")) if same_model else None,
        "operator_hold": state.get("operator_hold") is True,
        "stale_state": model_state if (not usable and same_model and has_terms) else None,
        "stale_age_s": age_s,
        "zero": _mapping(state.get("zero")),
        "axes_state": _axes_state(_mapping(state.get("axes")), usable=usable),
    }


def _axes_state(axes: Mapping[str, Any] | None, *, usable: bool
                ) -> dict[str, Any] | None:
    """Each axis's confirmed value and slope (and for an axis at its position the
    offset last confirmed and the position it was written at), and its models' state:
    resumed when
    the checkpoint is fresh and of the same model (``fresh``), else only their
    reference state kept, and they start at the steady state of today's inputs
    (as the offset's model does)."""
    if axes is None:
        return None
    keep = ("value", "slope", "value_model", "slope_model", "value_model_sha256",
            "slope_model_sha256", "offset_um", "position_mm")
    return {axis: {**{k: v for k, v in doc.items() if k in keep}, "fresh": usable}
            for axis, doc in axes.items() if isinstance(doc, Mapping)}


def output_stage(params: CycleParams, offset_um: float | None) -> OutputStage:
    """The output stage, believed to hold `offset_um` (the checkpoint's)."""
    stage = OutputStage(
        limit_um=params.limit_um, slew_um_s=params.slew_um_s,
        deadband_um=params.deadband_um, sign=params.sign,
        units_per_um=params.units_per_um, max_dt_s=2.0 * params.period_s,
        initial_um=offset_um if offset_um is not None else 0.0,
        quantum_um=params.offset_quantum_um)
    # what the controller is known to hold at start: the checkpoint's last
    # confirmed offset; without one and without read-back, 0 (a first start
    # can assume nothing else, and a refused first write must fall back to
    # it, not to a value never written); with read-back, unknown until read
    if (offset_um is not None and math.isfinite(offset_um)) or not params.readback:
        stage.confirm()
    return stage


def probe_stage(settings: AdaptationSettings | None, n_terms: int,
                state: Mapping[str, Any] | None, events: list[Event]) -> ProbeStage | None:
    """The adaptation's estimator continuing `state` (None: no [adaptation]); a
    state it refuses starts it afresh, told (ADAPTATION_STATE_REFUSED)."""
    if settings is None:
        return None
    try:
        return ProbeStage(settings, n_terms, state)
    except (ValueError, KeyError, TypeError) as exc:
        events.append(Event(EventName.ADAPTATION_STATE_REFUSED, {"reason": str(exc)}))
        return ProbeStage(settings, n_terms)
