"""What the cycle reports beyond the output (pure): the `Snapshot` the faces
read (the operator's hold, the adaptation estimator, the pending change, the
re-zero and the reference state in force) and the model's contributions as
recorded, both taken from the cycle's parts when it plans or commits."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from compd.core.adaptation import ProbeStage
from compd.core.modelstep import ModelStepper
from compd.core.plan import AdaptationView, Snapshot
from compd.core.stepping import Stepped

__all__ = ["probe_record", "recorded_contributions", "take_snapshot"]


def take_snapshot(*, operator_hold: bool, probes: ProbeStage | None, models: ModelStepper,
                  fallback_for: str | None, pending_um: float | None) -> Snapshot:
    adaptation = None
    if probes is not None:
        est = probes.adapter
        adaptation = AdaptationView(est.estimated_bias_um, est.bias_sigma_um,
                                    probes.correction_um, est.standing_down,
                                    probes.model_worse, guard_probes=len(probes.guard),
                                    guard_worse=probes.guard_worse,
                                    probes_accepted=probes.accepted,
                                    probes_refused=probes.refused,
                                    gate_refusals=probes.gate_refusals)
    # the stepper replaces its references, never changes them in place: a
    # read-only view of the dict in force is the snapshot's
    refs = models.references
    return Snapshot(operator_hold, adaptation, pending_um=pending_um,
                    zero_um=models.zero_um if models.zero_by else None,
                    model_start=models.init_mode, reference=models.reference_source,
                    fallback_for=fallback_for,
                    references=None if refs is None else MappingProxyType(refs))


def recorded_contributions(models: ModelStepper, probes: ProbeStage | None, stepped: Stepped,
                           *, valid: bool, recorded: bool) -> dict[str, float]:
    """Each term's contribution as recorded (`recorded`: ``[recorder] record_model``),
    with the fallback's, the shadow's and the adaptation's totals."""
    contributions = models.contributions() if valid and recorded else {}
    if stepped.fallback_for is not None and stepped.model_um is not None and recorded:
        contributions["fallback_total"] = stepped.model_um
    if stepped.shadow_um is not None:
        contributions["shadow_total"] = stepped.shadow_um
    if probes is not None and valid:
        contributions["adaptation"] = probes.correction_um
    return contributions


def probe_record(probes: ProbeStage | None) -> Mapping[str, Any] | None:
    """The probe that arrived this cycle, read-only (None: none, or no adaptation)."""
    last = probes.last if probes is not None else None
    return None if last is None else MappingProxyType(dict(last))
