"""`compd fit`'s structure choice: the cross-validated selection of
`models.identify.structures` composed with the command's arguments, and the
summary the command prints and writes as provenance."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from compd.offline.fit_terms import FitTerm, usable_rows
from models.errors import ModelError
from models.identify.segments import Segments
from models.identify.structures import (
    DEFAULT_VALIDATION,
    STRUCTURES,
    Selection,
    select_structure,
)

if TYPE_CHECKING:
    from compd.offline.fit_request import FitRun

FloatArray = npt.NDArray[np.float64]

#: how `compd fit` names each validation scheme
VALIDATION_WORDS = {"blocked": "blocked cross-validation",
                    "forward": "forward validation (each block predicted from the rows before it)",
                    "both": "blocked and forward validation pooled"}


def run_selection(args: FitRun, y: FloatArray, us: list[FloatArray], seg: Segments,
                  radius: float, holdout: Any, names: list[str] | None = None,
                  veto: Any = None) -> Selection:
    """The selection for `--structure` (auto: every structure), on the usable
    rows (`usable_rows`); `veto`: why a candidate must not be chosen (`compd
    fit`: a model `compd check` warns about)."""
    structures = STRUCTURES if args.request.structure == "auto" else ("arx", args.request.structure)
    if args.folds < 2:
        raise ModelError(f"--folds {args.folds}: cross-validation needs at least 2 folds")
    h = None if holdout is None else (holdout.y, list(holdout.inputs), holdout.segments)
    try:
        return select_structure(y, us, na_range=args.request.orders, nb_range=args.request.orders,
                                segments=seg, radius=radius, folds=args.folds,
                                structures=structures, holdout=h, names=names,
                                usable=usable_rows(args), veto=veto)
    except ValueError as exc:
        raise ModelError(f"identification failed: {exc}") from None


def _finite(x: float) -> float | None:
    """x, or None where JSON and TOML have no value (nan, inf)."""
    return x if math.isfinite(x) else None


def summarise(sel: Selection, forced: str, how: str) -> dict[str, Any]:
    """What fit prints and writes: the chosen structure, its validation
    figure, the runners-up, and notes (a forced structure below the ARX
    baseline is said)."""
    chosen = sel.chosen
    if forced not in ("auto", "arx"):
        chosen = next((c for c in sel.candidates if c.structure == forced), chosen)
    notes = list(sel.notes) if forced == "auto" else []
    if chosen.rejected and forced != "auto":
        notes.append(f"warning: {chosen.structure} is implausible: {chosen.rejected}")
    base = sel.baseline
    if base is not None and not base.rejected and \
            chosen.validation_fit_pct < base.validation_fit_pct:
        notes.append(f"warning: {chosen.structure} validates at {chosen.validation_fit_pct:.2f} "
                     f"%, below the ARX least-squares baseline ({base.validation_fit_pct:.2f} "
                     "%)")
    oe_fits = [c.fit_pct for c in sel.candidates if c.structure != "arx"]
    return {
        "structure": chosen.structure + (f" ({chosen.detail})" if chosen.detail else ""),
        "orders": {"denominator_order": sel.orders[0], "numerator_length": sel.orders[1]},
        "initial_conditions": "estimated" if sel.initial else "rest",
        "validation": how,
        "validation_fit_percent": chosen.validation_fit_pct,
        "fold_fit_percent": list(chosen.fold_fits),
        "heldout_rms_um": _finite(chosen.heldout_rms),
        "displacement_rms_um": _finite(chosen.displacement_rms),
        "arx_fit_percent": base.fit_pct if base is not None else None,
        "oe_fit_percent": max(oe_fits) if oe_fits else chosen.fit_pct,
        "candidates": [{"structure": c.structure, "validation_fit_percent":
                        c.validation_fit_pct, "fit_percent": c.fit_pct,
                        "parameters": c.n_params, **({"detail": c.detail} if c.detail else {}),
                        **({"rejected": c.rejected} if c.rejected else {})}
                       for c in sel.candidates],
        "notes": notes,
        "_model": chosen.model,
        "_heldout_residuals": chosen.heldout_residuals,
    }


def worse_than_none(summary: dict[str, Any]) -> str | None:
    """Why the chosen model must not reach a machine (its residue on rows it
    was not calibrated on exceeds the displacement itself there), or None."""
    err, disp = summary.get("heldout_rms_um"), summary.get("displacement_rms_um")
    if err is None or disp is None or err <= disp:
        return None
    return (f"the model's error on rows it was not calibrated on (RMS {err:.3g} µm, "
            f"{summary['validation']}) exceeds the displacement itself there (RMS {disp:.3g} "
            "µm): compensation would make the machine worse")


def select_for_fit(args: FitRun, y: FloatArray, us: list[FloatArray],
                   seg: Segments, radius: float, holdout: Any,
                   specs: list[tuple[str, dict[str, float]]], rel: list[bool],
                   pool: dict[str, FloatArray] | None = None, veto: Any = None,
                   check: Callable[[list[FitTerm]], str | None] | None = None
                   ) -> tuple[list[FitTerm], dict[str, Any]]:
    """(terms, summary) of the chosen model: the chosen structure on the
    inputs of `specs`, or, when that choice is not stable across resampled
    held-out blocks, the leading candidates averaged (`compd.offline.
    fit_hedge`; the textbook ARX on a pair of `pool`, temperatures relative to
    their first sample, is always one of them). `veto` refuses a candidate of
    the selection, `check` a member of the average and the average itself
    (`compd fit`: a model `compd check` warns about). The summary's
    ``_heldout_residuals`` (the residue on the rows each fold's model was not
    calibrated on, arrays) is for the caller to take out before the summary is
    written anywhere."""
    from compd.offline.fit_hedge import hedge_choice, pool_textbook

    names = [n for n, _ in specs]
    if pool is None:  # the textbook's pair among the single sensors given, by channel
        pool = {next(iter(inputs)): u for (_, inputs), u, r in zip(specs, us, rel, strict=True)
                if r and list(inputs.values()) == [1.0]}
    # the textbook before the selection: its arrays are let go before the
    # candidates' held-out residues are made (`compd.offline.fit_hedge.pool_textbook`)
    pooled = pool_textbook(args, y, seg, radius, pool, check) if holdout is None else None
    sel = run_selection(args, y, us, seg, radius, holdout, names, veto)
    how = "held-out records" if holdout is not None else \
        f"{VALIDATION_WORDS[DEFAULT_VALIDATION]}, {args.folds} folds"
    summary = summarise(sel, args.request.structure, how)
    model = summary.pop("_model")
    terms = [FitTerm(n, inputs, u, num, den, r) for (n, inputs), u, num, den, r
             in zip(specs, us, model.nums, model.term_dens(), rel, strict=True)]
    if holdout is not None:
        return terms, summary
    return hedge_choice(args, y, seg, radius, sel, specs, us, rel, pool, terms, summary, check,
                        pooled)


def judged(args: FitRun, y: FloatArray, seg: Segments, radius: float,
           terms: list[FitTerm], summary: dict[str, Any],
           check: Callable[[list[FitTerm]], str | None] | None = None
           ) -> tuple[list[FitTerm], dict[str, Any]]:
    """(terms, summary) after the inner held-out blocks' verdict
    (`compd.offline.fit_judge`): compd's choice, or the textbook (or the
    average of the two) in its place (its forward-fold residue then the
    summary's), or compd's choice with the summary's ``judge`` saying that
    nothing may be written (`refused`). `check(terms)`: why the average must
    not be written (`compd fit`: `compd check`'s warnings); compd's choice is
    written then."""
    from compd.offline.fit_blocks import inner_blocks
    from compd.offline.fit_hedge import _merge, term_orders
    from compd.offline.fit_judge import AVERAGE, COMPD, LEAN_WEIGHT, TEXTBOOK, judge

    plan = summary.pop("_judge", None)
    if plan is None:
        return terms, summary
    # compd's choice before the verdict and the textbook, for a caller that
    # measures what the verdict changed (benchmarks/bench_real_record.py)
    args.unjudged_terms = terms
    args.judged_textbook_terms = plan["textbook"]["terms"] if plan["textbook"] else None
    usable = usable_rows(args)
    speed, time_s = args.judge_rows or (None, None)
    blocks = inner_blocks(seg, usable, speed, time_s)
    tb = plan["textbook"]
    verdict = judge(y, seg, radius, usable, blocks, plan["choice"],
                    tb["member"] if tb is not None else None,
                    forced=args.request.structure != "auto")
    if verdict is None:
        return terms, summary
    summary["judge"] = verdict.as_dict()
    args.judge_verdict = summary["judge"]
    if verdict.chosen not in (TEXTBOOK, AVERAGE) or tb is None:
        return terms, summary
    blocks_r = tb["residuals"]
    if verdict.chosen == AVERAGE:
        w = LEAN_WEIGHT
        both = _merge([FitTerm(t.name, t.inputs, t.u, tuple((1.0 - w) * v for v in t.num),
                               t.den, t.relative) for t in terms]
                      + [FitTerm(t.name, t.inputs, t.u, tuple(w * v for v in t.num), t.den,
                                 t.relative) for t in tb["terms"]])
        flag = check(both) if check is not None else None
        if flag:  # the average is a model of its own: it must pass the check too
            summary["judge"]["chosen"] = COMPD
            summary["judge"]["reasons"].append(
                f"not averaged, compd check would warn about the average: {flag}")
            return terms, summary
        mine = summary.get("_heldout_residuals") or ()
        # the average's residue on the folds' held-out rows is the same average of
        # theirs; a textbook without fold estimates leaves none
        blocks_r = tuple((1.0 - w) * a + w * b for a, b in zip(mine, blocks_r, strict=True)) \
            if len(mine) == len(blocks_r) and all(
                a.size == b.size for a, b in zip(mine, blocks_r, strict=True)) else ()
        count = sum(r.size for r in blocks_r)
        rms = math.sqrt(sum(float(np.sum(r ** 2)) for r in blocks_r) / count) if count else None
        disp = summary.get("displacement_rms_um")
        if rms is not None and disp is not None and rms > disp:
            # the average would be refused as worse than none on the folds' held-out
            # rows (`worse_than_none`), where compd's choice alone passed: the choice
            summary["judge"]["chosen"] = COMPD
            summary["judge"]["reasons"].append(
                f"not averaged, the average's error on the rows the folds held out (RMS "
                f"{rms:.3g} µm) exceeds the displacement itself there (RMS {disp:.3g} µm)")
            return terms, summary
        summary["structure"] = (f"average of compd's choice ({summary['structure']}) ×"
                                f"{1.0 - w:.2f}, {tb['label']} ×{w:.2f}")
        out = both
    else:
        summary["structure"] = tb["label"]
        summary["initial_conditions"] = "rest"
        out = list(tb["terms"])
    count = sum(r.size for r in blocks_r)
    summary["_heldout_residuals"] = blocks_r
    summary["heldout_rms_um"] = math.sqrt(sum(float(np.sum(r ** 2)) for r in blocks_r)
                                          / count) if count else None
    summary["orders"] = term_orders(out)
    return out, summary


def refused(summary: dict[str, Any]) -> str | None:
    """Why nothing may be written after the inner blocks' verdict, or None."""
    from compd.offline.fit_judge import NONE

    v = summary.get("judge")
    if not v or v["chosen"] != NONE:
        return None
    return ("no model is safer than no compensation on the calibration's inner held-out "
            "blocks: " + "; ".join(v["reasons"]))


def selection_lines(summary: dict[str, Any]) -> list[str]:
    """The lines `compd fit` prints about the choice."""
    out = [f"  structure {summary['structure']} (validation {summary['validation_fit_percent']:.2f}"
           f" %, {summary['validation']}; orders: denominator "
           f"{summary['orders']['denominator_order']}, numerator length "
           f"{summary['orders']['numerator_length']}; start of each record: "
           f"{summary['initial_conditions']})"]
    for c in summary["candidates"]:
        out.append(f"    {c['structure']:<12} validation {c['validation_fit_percent']:8.2f} %  "
                   f"fit {c['fit_percent']:6.2f} %  {c['parameters']} parameters "
                   f"{c.get('detail', '')}".rstrip()
                   + (f"  (rejected: {c['rejected']})" if c.get("rejected") else ""))
    err, disp = summary.get("heldout_rms_um"), summary.get("displacement_rms_um")
    if err is not None and disp is not None:
        out.append(f"  on rows it was not calibrated on: residue RMS {err:.3f} µm against the "
                   f"displacement's {disp:.3f} µm without compensation")
    out += [f"  {n}" for n in summary["notes"]]
    return out
