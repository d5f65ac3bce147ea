"""`compd refine MODEL PROBES -o OUT.toml [--force] [--json]`

The model's `[adaptation]` settings refined from the probes a running machine
took (its recorder database, or a CSV probe log: `compd.offline.probe_log`).
`compd fit --adaptation` learns them from the calibration record's residual,
a floor measured on the day the model was fitted; the probes measure this
machine's drift at the spacing it really probes at, with the probe it really
has (`compd.offline.probes.refine_from_probes`). OUT is the model file with
that table replaced and a `[provenance.adaptation_refined]` entry saying from
what; the terms are copied as they are. Each refined setting is held within the
bounds `compd check` holds a model's [adaptation] table to, and a setting held at
its bound is named (`--json`: ``at_bound``, with the value the probes gave). The
daemon and `compd replay --probe-every-min` use the new table unless the config or an
option overrides it.
"""

from __future__ import annotations

import argparse
import json
import sys
from datetime import UTC, datetime
from typing import Any

from compd.sysexits import EX_DATAERR

HELP = "refine a model's [adaptation] settings from the probes a running machine took"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file (as `compd fit` wrote it)")
    parser.add_argument("probes", metavar="PROBES",
                        help="recorder database (.db/.sqlite/.sqlite3) or CSV probe log "
                             "(time_s, measured_um, model_um)")
    parser.add_argument("-o", "--out", metavar="OUT.toml", required=True,
                        help="the refined model file")
    parser.add_argument("--force", action="store_true", help="replace an existing OUT")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON line")


def run(args: argparse.Namespace) -> int:
    from compd.infiles import MAX_CONFIG_BYTES, read_toml_document
    from compd.offline.probe_log import describe, read_probe_log
    from compd.offline.probes import refine_from_probes
    from compd.offline.records import RecordError
    from compd.outfiles import check_output, write_atomically
    from models.adaptation import AdaptationParams
    from models.errors import ModelError
    from models.modelfile import dumps_model, parse_model

    check_output(args.out, "model file", force=args.force, inputs=[args.model, args.probes])
    try:
        _, doc = read_toml_document(args.model, "model file", MAX_CONFIG_BYTES)
        model = parse_model(doc, str(args.model))
        log = read_probe_log(args.probes)
        # the probes prove the settings: a table compd fit could not learn was unproven
        learnt = {k: v for k, v in model.adaptation.items() if k != "unproven"}
        before = {**_defaults(AdaptationParams()), **learnt}
        refined = refine_from_probes(log.time_s, log.residual_um,
                                     float(before["probe_noise_um"]))
    except (RecordError, ModelError) as exc:
        print(f"compd refine: {exc}", file=sys.stderr)
        return EX_DATAERR
    except ValueError as exc:  # too few probes
        print(f"compd refine: {args.probes}: {exc}", file=sys.stderr)
        return EX_DATAERR
    table, at_bound = refined.suggestion.bounded()
    doc = dict(doc)
    doc["adaptation"] = {**learnt, **table}
    provenance = dict(model.provenance)
    provenance["adaptation_refined"] = {
        "tool": "compd refine", "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "probes_file": str(args.probes), "probes_sha256": log.sha256,
        "probes": refined.probes, "pairs": refined.pairs, "spacing_s": refined.spacing_s,
        "probe_noise_from": refined.noise_from}
    doc["provenance"] = provenance
    text = dumps_model(doc)
    import tomllib
    parse_model(tomllib.loads(text), str(args.out))  # what is written reads back
    write_atomically(args.out, lambda tmp: tmp.write_text(text, encoding="utf-8"),
                     "model file", force=args.force, inputs=[args.model, args.probes])
    figures: dict[str, Any] = {
        "probes": refined.probes, "pairs": refined.pairs, "left_out": log.left_out,
        "spacing_s": refined.spacing_s, "probe_noise_from": refined.noise_from,
        "plain_rms_um": refined.suggestion.plain_rms_um,
        "held_rms_um": refined.suggestion.held_rms_um,
        "before": {k: before.get(k) for k in table}, "after": table, "at_bound": at_bound}
    if args.json:
        print(json.dumps(figures))
        return 0
    print(f"{args.out}: [adaptation] refined from {describe(log)} in {args.probes} "
          f"({refined.pairs} spacings of about {refined.spacing_s / 3600.0:.3g} h; "
          f"{log.left_out} left out)")
    for key, value in table.items():
        bound = (f"  (the probes say {at_bound[key]:.4g}: held at the bound `compd check` "
                 "enforces)" if key in at_bound else _remark(key, before.get(key), value))
        print(f"  {key:24s} {before.get(key)!s:>10} → {value:g}{bound}")
    plain, held = refined.suggestion.plain_rms_um, refined.suggestion.held_rms_um
    verdict = ("a correction held from one probe to the next pays" if held < plain else
               "holding a probe's correction does not pay at this spacing: the estimator "
               "starts stood down")
    print(f"  at the probes: plain model {plain:.3g} µm RMS, held correction {held:.3g} µm "
          f"RMS: {verdict}")
    return 0


#: what a refined setting of zero means, said beside it (a zero looks like "off")
_ZERO_MEANS = {
    "bias_rw_um_per_sqrt_h": "the probes show no drift beyond their noise: the estimator "
                             "learns one constant bias and never follows a drift",
    "gain_rw_per_sqrt_h": "the probes show no change of the terms' gains: the gains are "
                          "learnt once and held",
}


def _remark(key: str, before: object, after: float) -> str:
    """A note beside a refined setting whose new value changes its meaning."""
    if after == 0.0 and isinstance(before, int | float) and before != 0.0 \
            and key in _ZERO_MEANS:
        return f"  ({_ZERO_MEANS[key]})"
    return ""


def _defaults(params: Any) -> dict[str, Any]:
    from dataclasses import asdict

    return asdict(params)
