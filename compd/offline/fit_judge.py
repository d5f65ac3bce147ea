"""`compd fit`'s last word on the model it writes, judged on inner held-out
blocks of every kind (`compd.offline.fit_blocks`: interior heat/cool cycles,
cool-downs, the end of the calibration).

The structure choice and its hedge (`compd.offline.fit_select`,
`compd.offline.fit_hedge`) are judged on forward folds: every held-out block
is a later stretch at a speed the calibration has not seen. A machine also
runs at speeds between those calibrated and cools down from them, and a
choice that extrapolates upward well may predict those worse than no
compensation at all. So three candidates are judged once more:

- **compd's choice** (the chosen structure on its inputs, or the average
  the hedge wrote), re-estimated on the calibration rows less the block;
- **the textbook** ARX(2,3) on its pair (`models.identify.textbook`), the
  same way;
- **no model** (the displacement from each record's first row).

Each is run from the record's start, as the daemon runs it, and scored
(mean absolute error) only on the block's rows. On each block the best of the
three sets the yardstick (at least `FLOOR_SHARE` of the displacement's span,
so that a flat block does not decide everything); a candidate's figure is its
*worst* ratio to that over the blocks. With a finite `TIE` the smallest worst
wins ("never much worse" beats "best on one block"; within `TIE` of it the
first of compd's choice, the textbook, no model); by default (`TIE` infinite,
see there) compd's choice stands. Then the one safety rule: a model whose
error exceeds no compensation's by `WORSE_RATIO` (and by more than the floor)
on an interior cycle or cool-down (or an interior part of a record cut
without its speed) is not written; the textbook takes its place, judged on
every block, the end too, and when it fails as well, nothing is written. The
end (the last stretch, calibrated on all before it) does not refuse compd's
choice (`FORWARD_KINDS`): it is a later stretch at a speed not yet
calibrated, the kind of block the choice was made on (forward folds), whose
own check of "worse than no compensation" (`compd.offline.fit_select.
worse_than_none`) every written model passes; one more such block, alone and
at a speed above all the rest, judges compd's choice twice on what it was
chosen for and refused models that were better than none on the later rows.
A structure forced with ``--structure`` is not replaced by the textbook: it
is written or refused.

Then the lean: compd's choice, safe, still gives way when it does not beat
the textbook on the inner blocks (the geometric mean over the blocks of its
MAE over the textbook's above `LEAN_RATIO`): the average of the two
(`LEAN_TO`, `LEAN_WEIGHT` each) is written in its place, when that average
passes the safety rule on every block, the end too, and `compd check` (the
textbook itself is picked among the pairs `compd check` passes:
`models.identify.textbook.pick_pair`). The textbook is small and its pair is
picked on what follows its calibration; a choice among many inputs and
structures that loses to it on the calibration's own interior cycles and
cool-downs is the bet the issue's table shows does not carry over.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from compd.offline.fit_blocks import InnerBlock
from models.identify.output_error import OeModel
from models.identify.segments import Segments

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: a model is worse than no compensation on a block when its MAE there exceeds
#: no compensation's by this factor. Judged on the whole table of
#: benchmarks/bench_real_record.py (docs/calibration.md §7): at 1.1 as at 1.5
#: two held-out cells are left worse than no compensation (three before the
#: verdict), at 2 three; 1.5 refused fewer models that were better than none
#: on the later rows (ch5's geometric mean ratio to the textbook 1.10, 1.27
#: at 1.1)
WORSE_RATIO = 1.5
#: the kinds of inner block (`compd.offline.fit_blocks.InnerBlock.kind`) that
#: judge only the textbook in compd's choice's place, never compd's choice (see
#: the module docstring). Judged on the whole table of
#: benchmarks/bench_real_record.py (docs/calibration.md §7): ch5 fitted on the
#: rows outside 20.1-27.8 h was refused on its inner end (3750 rpm, MAE 17.0 µm
#: against 7.19 uncompensated) while it is 12.6 µm against 19.4 on those rows;
#: no cell the end alone refused was worse than none, and the two cells left
#: worse than none stay two
FORWARD_KINDS: frozenset[str] = frozenset({"end"})
#: the yardstick of a block is at least this share of the displacement's span
#: over the usable rows (a flat block's tiny error does not decide the choice)
FLOOR_SHARE = 0.02
#: candidates whose worst ratio is within this factor of the best one's are tied:
#: the first of compd's choice, the textbook, no model wins. Off (infinite: compd's
#: choice unless the safety rule refuses it) by the whole table of
#: benchmarks/bench_real_record.py: swapping a choice for the textbook because
#: its worst inner block was better, at 1.05 or at 1.5, left two held-out cells
#: worse than no compensation that compd's choice had not been (ch2 after
#: 12.1 h, ch3 on the 2500 rpm cycle) and raised the geometric mean ratio of
#: ch3 from 0.98 to 1.21: with two to six inner blocks, the smallest worst
#: ratio is as noisy a choice as the best fold
TIE = math.inf

#: compd's choice gives way when it does not beat the textbook on the inner
#: blocks by this much: when the geometric mean over the blocks of its MAE
#: over the textbook's (each at least the floor) exceeds this, the average of
#: the two (`LEAN_TO`) is written in its place, if that passes the safety rule
#: on every block. Judged on the whole table of
#: benchmarks/bench_real_record.py (docs/calibration.md §7; 40 cells): from
#: 0.4 to 0.6 no cell is worse than no compensation and the worst ratio per
#: channel is 0.79, 0.86, 2.82, 2.36, 1.90; at 0.7 and 1.0 one cell of ch5 is
#: worse than none (ch5's worst 2.29), at 0.3 one of ch1 (an average where
#: compd's choice alone is far better); never leaning leaves ch4 at 2.61, ch5
#: at 2.42 and one cell worse than none. 0.5: the middle of the plateau
LEAN_RATIO = 0.5
#: what is written when compd's choice gives way to the textbook: AVERAGE or
#: TEXTBOOK
LEAN_TO = "average with the textbook"
#: the textbook's weight in that average
LEAN_WEIGHT = 0.5

#: the candidates, in the order of preference on a tie
COMPD, TEXTBOOK, NONE = "compd's choice", "textbook", "no model"
#: compd's choice and the textbook averaged, (1 - `LEAN_WEIGHT`) and `LEAN_WEIGHT`
AVERAGE = LEAN_TO


@dataclass(frozen=True)
class Member:
    """One model of compd's choice (or the textbook), as it is re-estimated
    on a calibration that leaves a block out: its structure, its inputs (as
    fitted), its estimate on every usable row (orders and ridge λ are
    taken from it) and whether the initial conditions are estimated."""

    structure: str
    us: tuple[FloatArray, ...]
    model: OeModel
    initial: bool = False
    detail: str = ""
    #: the selection's own fold estimates by the key of their training rows
    #: (`models.identify.structures.Candidate.fold_models`): a block whose
    #: calibration is a fold's (the end block is the last forward fold's) takes
    #: that estimate, the very one `refit` would make again
    folds: tuple[tuple[bytes, OeModel | None], ...] = field(default=(), repr=False)


@dataclass
class Verdict:
    #: COMPD, TEXTBOOK or NONE: what is written
    chosen: str
    #: the inner blocks' names and each candidate's MAE there (nan: no model)
    blocks: list[str]
    mae: dict[str, list[float]]
    #: each candidate's worst ratio to the best of the block
    worst: dict[str, float]
    #: why the choice is not compd's (empty when it is)
    reasons: list[str] = field(default_factory=list)
    #: the least yardstick of a block, µm (`FLOOR_SHARE` of the displacement's span)
    floor: float = 0.0
    #: each block's kind (`compd.offline.fit_blocks.InnerBlock.kind`)
    kinds: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        return {"chosen": self.chosen, "blocks": self.blocks,
                "mae_um": {k: [v if math.isfinite(v) else None for v in vs]
                           for k, vs in self.mae.items()},
                "worst_ratio": {k: v if math.isfinite(v) else None
                                for k, v in self.worst.items()},
                "reasons": self.reasons, "floor_um": self.floor, "kinds": self.kinds}


#: `refit`'s marker of rows that are no fold's training rows
_NOT_A_FOLD = object()


def refit(y: FloatArray, seg: Segments, radius: float, usable: BoolArray | None,
          member: Member, train: BoolArray) -> FloatArray | None:
    """`member` re-estimated on the `train` rows and run over every row from
    each record's start (initial conditions fitted on `train` when the
    member estimates them); None when that estimate is unstable. Each is
    estimated by the selection's own chain from the least squares (ARX,
    Steiglitz–McBride, shared-oe, then per-term-oe or ridge at its λ alone):
    started from its estimate on every row instead, which has seen the
    block, the ridge of ch5 calibrated without the 2500 rpm cycle of
    benchmarks/bench_real_record.py fell into a basin that predicts its inner
    3750 rpm cycle better than the chain's (it was written, 33.6 µm MAE on
    the held-out cycle against 25.5 µm uncompensated, where the chain's
    verdict refused it)."""
    from models.identify.estimators import _fold_models, _ridge, _static_fit, arx_fit
    from models.identify.fold_data import _Data, rows_key
    from models.identify.fold_scores import _simulate
    from models.identify.textbook import TEXTBOOK_ORDERS
    from models.identify.validate import forced_response

    d = _Data(y, list(member.us), seg, radius, [], initial=member.initial, usable=usable)
    m: OeModel | None
    if member.folds and member.structure != "textbook":
        key = rows_key(train)
        done = next((fm for k, fm in member.folds if k == key), _NOT_A_FOLD)
        if done is not _NOT_A_FOLD:
            m = done if isinstance(done, OeModel) else None
            return None if m is None else _simulate(d, m, train, y, d.us, seg)
    if member.structure == "textbook":
        d.initial = False
        m = arx_fit(d, *TEXTBOOK_ORDERS, train)
        if m is None:
            return None
        return forced_response(m.nums, m.dens, m.groups, d.us, seg)
    na, nb = len(member.model.dens[0]) - 1, len(member.model.nums[0])
    if member.structure == "static":
        m = _static_fit(d, train)
    elif member.structure == "arx":
        m = arx_fit(d, na, nb, train)
    elif member.structure == "ridge":  # its own λ only, on the chain's shared-oe
        shared = _fold_models(d, na, nb, train, ("shared-oe",), 40).get("shared-oe")
        m = _ridge(d, shared, train, float(member.detail.rpartition("= ")[2]))
    else:
        m = _fold_models(d, na, nb, train, (member.structure,), 40).get(member.structure)
    if m is None:
        return None
    return _simulate(d, m, train, y, d.us, seg)


def lone_textbook(d: Any, candidates: Sequence[FloatArray],
                  veto: Callable[[tuple[int, ...], OeModel], str | None] | None = None
                  ) -> tuple[tuple[int, ...], OeModel] | None:
    """(pair, estimate on every usable row) of the textbook ARX(2,3)
    (`models.identify.textbook`, its pair one `veto` passes) where its forward
    folds gave none: the verdict re-estimates it on each calibration less a
    block itself."""
    from models.identify.estimators import arx_fit
    from models.identify.textbook import TEXTBOOK_ORDERS, _data, pick_pair

    pair = pick_pair(d, candidates, veto)
    if pair is None:
        return None
    m = arx_fit(_data(d, [candidates[i] for i in pair]), *TEXTBOOK_ORDERS, d.every)
    return None if m is None else (pair, m)


def _mae(y: FloatArray, sim: FloatArray | None, rows: BoolArray) -> float:
    if sim is None:
        return math.nan
    v = float(np.mean(np.abs(y[rows] - sim[rows])))
    return v if math.isfinite(v) else math.nan


def judge(y: FloatArray, seg: Segments, radius: float, usable: BoolArray | None,
          blocks: Sequence[InnerBlock], choice: Sequence[tuple[Member, float]],
          textbook: Member | None, forced: bool = False,
          progress: Callable[[str], None] | None = None) -> Verdict | None:
    """The verdict (module docstring) on `blocks`, compd's `choice` a weighted
    sum of members; None without a block to judge on."""
    if not blocks:
        return None
    use = np.ones(seg.total, dtype=bool) if usable is None else usable
    start = np.concatenate([np.full(e - s, y[s]) for s, e in seg.bounds])
    floor = FLOOR_SHARE * float(np.ptp(y[use]))
    names = [COMPD, *([TEXTBOOK, AVERAGE] if textbook is not None else []), NONE]
    mae: dict[str, list[float]] = {n: [] for n in names}
    for b in blocks:
        if progress is not None:
            progress(b.name)
        train = use & ~b.rows
        # the weighted sum of the members' runs, summed in place (a month at 1 s:
        # 21 MB a run); one member of weight 1 is its own run
        total: FloatArray | None = None
        for member, w in choice:
            sim = refit(y, seg, radius, usable, member, train)
            if sim is None:
                total = None
                break
            part = sim if w == 1.0 else w * sim
            total = part if total is None else np.add(total, part, out=total)
            del sim, part
        mae[COMPD].append(_mae(y, total, b.rows))
        if textbook is not None:
            tb = refit(y, seg, radius, usable, textbook, train)
            mae[TEXTBOOK].append(_mae(y, tb, b.rows))
            both = None if total is None or tb is None else \
                (1.0 - LEAN_WEIGHT) * total + LEAN_WEIGHT * tb
            mae[AVERAGE].append(_mae(y, both, b.rows))
            del tb, both
        del total
        mae[NONE].append(_mae(y, start, b.rows))
    return decide(mae, [b.name for b in blocks], floor, forced, TIE, WORSE_RATIO,
                  [b.kind for b in blocks], FORWARD_KINDS, LEAN_RATIO, LEAN_TO)


def lean_score(mae: dict[str, list[float]], floor: float) -> float:
    """The geometric mean over the blocks of compd's choice's MAE over the
    textbook's, each at least `floor` (a block where either has no stable
    estimate is left out); nan without a textbook or such a block."""
    if TEXTBOOK not in mae:
        return math.nan
    logs = [math.log(max(c, floor, 1e-12) / max(t, floor, 1e-12))
            for c, t in zip(mae[COMPD], mae[TEXTBOOK], strict=True)
            if math.isfinite(c) and math.isfinite(t)]
    return math.exp(sum(logs) / len(logs)) if logs else math.nan


def decide(mae: dict[str, list[float]], blocks: list[str], floor: float, forced: bool = False,
           tie: float = TIE, worse_ratio: float = WORSE_RATIO, kinds: list[str] | None = None,
           forward: frozenset[str] = FORWARD_KINDS, lean_ratio: float = LEAN_RATIO,
           lean_to: str = LEAN_TO) -> Verdict:
    """The verdict from each candidate's MAE per block (module docstring);
    `floor`: the least yardstick of a block, µm; `kinds`: each block's kind
    (None: none of `forward`), those of `forward` judging only the textbook;
    `lean_ratio`, `lean_to`: when compd's choice gives way to the textbook
    (`LEAN_RATIO`; inf: never) and to what."""
    names = [n for n in mae if n != AVERAGE]  # the average is a way out, not a rival
    worst: dict[str, float] = {}
    for n in names:
        ratios = []
        for k in range(len(blocks)):
            best = min((mae[c][k] for c in names if math.isfinite(mae[c][k])), default=math.nan)
            ref = max(best, floor, 1e-12)
            ratios.append(mae[n][k] / ref if math.isfinite(mae[n][k]) else math.inf)
        worst[n] = max(ratios)
    kinds = list(kinds) if kinds is not None else ["interior"] * len(blocks)
    verdict = Verdict(COMPD, list(blocks), mae, worst, floor=floor, kinds=kinds)
    lead = min(worst.values())
    # an infinite tie keeps every candidate (inf × a worst of 0 would be nan)
    order = [COMPD] if forced else [n for n in names if math.isinf(tie) or
                                    worst[n] <= lead * tie]
    pick = order[0]
    if pick != COMPD:
        verdict.reasons.append(
            f"{pick} has the smallest worst ratio to the best on each block "
            f"({worst[pick]:.2f}, compd's choice {worst[COMPD]:.2f})")
    for cand in ([pick, TEXTBOOK] if pick == COMPD and not forced and TEXTBOOK in mae
                 else [pick]):
        if cand == NONE:
            pick = NONE
            break
        judged = [k for k, kind in enumerate(kinds) if cand != COMPD or kind not in forward]
        bad = _worse_than_none([mae[cand][k] for k in judged], [mae[NONE][k] for k in judged],
                               floor, [blocks[k] for k in judged], worse_ratio)
        if bad is None:
            pick = cand
            break
        verdict.reasons.append(f"{cand} is worse than no compensation on {bad}")
        pick = NONE
    score = lean_score(mae, floor)
    if pick == COMPD and not forced and lean_to in mae and score > lean_ratio:
        every = list(range(len(blocks)))
        bad = _worse_than_none([mae[lean_to][k] for k in every], [mae[NONE][k] for k in every],
                               floor, blocks, worse_ratio)
        if bad is None:
            pick = lean_to
            verdict.reasons.append(
                f"compd's choice does not beat the textbook on the inner blocks by enough (its "
                f"MAE is {score:.2f}x the textbook's, geometric mean over {len(blocks)} blocks; "
                f"alone at most {lean_ratio:.2f}x)")
    verdict.chosen = pick
    return verdict


def _worse_than_none(mine: list[float], none: list[float], floor: float,
                     names: list[str], worse_ratio: float = WORSE_RATIO) -> str | None:
    """The first block where `mine` exceeds no compensation by `WORSE_RATIO`
    (and by more than the floor), said with both figures; None when there is none."""
    for m, n, name in zip(mine, none, names, strict=True):
        if not math.isfinite(m) or (m > worse_ratio * n and m - n > floor):
            fig = f"MAE {m:.3g} µm" if math.isfinite(m) else "no stable estimate"
            return f"the inner block {name} ({fig} against {n:.3g} µm uncompensated)"
    return None


def verdict_lines(summary: dict[str, Any]) -> list[str]:
    """What `compd fit` prints about the verdict (the summary's ``judge``)."""
    v = summary.get("judge")
    if not v:
        return []
    mae: dict[str, list[float | None]] = v["mae_um"]
    worst: dict[str, float | None] = v["worst_ratio"]
    out = [f"  judged on {len(v['blocks'])} inner held-out blocks (each left out of the "
           "calibration in turn, every model run from the record's start), MAE µm "
           + " / ".join(mae) + "; worst ratio to the best of each block: "
           + ", ".join(f"{k} {w:.2f}" if w is not None else f"{k} -"
                       for k, w in worst.items())]
    for k, name in enumerate(v["blocks"]):
        out.append(f"    {name}: " + " / ".join(
            f"{vs[k]:.2f}" if vs[k] is not None else "-" for vs in mae.values()))
    if v["chosen"] == COMPD and not v["reasons"]:
        out.append("  written: compd's choice")
    elif v["chosen"] == COMPD:
        out.append("  written: compd's choice (" + "; ".join(v["reasons"]) + ")")
    else:
        what = summary["structure"] if v["chosen"] in (TEXTBOOK, AVERAGE) else "nothing"
        out.append(f"  written: {what} (" + "; ".join(v["reasons"]) + ")")
    return out


def fallback_line(summary: dict[str, Any]) -> str | None:
    """The one line on stderr when the verdict wrote the textbook (or the
    average with it) instead of compd's choice, else None."""
    v = summary.get("judge")
    if not v or v["chosen"] not in (TEXTBOOK, AVERAGE):
        return None
    return (f"compd fit: fell back to {summary['structure']}: " + "; ".join(v["reasons"])
            + f" (judged on {', '.join(v['blocks'])})")
