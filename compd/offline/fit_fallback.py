"""`compd fit`'s fallback models: for each input of the model, a model on the
others, fitted and validated the same way on the same records, written into
the model file as a ``[[fallback]]`` table (`models.modelfile`); the daemon
switches to it while that input is invalid (`compd.core.fallback`).

A fallback is the main fit run again (`compd.offline.fit_identify.identify_terms`: the
same structure selection, folds, pole bound and checks) on the terms that do
not read the lost channel (a term ``bearing-column`` goes with either). No
fallback is written for a channel when no term is left without it, when a
``--fixed`` term reads it, when its identification fails, when `compd check`
would warn about it, or when it validated worse than no compensation: that
one is refused even with ``--force`` (a fallback is never forced: without it
the daemon holds, then ramps, which is safe). Only ``--kind tf`` models get
fallbacks (the other kinds fit one term). Each skipped channel is said, with
why, in ``notes``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from compd.offline.fit_request import FitRun
    from compd.offline.records import Record
    from models.compensation import CompensationModel, Term


@dataclass
class Fallbacks:
    """The fallbacks fitted, by the channel each covers, and a line per channel left out."""

    models: dict[str, CompensationModel] = field(default_factory=dict)
    #: per fallback: its validation figure and structure (for the provenance and --json)
    figures: dict[str, dict[str, Any]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def fit_fallbacks(run: FitRun, records: list[Record], ys: list[Any],
                  specs: list[tuple[str, dict[str, float]]], holdout: list[Record],
                  fixed: list[Term], reads: set[str] | None = None) -> Fallbacks:
    """A fallback for the loss of each input channel the main model `reads`
    (default: those of `specs`; an averaged model also reads its other members'
    channels: `compd.offline.fit_hedge`), module docstring."""
    from compd.offline.fit_checks import gate
    from compd.offline.fit_identify import identify_terms
    from models.compensation import CompensationModel
    from models.errors import ModelError

    out = Fallbacks()
    if run.request.kind != "tf":
        return out
    channels = sorted(reads if reads is not None else
                      {ch for _, inputs in specs for ch in inputs})
    for lost in channels:
        # the terms left: those that read neither the lost channel nor one the main
        # model does not read (an average may have left a chosen input out)
        reduced = [(n, i) for n, i in specs if lost not in i and set(i) <= set(channels)]
        if not reduced:
            out.notes.append(f"no fallback without {lost}: no term is left without it")
            continue
        if any(lost in t.channels for t in fixed):
            out.notes.append(f"no fallback without {lost}: a --fixed term reads it")
            continue
        # a fallback worse than none, or one check warns of, is never written (never
        # forced); the hedge's other candidates (`compd.offline.fit_hedge`) read
        # only what the main model reads, never the lost channel
        one = dataclasses.replace(run, force=False, hedge_channels=set(channels) - {lost})
        said = io.StringIO()
        try:
            with contextlib.redirect_stderr(said):
                terms, info = identify_terms(one, records, ys, reduced, holdout)
                model = CompensationModel(
                    fixed + terms, records[0].period_s, name=f"without {lost}",
                    description=f"compd fit: the model without {lost}")
                gate(model, False)
        except ModelError as exc:
            why = str(exc).replace(" (--force writes it anyway)", "")  # never forced
            out.notes.append(f"no fallback without {lost}: {why}")
            continue
        selection = info[0]["selection"] if info else {}
        figures = {"validation_fit_percent": selection.get("validation_fit_percent"),
                   "structure": selection.get("structure"),
                   "inputs": [n for n, _ in reduced]}
        model.provenance = {"tool": "compd fit (fallback)", "lost": lost,
                            **{k: v for k, v in figures.items() if v is not None}}
        out.models[lost] = model
        out.figures[lost] = figures
        out.notes.extend(f"fallback without {lost}: {line}"
                         for line in said.getvalue().splitlines() if line.strip())
    return out
