"""`compd fit`'s identification of the terms from the records: each term's input
built from its channels (relative to the record's first sample, speed and power
absolute), the structure chosen (`compd.offline.fit_select`) or searched
(`models.identify.tf_fit`), every term rebuilt and checked as the model file will
hold it. The main fit (`compd.offline.fit`) and each fallback
(`compd.offline.fit_fallback`) run it."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from compd.offline.fit_request import FitRun
    from compd.offline.records import Record
    from models.compensation import Term


def relative_input(record: Record, inputs: dict[str, float], relative: bool) -> Any:
    import numpy as np

    u = np.zeros(len(record))
    for ch, c in inputs.items():
        col = record.column(ch)
        u += c * (col - col[0] if relative else col)
    return u


def joined(parts: list[Any]) -> Any:
    """The records' arrays end to end (one record's array itself, not a copy: a
    month at 1 s is 21 MB a column)."""
    import numpy as np

    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _fit_tf(run: FitRun, records: list[Record], ys: list[Any],
            specs: list[tuple[str, dict[str, float]]], holdout_records: list[Record],
            ) -> tuple[list[Term], list[dict[str, Any]]]:
    import numpy as np

    from compd.offline.fit_terms import FitTerm
    from models.compensation import Term
    from models.errors import ModelError
    from models.identify.checks import build_checked_tf
    from models.identify.segments import Segments, pole_radius
    from models.identify.tf_fit import Holdout, fit_tf_terms

    period = records[0].period_s
    radius = pole_radius(period, run.request.max_time_constant_days * 86400.0)
    seg = Segments.from_lengths([len(r) for r in records])
    y = joined(ys)
    from compd.offline.channel_kind import is_rate_channel
    from compd.offline.fit_terms import usable_rows

    usable = usable_rows(run)  # the span the loss saw: rows outside are not calibration
    y_span = float(np.ptp(y if usable is None else y[usable]))

    rel = [not all(is_rate_channel(ch) for ch in inputs) for _, inputs in specs]
    us = [joined([relative_input(r, inputs, rl) for r in records])
          for (_, inputs), rl in zip(specs, rel, strict=True)]
    holdout = None
    if holdout_records:
        h_y = np.concatenate([r.column(run.request.output) for r in holdout_records])
        h_us = tuple(np.concatenate([relative_input(r, inputs, rl) for r in holdout_records])
                     for (_, inputs), rl in zip(specs, rel, strict=True))
        holdout = Holdout(h_y, h_us, Segments.from_lengths([len(r) for r in holdout_records]))
    if run.request.structure == "search":
        try:
            fit = fit_tf_terms(y, us, run.request.orders, run.request.orders,
                               validation=run.request.validation, segments=seg, radius=radius,
                               holdout=holdout)
        except ValueError as exc:
            raise ModelError(f"identification failed: {exc}") from None
        summary = {"structure": "per-term-oe (greedy search)",
                   "validation_fit_percent": fit.oe_validation_fit_pct,
                   "arx_fit_percent": fit.arx_fit_pct, "oe_fit_percent": fit.oe.fit_pct}
        fitted = [FitTerm(n, inputs, u, tuple(num), tuple(den), rl) for (n, inputs), u, num,
                  den, rl in zip(specs, us, fit.oe.nums, fit.oe.dens, rel, strict=True)]
    else:
        from compd.offline.fit_blocks import judge_rows
        from compd.offline.fit_checks import CheckVeto, fallback_line
        from compd.offline.fit_select import select_for_fit, worse_than_none

        run.judge_rows = judge_rows(records)  # the inner blocks are cut from the speed
        veto = CheckVeto(specs, rel, [float(np.ptp(u)) for u in us], y_span, period)
        pool = run.search_pool
        try:
            fitted, summary = select_for_fit(run, y, us, seg, radius, holdout, specs, rel,
                                             pool, veto, veto.terms)
        except ModelError:
            if not veto.vetoed:
                raise
            if not run.force:
                raise ModelError(f"every candidate model gets a warning from compd check (the "
                                 f"first: {veto.vetoed[0]}); nothing written (--force writes "
                                 "the best validated anyway)") from None
            fitted, summary = select_for_fit(run, y, us, seg, radius, holdout, specs, rel,
                                             pool, None, veto.terms)
        else:
            line = fallback_line(summary, veto)
            if line is not None:
                print(line, file=sys.stderr)
        from compd.offline.fit_judge import fallback_line as judge_line
        from compd.offline.fit_select import judged, refused

        if holdout is None:  # the last word: inner held-out blocks of the calibration rows
            fitted, summary = judged(run, y, seg, radius, fitted, summary, veto.terms)
        said = judge_line(summary)
        if said is not None:
            print(said, file=sys.stderr)
        unsafe = refused(summary)
        if unsafe is not None and not run.force:
            raise ModelError(f"{unsafe}; nothing written (--force writes compd's choice "
                             "anyway)")
        if unsafe is not None:
            print(f"compd fit: warning: {unsafe}; compd's choice written all the same "
                  "(--force)", file=sys.stderr)
        # for the adaptation settings: how fast the error moves on rows not calibrated on
        run.heldout_residuals = summary.pop("_heldout_residuals")
        worse = worse_than_none(summary)
        if worse is not None and not run.force:
            raise ModelError(f"{worse}; not written (--force writes it anyway)")
        if worse is not None:
            print(f"compd fit: warning: {worse}; written all the same (--force)",
                  file=sys.stderr)
    terms: list[Term] = []
    info: list[dict[str, Any]] = []
    for ft in fitted:
        name, inputs, u, num, den, rl = ft.name, ft.inputs, ft.u, ft.num, ft.den, ft.relative
        nb, na = len(num), len(den) - 1
        check = build_checked_tf(num, den, name, max_pole=radius, period_s=period,
                                 input_span=float(np.ptp(u)), output_span=y_span)
        terms.append(Term(name=name, inputs=inputs, dynamics=check.tf, relative=rl))
        info.append({"name": name, "kind": "tf", "inputs": inputs, "relative": rl,
                     "orders": {"numerator_length": nb, "denominator_order": na},
                     "dc_gain_um_per_k": check.dc_gain,
                     "input_span": float(np.ptp(u)), "output_span_um": y_span,
                     "poles": [abs(p) for p in check.poles],
                     "sensitivity": check.sensitivity,
                     "arx_fit_percent": summary["arx_fit_percent"],
                     "oe_fit_percent": summary["oe_fit_percent"],
                     "oe_validation_fit_percent": summary["validation_fit_percent"],
                     "selection": summary})
    from models.diagnostics import cancelling_terms

    # terms on the same input (members of an averaged model) count once, with
    # their DC gains summed: their split was not estimated, it is the weights
    per_input: dict[str, tuple[str, Any, float]] = {}
    for ft, t in zip(fitted, info, strict=True):
        key = repr(sorted(ft.inputs.items()))
        name, u, gain = per_input.get(key, (ft.name, ft.u, 0.0))
        per_input[key] = (name, u, gain + t["dc_gain_um_per_k"])
    for w in cancelling_terms([v[0] for v in per_input.values()],
                              [v[1] for v in per_input.values()],
                              [v[2] for v in per_input.values()], y_span):
        print(f"compd fit: warning: {w}", file=sys.stderr)
    return terms, info


def identify_terms(run: FitRun, records: list[Record], ys: list[Any],
               specs: list[tuple[str, dict[str, float]]], holdout_records: list[Record],
               ) -> tuple[list[Term], list[dict[str, Any]]]:
    from models.compensation import Term
    from models.errors import ModelError

    if run.request.kind == "tf":  # the fitters below load scipy.optimize: only for them
        return _fit_tf(run, records, ys, specs, holdout_records)
    from models.greybox import GreyBox
    from models.identify.greybox_fit import fit_greybox
    from models.identify.mbotv_fit import fit_mbotv
    from models.mbotv import Mbotv

    if len(records) != 1 or holdout_records:
        raise ModelError(f"--kind {run.request.kind} fits one record; got {len(records)} (and "
                         f"{len(holdout_records)} validation record(s)); use --kind tf")
    record, y = records[0], ys[0]
    period = record.period_s
    terms: list[Term] = []
    info: list[dict[str, Any]] = []
    if len(specs) != 1:
        raise ModelError(f"--kind {run.request.kind} fits one term; got {len(specs)}")
    name, inputs = specs[0]
    if run.request.kind == "greybox":
        u1 = relative_input(record, inputs, False)
        u2 = record.column(run.request.switch) if run.request.switch else None
        gfit = fit_greybox(y, u1, period, u2)
        gb = GreyBox(list(gfit.p), period, name=name)
        terms.append(Term(name=name, inputs=inputs, dynamics=gb, relative=False,
                          switch_channel=run.request.switch))
        info.append({"name": name, "kind": "greybox", "inputs": inputs, "p": list(gfit.p),
                     "dc_gain": gb.dc_gain, "fit_percent": gfit.fit_pct})
        return terms, info
    T = relative_input(record, inputs, True)
    mfit = fit_mbotv(y, T, period)
    mb = Mbotv(alpha=mfit.alpha, beta=mfit.beta, k=mfit.k, gamma=mfit.gamma, period_s=period,
               delta=mfit.delta, name=name)
    terms.append(Term(name=name, inputs=inputs, dynamics=mb))
    info.append({"name": name, "kind": "mbotv", "inputs": inputs, "alpha": mfit.alpha,
                 "beta": mfit.beta, "k": mfit.k, "gamma": mfit.gamma,
                 "dc_gain_um_per_k": mfit.alpha, "fit_percent": mfit.fit_pct})
    return terms, info

