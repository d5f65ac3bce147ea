"""The `compd` command line: one module per subcommand in `compd.commands`.

Each command module exposes ``HELP: str``, ``add_arguments(parser)`` and
``run(args) -> int``; heavy imports (scipy, matplotlib, protocol libraries)
happen inside ``run`` so that one command never pays for another's.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from types import ModuleType

from compd.errors import EX_CONFIG, ConfigError

#: subcommand -> module under compd.commands
COMMANDS: dict[str, str] = {
    "run": "run",
    "check": "check",
    "demo": "demo",
    "sim": "sim",
    "fit": "fit",
    "replay": "replay",
    "step": "step",
    "health": "health",
}


def _load(module: str) -> ModuleType | None:
    try:
        return importlib.import_module(f"compd.commands.{module}")
    except ModuleNotFoundError as exc:
        if exc.name == f"compd.commands.{module}":
            return None
        raise


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="compd", description="Real-time thermal error compensation for CNC machine tools.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module_name in COMMANDS.items():
        module = _load(module_name)
        if module is None:
            continue
        text = module.HELP.replace("%", "%%")  # argparse formats help strings with %
        p = sub.add_parser(name, help=text, description=text)
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


def main(argv: Sequence[str] | None = None) -> int:
    _ensure_std_streams()
    args = build_parser().parse_args(argv)
    try:
        rc: int = args._run(args)
    except ConfigError as exc:
        print(f"compd: configuration error: {exc}", file=sys.stderr)
        return EX_CONFIG
    return rc


if __name__ == "__main__":
    sys.exit(main())
