"""`compd rezero (CONFIG | --state-dir DIR) [--wait-s S]`: take the running
daemon's present prediction as the new zero (at tool touch-off).

The request goes through the daemon's state directory
(`compd.runtime.rezero_request`: only the daemon's user and root can write
there, so the operating system authorises it; no listener is opened): a file
``rezero.request`` (who, when, an id) written by a temporary name and a
rename. The daemon takes it before its next cycle, re-zeroes (the offset
ramps to the new target at the slew limit, never a step at the tool) and
writes its checkpoint at once, naming the request; this command waits for
that checkpoint. Exit 0 when the daemon re-zeroed (the zero is printed); 75
when no daemon took the request within ``--wait-s`` (the request is removed:
a re-zero is for now, never for the daemon's next start); 64 bad arguments;
78 a config that does not load; 74 the state directory cannot be written.
"""

from __future__ import annotations

import argparse
import contextlib
import getpass
import json
import os
import secrets
import sys
import time
from pathlib import Path

from compd.argtypes import number
from compd.sysexits import EX_IOERR, EX_TEMPFAIL

HELP = "re-zero the running daemon: its present prediction becomes the new zero"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", nargs="?", type=Path, metavar="CONFIG",
                        help="the daemon's config (its [state] dir is used)")
    parser.add_argument("--state-dir", metavar="DIR", type=Path,
                        help="the daemon's state directory (instead of CONFIG)")
    parser.add_argument("--wait-s", type=number(0.1, 600.0), default=30.0,
                        metavar="S", help="how long to wait for the daemon to take it "
                                          "(default 30 s)")


def _state_dir(args: argparse.Namespace) -> Path:
    if args.state_dir is not None:
        return Path(args.state_dir)
    from compd.config.loader import load_config

    return load_config(args.config).state_dir


def _usage(message: str) -> int:
    from compd.sysexits import EX_USAGE

    print(f"compd rezero: {message}", file=sys.stderr)
    return EX_USAGE


def _write_request(state_dir: Path, doc: dict[str, object]) -> None:
    """``rezero.request`` in `state_dir` by a temporary name and a rename, never
    through a link."""
    from compd.runtime.rezero_request import REQUEST_NAME

    dfd = os.open(state_dir, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        tmp = f".{REQUEST_NAME}.{doc['id']}"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC,
                     0o600, dir_fd=dfd)
        try:
            os.write(fd, json.dumps(doc).encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, REQUEST_NAME, src_dir_fd=dfd, dst_dir_fd=dfd)
    finally:
        os.close(dfd)


def _applied(state_dir: Path, rid: str) -> dict[str, object] | None:
    """The checkpoint's zero when it names request `rid`."""
    from compd.runtime.checkpoint import CHECKPOINT_NAME, CheckpointError, load_checkpoint

    try:
        owner = state_dir.stat().st_uid
        state = load_checkpoint(state_dir / CHECKPOINT_NAME, owner=owner)
    except (CheckpointError, OSError):
        return None
    zero = state.get("zero") if state is not None else None
    if isinstance(zero, dict) and f"request {rid})" in str(zero.get("by", "")):
        return zero
    return None


def run(args: argparse.Namespace) -> int:
    from compd.runtime.rezero_request import REQUEST_NAME

    if (args.config is None) == (args.state_dir is None):
        return _usage("give either CONFIG or --state-dir DIR")
    state_dir = _state_dir(args)
    rid = secrets.token_hex(8)
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = f"uid{os.geteuid()}"
    doc: dict[str, object] = {"user": user[:64], "id": rid, "wall_s": time.time()}
    try:
        _write_request(state_dir, doc)
    except OSError as exc:
        print(f"compd rezero: state dir {state_dir}: cannot write the request: "
              f"{exc.strerror or exc}", file=sys.stderr)
        return EX_IOERR
    end = time.monotonic() + args.wait_s
    while time.monotonic() < end:
        zero = _applied(state_dir, rid)
        if zero is not None:
            print(f"re-zeroed: the prediction {zero.get('um')} um is the new zero "
                  f"({zero.get('by')}); the offset ramps at the slew limit")
            return 0
        time.sleep(0.1)
    with contextlib.suppress(OSError):
        dfd = os.open(state_dir, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
        try:
            os.unlink(REQUEST_NAME, dir_fd=dfd)
        finally:
            os.close(dfd)
    if _applied(state_dir, rid) is not None:  # taken as it was removed
        print("re-zeroed (late)")
        return 0
    print(f"compd rezero: state dir {state_dir}: no daemon took the request within "
          f"{args.wait_s:g} s (is compd running with this state directory?); request removed",
          file=sys.stderr)
    return EX_TEMPFAIL
