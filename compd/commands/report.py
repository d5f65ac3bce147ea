"""`compd report MODEL RECORD… -o report.html [--column dz_um]
[--held-out-from SECONDS] [--force]`

One self-contained HTML page (style inline, figures inline SVG, no script,
nothing fetched) that shows a calibration as an engineer judges it and hands
it on: each record (temperatures, speed, displacement) with the model's
prediction and the residue, its calibration and held-out windows marked, the
figures per window, the structure choice and its runners-up as the model's
provenance holds them (and how stable the choice was, or "not recorded"),
each term's step response on one scale per input unit, the poles with their
time constants, ISO 230-3's drift and ETVE figures, and the provenance
(compd version, command, record hashes). The model runs over each record as
`compd replay` runs it (initial state estimated). The page is written as
every output file is (`compd.outfiles`: checked before the work, never over
an input, atomically, replaced only with --force).
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compd.argtypes import number
from compd.sysexits import EX_DATAERR, EX_USAGE

if TYPE_CHECKING:
    from compd.offline.report import RecordResult
    from compd.offline.report_page import Cell, Page
    from models.compensation import CompensationModel

HELP = ("write a calibration report: one self-contained HTML page with a model's figures on "
        "records, its validation, step responses, poles, ISO 230-3 drift and provenance")

#: records in one report at most (each adds two figures)
MAX_RECORDS = 12


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file, or a library name (sp2)")
    parser.add_argument("records", metavar="RECORD", nargs="+",
                        help="calibration and/or verification records (CSV or a compd "
                             "recorder .db): one whose SHA-256 the model's provenance lists "
                             "is marked calibration, any other held out")
    parser.add_argument("-o", dest="output", metavar="REPORT.html", required=True,
                        help="the page to write")
    parser.add_argument("--column", default=None, metavar="COLUMN",
                        help="the measured displacement column (µm); default: the one the "
                             "model's provenance names in its fit command, else dz_um")
    parser.add_argument("--held-out-from", type=number(0.0, 1e9), default=None,
                        metavar="SECONDS",
                        help="in a record the fit did not read whole: the rows before this "
                             "time are marked calibration, the rest held out, each scored")
    parser.add_argument("--force", action="store_true", help="replace an existing REPORT.html")


def _column(args: argparse.Namespace, provenance: dict[str, Any]) -> str:
    if args.column is not None:
        return str(args.column)
    try:
        words = shlex.split(str(provenance.get("command_line", "")))
    except ValueError:
        words = []
    for flag in ("--column", "--output"):
        if flag in words[:-1]:
            return words[words.index(flag) + 1]
    return "dz_um"


def run(args: argparse.Namespace) -> int:
    from compd.infiles import load_model
    from compd.offline.records import RecordError, check_units, read_record
    from compd.outfiles import check_output, write_atomically
    from models.errors import ModelError

    if len(args.records) > MAX_RECORDS:
        print(f"compd report: {len(args.records)} records; at most {MAX_RECORDS} in one report",
              file=sys.stderr)
        return EX_USAGE
    inputs = [args.model, *args.records]
    out = check_output(args.output, "report", force=args.force, inputs=inputs)
    if out.suffix.lower() not in (".html", ".htm"):
        print(f"compd report: {out}: the report is an HTML page; name it .html",
              file=sys.stderr)
        return EX_USAGE
    try:
        model = load_model(args.model)
        provenance = dict(model.provenance or {})
        column = _column(args, provenance)
        from compd.offline.model_replay import replay_with_init
        from compd.offline.report import RecordResult, record_role, score

        results: list[RecordResult] = []
        for path in args.records:
            record = read_record(path)
            record.require([column, *sorted(model.channels)])
            check_units(record, sorted(model.reference_channels), column)
            measured = record.columns[column]
            simulated = replay_with_init(model, record, measured, "estimate")
            role = record_role(record, provenance)
            results.append(RecordResult(record, role, simulated, measured,
                                        score(record, measured, simulated, role,
                                              args.held_out_from)))
    except (RecordError, ModelError) as exc:
        print(f"compd report: {exc}", file=sys.stderr)
        return EX_DATAERR
    page = build_page(args, model, results, column)
    text = page.render()
    write_atomically(out, lambda tmp: tmp.write_text(text, encoding="utf-8"), "report",
                     force=args.force, inputs=inputs)
    print(f"compd report: {len(results)} record(s), model {model.name!r}: wrote {out}")
    return 0


def build_page(args: argparse.Namespace, model: CompensationModel,
               results: list[RecordResult], column: str) -> Page:
    """Every section of the page, in the order an engineer reads them."""
    from compd import __version__
    from compd.commands.step import auto_span_s, step_responses
    from compd.offline.plots import build_replay_figure, build_step_figure
    from compd.offline.report import (
        file_sha256,
        hash_rows,
        iso_figures,
        provenance_rows,
        summary_rows,
        thin,
        validation_section,
        window_legend,
    )
    from compd.offline.report_figures import build_drift_figure
    from compd.offline.report_page import Page, cell
    from compd.offline.report_svg import figure_svg

    prov = dict(model.provenance or {})
    page = Page(f"compd calibration report: {model.name}")
    page.heading(f"Calibration report: {model.name}", 1)
    page.note(f"Model {args.model} (period {model.period_s:g} s, {len(model.terms)} term(s)), "
              f"judged on {len(results)} record(s), displacement column {column}. Written "
              f"{datetime.now(UTC).isoformat(timespec='seconds')} by compd {__version__}.")
    page.heading("Figures per record and window", anchor="summary")
    page.table(["record", "window", "time", "samples", "fit %", "MAE µm", "RMS µm",
                "residue min … max µm", "Δpk µm", "range reduction"], summary_rows(results))
    page.note("Judge the model on the held-out rows: a model always looks better on the "
              "rows it was fitted to. The model runs over each whole record from an estimated "
              "initial state (as compd replay does); each window is scored on its own rows.")
    window_legend(page)
    for i, r in enumerate(results):
        step = thin(len(r.record))
        inputs = {c: r.record.columns[c][step] for c in r.record.columns
                  if c in model.channels or _is_speed(c)}
        n = len(r.record.time_s[step])
        fig = build_replay_figure(
            r.record.time_s[step], inputs, r.measured[step], r.simulated[step],
            title=f"{Path(r.record.path).name}: {r.role}",
            windows=[w.window for w in r.windows])
        page.heading(f"{Path(r.record.path).name} ({r.role})", 3)
        drawn = "" if n == len(r.record) else f" Drawn at one sample in {step.step}."
        page.figure(figure_svg(fig, f"rec{i}"),
                    "Above: the inputs (temperatures °C, spindle speed dashed). Below: the "
                    "measured displacement, the model's prediction and the residue left after "
                    f"compensation; the title's figures are the whole record's.{drawn}")
    page.heading("Each term's step response", anchor="steps")
    span_n = max(2, int(auto_span_s(model) / model.period_s) + 1)
    t, responses, units, gains = step_responses(model, span_n)
    page.figure(figure_svg(build_step_figure(t, responses, units,
                                             title=f"{model.name}: step response per term",
                                             dc_gains=gains), "step"),
                "The response of each term to a step of one unit of its input, all terms of "
                "one unit on one scale: terms that oppose show as such.")
    page.heading("Poles and time constants", anchor="poles")
    page.table(["term", "pole", "|p|", "time constant"], poles_rows(model))
    page.note("τ = −Ts / ln|p| for a pole with a positive real part; a pole with a negative "
              "real part alternates sign and has none.")
    validation_section(page, prov)
    page.heading("ISO 230-3: drift over the run and environmental variation error",
                 anchor="iso")
    iso = [iso_figures(r, model) for r in results]
    page.table(["record", "hours", "δZ drift max / min µm", "drift range µm",
                "largest at", "with compensation µm", "ETVE µm", "ETV K",
                "ETVE compensated µm"],
               [[cell(Path(r.record.path).name, css="name"), cell(f["hours"], ".3g"),
                 cell(f"{f['drift_max_um']:.2f} / {f['drift_min_um']:.2f}"),
                 cell(f["drift_range_um"], ".2f"), cell(f"{f['drift_at_h']:.3g} h"),
                 cell(f["residue_range_um"], ".2f"),
                 *([cell(f["etve_um"], ".2f"), cell(f["etv_k"], ".2f"),
                    cell(f["etve_compensated_um"], ".2f")] if f["etve"] is None
                   else [cell(f["etve"], css="missing"), cell(None), cell(None)])]
                for r, f in zip(results, iso, strict=True)])
    page.note("Drift: δZ from the run's first sample (ISO 230-3's thermal distortion over the "
              "run); ETVE: the range of δZ over an environmental run (the spindle at rest) "
              "beside the range of the room temperature (ETV).")
    page.figure(figure_svg(build_drift_figure(results, iso), "drift"),
                "The drift over each run without and with compensation (dotted: its largest "
                "excursion each way).")
    page.heading("Provenance", anchor="provenance")
    model_hash = file_sha256(args.model)
    page.table(["", ""], [
        [cell("report written by"), cell(f"compd {__version__}")],
        [cell("report command"), cell(_command_line(args), css="mono")],
        [cell("model file"), cell(args.model, css="mono")],
        [cell("model file SHA-256"), cell(model_hash or "a bundled model", css="mono")],
        [cell("model fitted by"), cell(f"compd {prov['compd_version']}"
                                       if "compd_version" in prov else "not recorded")]])
    page.heading("Records", 3)
    page.table(["record", "SHA-256", "in the model's provenance"], hash_rows(results, prov))
    page.heading("The model file's provenance", 3)
    if prov:
        page.table(["key", "value"], provenance_rows(prov))
    else:
        page.note("not recorded (the model file has no [provenance])", "note missing")
    return page


def poles_rows(model: CompensationModel) -> list[list[Cell]]:
    """Each term's poles with |p| and the time constant (as `compd check` says it)."""
    from compd.offline.model_description import (
        describe_model,
        duration_text,
        pole_time_constant_samples,
    )
    from compd.offline.report_page import cell

    rows = []
    report = describe_model(model)
    for t in report["terms"]:
        for re_, im in t["poles"]:
            tau = pole_time_constant_samples([re_, im])
            body = f"{re_:.7g}" if abs(im) < 1e-15 else f"{re_:.6g} {im:+.6g}j"
            if tau is not None:
                tau_text = f"{tau:.3g} samples = {duration_text(tau * model.period_s)}"
            elif re_ < 0.0:
                tau_text = "none: negative real part (alternates sign)"
            else:
                tau_text = "—"
            rows.append([cell(t["name"], css="name"), cell(body), cell(math.hypot(re_, im),
                                                                       ".6f"),
                         cell(tau_text)])
    return rows


def _is_speed(column: str) -> bool:
    from compd.offline.channel_kind import ChannelKind, channel_kind

    return channel_kind(column) is ChannelKind.SPEED


def _command_line(args: argparse.Namespace) -> str:
    if sys.argv[1:2] == ["report"]:
        return shlex.join(["compd", *sys.argv[1:]])
    return shlex.join(["compd", "report", args.model, *args.records, "-o", args.output])
