"""`compd export RECORDER.db [--since T] [--until T] [--format csv|parquet] [-o FILE]`

The daemon's recorder (`recorder.path`, by default STATE_DIR/samples.sqlite)
as CSV for a spreadsheet or Parquet for a historian, cut to a wall-clock
window. CSV goes to stdout unless ``-o`` names a file; Parquet needs ``-o``
and pyarrow (``pip install 'compd[parquet]'``). The output is checked before
the work and written atomically (`compd.outfiles`); the recorder may be read
while the daemon writes it (SQLite's WAL).
"""

from __future__ import annotations

import argparse
import sys

from compd.sysexits import EX_DATAERR, EX_UNAVAILABLE, EX_USAGE

HELP = "write the daemon's recorder as CSV or Parquet, cut to a time window"


def _when(text: str) -> float:
    from compd.offline.export import parse_when

    try:
        return parse_when(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recorder", metavar="RECORDER.db",
                        help="the daemon's recorder database (recorder.path)")
    parser.add_argument("--since", type=_when, metavar="TIME",
                        help="first wall-clock time kept, ISO 8601 (UTC unless an offset "
                             "is given; default: the first row)")
    parser.add_argument("--until", type=_when, metavar="TIME",
                        help="keep rows before this wall-clock time, ISO 8601 (default: all)")
    parser.add_argument("--format", choices=("csv", "parquet"), default=None,
                        help="output format (default: from the -o suffix, else csv)")
    parser.add_argument("-o", "--output", metavar="FILE", default=None,
                        help="write here instead of stdout (required for parquet)")
    parser.add_argument("--force", action="store_true", help="replace an existing -o file")


def run(args: argparse.Namespace) -> int:
    from compd.offline.export import (
        Export,
        ExportError,
        write_csv,
        write_csv_file,
        write_parquet,
    )
    from compd.outfiles import check_output, write_atomically

    fmt = args.format or ("parquet" if (args.output or "").lower().endswith(".parquet")
                          else "csv")
    if fmt == "parquet" and args.output is None:
        print("compd export: --format parquet needs -o FILE", file=sys.stderr)
        return EX_USAGE
    if args.since is not None and args.until is not None and args.until <= args.since:
        print("compd export: --until must be after --since", file=sys.stderr)
        return EX_USAGE
    if fmt == "parquet":
        try:
            import pyarrow  # noqa: F401
        except ModuleNotFoundError:
            print("compd export: Parquet needs pyarrow: pip install 'compd[parquet]'",
                  file=sys.stderr)
            return EX_UNAVAILABLE
    if args.output is not None:
        check_output(args.output, "export", force=args.force, inputs=[args.recorder])
    try:
        with Export(args.recorder, args.since, args.until) as export:
            if args.output is None:
                write_csv(export, sys.stdout)
            else:
                write = write_csv_file if fmt == "csv" else write_parquet
                write_atomically(args.output, lambda tmp: write(export, tmp), "export",
                                 force=args.force, inputs=[args.recorder])
    except ExportError as exc:
        print(f"compd export: {exc}", file=sys.stderr)
        return EX_DATAERR
    if args.output is not None:
        print(f"compd export: {export.rows} rows written to {args.output}")
    return 0
