"""The `compd` command line: one module per subcommand in `compd.commands`.

Each command module exposes ``HELP: str``, ``add_arguments(parser)`` and
``run(args) -> int``; heavy imports (scipy, matplotlib, protocol libraries)
happen inside ``run`` so that one command never pays for another's.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import sys
import typing
from collections.abc import Sequence
from types import ModuleType

from compd.errors import EX_CONFIG, ConfigError
from compd.infiles import InputError
from compd.outfiles import OutputError
from compd.sysexits import EX_IOERR, EX_USAGE

#: subcommand -> module under compd.commands
COMMANDS: dict[str, str] = {
    "run": "run",
    "check": "check",
    "demo": "demo",
    "sim": "sim",
    "fit": "fit",
    "replay": "replay",
    "refine": "refine",
    "step": "step",
    "report": "report",
    "health": "health",
    "status": "status",
    "rezero": "rezero",
    "export": "export",
    "schema": "schema",
    "plan": "plan",
}


def command_named(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` names, when its first word that is not an option
    is one of ``COMMANDS`` (the top level's only options, --help and --version,
    take no value); else None."""
    for word in argv:
        if word.startswith("-") and word not in ("-", "--"):
            continue
        return word if word in COMMANDS else None
    return None


def _load(module: str) -> ModuleType | None:
    try:
        return importlib.import_module(f"compd.commands.{module}")
    except ModuleNotFoundError as exc:
        if exc.name == f"compd.commands.{module}":
            return None
        raise


class Parser(argparse.ArgumentParser):
    """Usage errors end with one line on stderr and exit 64 (EX_USAGE)."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(EX_USAGE, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or of the one command ``only`` names.

    A process runs one command: ``compd run`` then imports neither ``fit``'s
    nor ``sim``'s module (and what they import at the top) just to build
    parsers it never uses. The top-level help and a wrong command name need
    them all (their one-line helps, the list of choices).
    """
    from compd import __version__
    from compd.examples_help import EXAMPLES

    parser = Parser(
        prog="compd", description="Real-time thermal error compensation for CNC machine tools.")
    parser.add_argument("--version", action="version", version=f"compd {__version__}",
                        help="print compd's version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module_name in COMMANDS.items():
        if only is not None and name != only:
            continue
        module = _load(module_name)
        if module is None:
            if only is not None:  # not installed: the full parser says "invalid choice"
                return build_parser()
            continue
        # argparse %-formats help strings but prints description and epilog as they are
        p = sub.add_parser(name, help=module.HELP.replace("%", "%%"), description=module.HELP,
                           epilog=EXAMPLES.get(name),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def _ensure_std_streams() -> None:
    """Started with stdout or stderr closed (``compd run 2>&-``), Python has
    None there and the first message would end the process with status 1: give
    the closed descriptor /dev/null so compd runs (and logs nowhere)."""
    import os

    for fd, name in ((1, "stdout"), (2, "stderr")):
        if getattr(sys, name) is not None:
            continue
        null = os.open(os.devnull, os.O_WRONLY)
        if null != fd:
            os.dup2(null, fd)
            os.close(null)
        setattr(sys, name, open(fd, "w", encoding="utf-8", closefd=False))  # noqa: SIM115


def _tolerant_std_streams() -> None:
    """A narrow output encoding (``PYTHONIOENCODING=ascii``, a C locale of
    another Python) must not end a command that prints µ, ° or ±, or a file
    name of raw bytes: what the encoding cannot say is written
    backslash-escaped (``\\xb5m``) instead of raising UnicodeEncodeError."""
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is None or getattr(stream, "errors", None) == "backslashreplace":
            continue
        with contextlib.suppress(OSError, ValueError):  # else left as it is
            reconfigure(errors="backslashreplace")


def _quiet_stdout() -> None:
    """stdout's reader went away (``compd check | head -1``): drop the rest
    quietly, as other Unix tools do, instead of a BrokenPipeError at exit."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass


def _flush_stdout() -> None:
    """Everything printed reaches stdout now, or the command says why it did not."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:  # stdout on a full disk or device
        _quiet_stdout()
        raise OutputError(f"cannot write to stdout ({exc.strerror or exc})", EX_IOERR
                          ) from None


def main(argv: Sequence[str] | None = None) -> int:
    _ensure_std_streams()
    _tolerant_std_streams()
    words = sys.argv[1:] if argv is None else argv
    args = build_parser(command_named(words)).parse_args(words)
    try:
        rc: int = args._run(args)
        _flush_stdout()
    except ConfigError as exc:
        print(f"compd: configuration error: {exc}", file=sys.stderr)
        return EX_CONFIG
    except (InputError, OutputError) as exc:
        print(f"compd {args.command}: {exc}", file=sys.stderr)
        return exc.code
    except BrokenPipeError:
        _quiet_stdout()
        return EX_IOERR
    except OSError as exc:  # an I/O error no command foresaw (stdout on a full disk, ...)
        try:
            sys.stdout.flush()
        except OSError:
            _quiet_stdout()
        print(f"compd {args.command}: I/O error: {exc.strerror or exc}", file=sys.stderr)
        return EX_IOERR
    return rc


if __name__ == "__main__":
    sys.exit(main())
