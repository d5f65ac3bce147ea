"""`compd check MODEL_OR_CONFIG [--json]`: load, analyse, refuse what is unsafe.

For a model file (or a bundled library name such as ``sp2``) it prints per
term: poles, zeros, stability, DC gain (µm/K) and its sensitivity to the
printed digits. A daemon config is handed to `compd.config.loader` when present.
Any invalid input exits 78 (EX_CONFIG) with one message naming the key.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from compd.offline.model_description import (
    describe_model,
    fallback_lines,
    format_pole,
    format_zero,
    plausibility,
)

HELP = "validate a model file or a daemon config and print poles, DC gains, sensitivity"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", metavar="MODEL_OR_CONFIG",
                        help="model file, bundled model name (e.g. sp2), daemon config, or "
                             "a directory of daemon configs (as compd run DIR)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--connect", action="store_true",
                        help="(config) also connect and read each channel once")


def _print_text(report: dict[str, Any]) -> None:
    period = float(report["period_s"])
    print(f"model {report['model']!r}: period {report['period_s']} s, "
          f"{len(report['terms'])} term(s)")
    for t in report["terms"]:
        ins = " ".join(f"{c:+g}·{ch}" for ch, c in t["inputs"].items())
        print(f"\nterm {t['name']!r} ({t['kind']}): input {ins}, gain {t['gain']}")
        poles = ", ".join(format_pole(p, period) for p in t["poles"])
        print(f"  poles: {poles}")
        if t.get("zeros"):
            print(f"  zeros: {', '.join(format_zero(z) for z in t['zeros'])}")
        for root in t.get("cancelled_unit_circle", []):
            print(f"  note: a pole at z = {root} is cancelled exactly by a zero at z = {root}; "
                  "the reduced form is used (stable)")
        print(f"  stable: {'yes' if t['stable'] else 'NO'}")
        print(f"  DC gain: {t['dc_gain']:.6g} {t['dc_gain_unit']}")
        if "dc_gain_note" in t:
            print(f"  sensitivity: {t['dc_gain_note']}")
    print()
    for line in fallback_lines(report.get("fallbacks", {})):
        print(line)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from compd.errors import ConfigError
    from models.errors import ModelError
    from models.sanity import check_model

    if Path(args.path).is_dir():  # as `compd run DIR`: every *.toml in it, one machine each
        from compd.commands.check_config import report_directory

        return report_directory(Path(args.path), args)
    kind, loaded = _load(args.path)
    if kind == "config":
        from compd.commands.check_config import report

        rc: int = report(loaded, args)
        return rc
    if args.connect:
        from compd.infiles import InputError
        from compd.sysexits import EX_USAGE

        raise InputError(f"--connect reads a daemon config's channels; {args.path} is a "
                         "model", EX_USAGE)
    try:
        check_model(loaded)  # physically absurd: refused (models.sanity)
        for lost, fb in loaded.fallbacks.items():
            try:
                check_model(fb)
            except ModelError as exc:
                raise ModelError(f"fallback for {lost!r}: {exc}") from None
    except ModelError as exc:
        raise ConfigError("", str(exc)) from None
    report_ = describe_model(loaded)
    flags = plausibility(loaded)
    if args.json:
        print(json.dumps({"terms": report_["terms"], "model": report_["model"],
                          "period_s": report_["period_s"], "implausible": flags,
                          "fallbacks": report_.get("fallbacks", {})}))
    else:
        _print_text(report_)
    for w in flags:
        print(f"compd check: warning: {w}", file=sys.stderr)
    return 0


def _load(path: str) -> tuple[str, Any]:
    """("config", LoadedConfig) or ("model", CompensationModel): the file read
    once by the reader `compd run` uses (`compd.infiles.read_toml_document`);
    a daemon config is one with any table a config has and a model file has not
    ([controller], [machine], [output], [channels], ...), so a config missing its
    [controller] is told so rather than read as a model."""
    import os
    from pathlib import Path

    from compd.config.loader import parse_config
    from compd.config.schema import DaemonConfig
    from compd.errors import ConfigError
    from compd.infiles import load_model, read_toml_document
    from models.errors import ModelError
    from models.modelfile import MODEL_FILE_KEYS, library_names, library_path, parse_model

    p = Path(path)
    try:
        if path and not os.path.lexists(p) and p.suffix == "" and library_path(path):
            return "model", load_model(path)
        if path and not os.path.lexists(p) and p.suffix == "" and "/" not in path:
            from compd.infiles import InputError

            raise InputError(f"{path}: no such file, nor a bundled model (bundled: "
                             f"{', '.join(library_names())})")
        text, doc = read_toml_document(p, "model or config file")
        if any(key in DaemonConfig.model_fields and key not in MODEL_FILE_KEYS
               for key in doc):
            return "config", parse_config(doc, p.resolve(), text)
        return "model", parse_model(doc)
    except ModelError as exc:
        raise ConfigError("", str(exc)) from None
