"""`compd fit` writes no model that `compd check` warns about (unless ``--force``).

`CheckVeto` is handed to the structure selection
(`models.identify.structures.select_structure`'s ``veto``): each candidate's
final estimate is built as the model file will hold it (its terms, their
inputs, and the spans fit writes into the provenance) and given to `compd
check`'s own warnings (`compd.offline.model_description.plausibility`: a negative real
pole, a DC gain out of proportion to the recorded range, terms that cancel).
A candidate they flag is rejected like an implausible one, so the selection
falls back to the best candidate without a warning (another structure, then
first order, then a static model). `gate` is the last word before the file is
written: the whole model, fixed terms included.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from models.errors import ModelError

if TYPE_CHECKING:
    from compd.offline.fit_terms import FitTerm
    from models.compensation import CompensationModel
    from models.identify.output_error import OeModel

#: how a candidate rejected by `CheckVeto` is named in the selection's table
VETO_PREFIX = "compd check would warn: "


class CheckVeto:
    """Why a candidate's model gets a warning from `compd check` (None: none).

    `specs`: (name, {channel: ±1}) per term; `relative` per term; `input_spans`
    and `output_span` as fit writes them into the provenance."""

    def __init__(self, specs: Sequence[tuple[str, dict[str, float]]],
                 relative: Sequence[bool], input_spans: Sequence[float], output_span: float,
                 period_s: float) -> None:
        self._specs = list(specs)
        self._relative = list(relative)
        self._provenance: dict[str, Any] = {"output_span_um": output_span}
        for (name, _), span in zip(self._specs, input_spans, strict=True):
            self._provenance[f"{name}_input_span"] = span
        self._period_s = period_s
        #: the first warning of each candidate vetoed, in the order they came
        self.vetoed: list[str] = []

    def model(self, nums: Sequence[Sequence[float]], dens: Sequence[Sequence[float]]
              ) -> CompensationModel:
        """The candidate as the model file would hold it (shortest round-trip floats)."""
        from models.compensation import CompensationModel, Term
        from models.tf import TransferFunction

        terms = [Term(name=name, inputs=inputs, relative=rel,
                      dynamics=TransferFunction([repr(float(v)) for v in num],
                                                [repr(float(v)) for v in den], name=name))
                 for (name, inputs), rel, num, den in zip(self._specs, self._relative, nums,
                                                          dens, strict=True)]
        return CompensationModel(terms, self._period_s, name="candidate",
                                 provenance=dict(self._provenance))

    def __call__(self, m: OeModel) -> str | None:
        flags = self._flags(m)
        if not flags:
            return None
        self.vetoed.append(flags[0])
        return self._said(flags)

    def quietly(self, m: OeModel) -> str | None:
        """The veto of `m` without counting it among `vetoed` (a selection asking ahead)."""
        flags = self._flags(m)
        return self._said(flags) if flags else None

    def _flags(self, m: OeModel) -> list[str]:
        from compd.offline.model_description import plausibility

        try:
            return list(plausibility(self.model(m.nums, m.term_dens())))
        except (ModelError, ValueError) as exc:  # not even a model the file could hold
            return [str(exc)]

    @staticmethod
    def _said(flags: list[str]) -> str:
        return VETO_PREFIX + flags[0] + (f" (and {len(flags) - 1} more)" if len(flags) > 1
                                         else "")


    def terms(self, fitted: Sequence[FitTerm]) -> str | None:
        """Why a model of `fitted` terms (a candidate of the hedge, or the
        average written: `compd.offline.fit_hedge`) gets a warning from `compd
        check`, its spans as fit writes them; None: none. Not counted among
        the selection's vetoes."""
        from compd.offline.model_description import plausibility
        from models.compensation import CompensationModel, Term
        from models.tf import TransferFunction

        prov = {"output_span_um": self._provenance["output_span_um"],
                **{f"{t.name}_input_span": float(np.ptp(t.u)) for t in fitted}}
        try:
            model = CompensationModel(
                [Term(name=t.name, inputs=t.inputs, relative=t.relative,
                      dynamics=TransferFunction([repr(float(v)) for v in t.num],
                                                [repr(float(v)) for v in t.den], name=t.name))
                 for t in fitted], self._period_s, name="candidate", provenance=prov)
            flags = plausibility(model)
        except (ModelError, ValueError) as exc:
            flags = [str(exc)]
        if not flags:
            return None
        return flags[0] + (f" (and {len(flags) - 1} more)" if len(flags) > 1 else "")


def fallback_line(summary: dict[str, Any], veto: CheckVeto) -> str | None:
    """Why the model written is not the best validated one, when `compd check`'s
    warnings made the difference (one line), else None."""
    if not veto.vetoed:
        return None
    chosen = summary["structure"]
    cands = summary.get("candidates", [])
    vetoed = [c for c in cands if c.get("rejected", "").startswith(VETO_PREFIX)]
    failed = [n for n in summary.get("notes", []) if n.startswith("failed:")
              and VETO_PREFIX in n]
    if failed:
        return (f"compd fit: fell back to {chosen} (denominator order "
                f"{summary['orders']['denominator_order']}, numerator length "
                f"{summary['orders']['numerator_length']}): compd check warns about the model "
                f"of every candidate at the orders asked for ({veto.vetoed[0]})")
    top = max(cands, key=lambda c: c["validation_fit_percent"], default=None)
    if top is None or top not in vetoed:
        return None
    reason = top["rejected"][len(VETO_PREFIX):]
    return (f"compd fit: fell back to {chosen} (validation "
            f"{summary['validation_fit_percent']:.2f} %): {top['structure']} validated better "
            f"({top['validation_fit_percent']:.2f} %) but compd check warns about its model: "
            f"{reason}")


def gate(model: CompensationModel, force: bool) -> None:
    """ModelError (the model is not written) when `compd check` would warn about
    `model`, unless `force` (then the warnings go to stderr)."""
    from compd.offline.model_description import plausibility

    flags = plausibility(model)
    if not flags:
        return
    more = f" (and {len(flags) - 1} more)" if len(flags) > 1 else ""
    if not force:
        raise ModelError(f"compd check would warn about this model: {flags[0]}{more}; not "
                         "written (--force writes it anyway)")
    for w in flags:
        print(f"compd fit: warning: compd check would warn: {w}; written all the same (--force)",
              file=sys.stderr)
