"""Atomic checkpoints of the daemon's state (model delay lines, last written
offset, cycle number) so that a restart resumes without a jump.

File format: one JSON object (one top-level key a line), the caller's state
plus three keys added here:
``version`` (the format, 1), ``saved_wall_s`` (the caller's wall-clock time of
the state: the daemon's cycle's; time.time() at save when none is given) and
``checksum`` (sha256 hex of the canonical JSON of everything else: sorted keys,
compact separators). A checkpoint is either the old one or the new one, never
a mixture: it is written to a temp file in the same directory, flushed and
fsynced, renamed over the old one with os.replace, and the directory is
fsynced so the rename itself survives a power cut.

`load_checkpoint` refuses (CheckpointError with a reason) anything it cannot
trust: an empty or truncated file, bytes that are not UTF-8 JSON, a wrong
version, a checksum that does not match, non-finite numbers. It never returns
part of a file.

One writer per checkpoint path: the daemon holds `compd.runtime.statelock.StateLock`
on its state directory, so a fixed temp name is safe. Whatever stands at the
temp name is unlinked first and the file is created with ``O_EXCL |
O_NOFOLLOW`` (mode 0600): a link planted there is removed, never written
through. A checkpoint that is a link (or has several names) is refused on load.

Every step (unlink, create, rename, fsync of the directory) works relative to
one descriptor of the directory: the daemon passes the one its lock holds
(`directory`), so a state directory swapped for a link while the daemon runs
gets nothing (the checkpoint lands in the directory that was opened); without
one, the directory is opened for this one save, safely (`StateDir.open`).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import time
from pathlib import Path
from typing import Any

from compd.errors import CompdError
from compd.runtime.statedir import StateDir, StateDirError, open_private
from models.nesting import loads_json

__all__ = ["CHECKPOINT_NAME", "FORMAT_VERSION", "RESERVED_KEYS", "CheckpointError",
           "encode_checkpoint", "load_checkpoint", "save_checkpoint", "write_checkpoint"]

#: The checkpoint's name in the state directory (the daemon writes it, `compd health` reads it).
CHECKPOINT_NAME = "checkpoint.json"

#: The checkpoint format this module writes and accepts.
FORMAT_VERSION = 1
#: A checkpoint holds delay lines and a few numbers; anything larger is not ours.
MAX_BYTES = 16 * 1024 * 1024
#: Keys added by `save_checkpoint`; a state dict may not use them itself.
RESERVED_KEYS = frozenset({"version", "saved_wall_s", "checksum"})


class CheckpointError(CompdError):
    """A checkpoint cannot be saved or trusted. `path` is the file, `reason` why."""

    def __init__(self, path: Path, reason: str) -> None:
        self.path = path
        self.reason = reason
        super().__init__(f"checkpoint {path}: {reason}")


def _canonical(payload: dict[str, Any]) -> bytes:
    """The bytes the checksum covers: sorted keys, no whitespace, finite numbers only."""
    return json.dumps(payload, sort_keys=True, separators=(",", ":"),
                      allow_nan=False, ensure_ascii=True).encode("ascii")


def _checksum(payload: dict[str, Any]) -> str:
    return hashlib.sha256(_canonical(payload)).hexdigest()


def _temp_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp")


def save_checkpoint(path: Path, state: dict[str, Any], *,
                    directory: StateDir | None = None) -> None:
    """Write `state` to `path` atomically (see the module docstring); with
    `directory` (the open state directory), into it under `path`'s name.

    Raises CheckpointError when the state cannot be stored faithfully (a NaN or
    infinity, a value JSON cannot hold, a reserved key) and OSError when the
    file system refuses (the old checkpoint is then left as it was).
    """
    write_checkpoint(path, encode_checkpoint(path, state), directory=directory)


def encode_checkpoint(path: Path, state: dict[str, Any], *,
                      wall_s: float | None = None) -> bytes:
    """The file's bytes for `state` (the first half of `save_checkpoint`: no I/O,
    so the caller may write them later or on another thread); CheckpointError as
    `save_checkpoint` raises it."""
    clash = RESERVED_KEYS.intersection(state)
    if clash:
        raise CheckpointError(path, f"state uses reserved key(s) {sorted(clash)}")
    payload: dict[str, Any] = dict(state)
    payload["version"] = FORMAT_VERSION
    payload["saved_wall_s"] = time.time() if wall_s is None else wall_s
    try:
        members = _members(payload)
    except ValueError as exc:  # allow_nan=False: NaN/inf; also circular references
        raise CheckpointError(
            path, f"state is not storable: {exc} (non-finite floats are refused)") from exc
    except TypeError as exc:
        raise CheckpointError(path, f"state is not storable as JSON: {exc}") from exc
    # the canonical JSON (`_canonical`) is the members in key order, joined
    checksum = hashlib.sha256(
        ("{" + ",".join(m for _, m in members) + "}").encode("ascii")).hexdigest()
    members += _members({"checksum": checksum})
    members.sort(key=lambda km: km[0])
    return ("{\n" + ",\n".join(m for _, m in members) + "\n}").encode("ascii")


def _members(payload: dict[str, Any]) -> list[tuple[str, str]]:
    """Each top-level key and its member (``"key":value``) as `_canonical` writes
    it (compact, sorted keys, finite numbers only, ASCII), in key order. The
    canonical JSON is these joined; the file is these one a line, so both come of
    one encoding by json's C encoder (``indent`` takes its pure-Python one, several
    times slower on a checkpoint of each axis's value and slope models' delay
    lines, saved every ``checkpoint_every`` cycles). Each member is dumped as a
    one-key object, so a key is written as json writes any key."""
    return [(k, json.dumps({k: v}, sort_keys=True, separators=(",", ":"), allow_nan=False,
                           ensure_ascii=True)[1:-1])
            for k, v in sorted(payload.items())]


def write_checkpoint(path: Path, data: bytes, *, directory: StateDir | None = None) -> None:
    """Write `encode_checkpoint`'s bytes to `path` atomically (the second half of
    `save_checkpoint`: temp file, fsync, rename, fsync of the directory)."""
    if directory is not None:
        _write(directory, path, data)
        return
    try:
        opened = StateDir.open(path.parent, create=False)
    except StateDirError as exc:
        raise CheckpointError(path, f"{exc.path}: {exc.reason}") from exc
    with opened:
        _write(opened, path, data)


def _write(directory: StateDir, path: Path, data: bytes) -> None:
    name, tmp = path.name, _temp_path(path).name
    # a leftover of a kill, or a planted link (the link goes, not its target)
    directory.unlink(tmp)
    try:
        fd = directory.open_file(tmp, os.O_WRONLY | os.O_EXCL)
    except StateDirError as exc:
        raise CheckpointError(path, exc.reason) from exc
    try:
        view = memoryview(data)
        while view:
            written = os.write(fd, view)
            view = view[written:]
        os.fsync(fd)
    except BaseException:
        os.close(fd)
        with contextlib.suppress(OSError):
            directory.unlink(tmp)
        raise
    os.close(fd)
    directory.replace(tmp, name)
    directory.fsync()


def _refuse_constant(name: str) -> float:
    raise ValueError(f"non-finite number {name}")


def load_checkpoint(path: Path, *, directory: StateDir | None = None,
                    owner: int | None = None) -> dict[str, Any] | None:
    """The checkpoint at `path` (state plus version, saved_wall_s, checksum),
    None when there is none, CheckpointError when it cannot be trusted. With
    `directory` (the open state directory), `path`'s name in it. The file must
    be this process's own, or `owner`'s when given (a reader that is not the
    daemon, as `compd health`: the owner of the state directory)."""
    try:
        if directory is not None:
            fd = directory.open_file(path.name, os.O_RDONLY, create=False)
        else:
            fd = open_private(path, os.O_RDONLY, create=False, owner=owner)
    except FileNotFoundError:
        return None
    except StateDirError as exc:
        raise CheckpointError(path, exc.reason) from exc
    except OSError as exc:
        raise CheckpointError(path, f"unreadable: {exc.strerror or exc}") from exc
    try:
        with os.fdopen(fd, "rb") as f:
            data = f.read(MAX_BYTES + 1)
    except OSError as exc:
        raise CheckpointError(path, f"unreadable: {exc.strerror or exc}") from exc
    if len(data) > MAX_BYTES:
        raise CheckpointError(path, f"larger than {MAX_BYTES // (1024 * 1024)} MiB: not ours")
    if not data.strip():
        raise CheckpointError(path, "empty file (torn write)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CheckpointError(path, f"not UTF-8 (garbled): {exc.reason} at byte {exc.start}") \
            from exc
    try:
        obj = loads_json(text, parse=lambda t: json.loads(t, parse_constant=_refuse_constant))
    except json.JSONDecodeError as exc:
        raise CheckpointError(
            path, f"not valid JSON (torn or garbled): {exc.msg} at line {exc.lineno} "
                  f"column {exc.colno}") from exc
    except ValueError as exc:
        raise CheckpointError(path, str(exc)) from exc
    except RecursionError:
        raise CheckpointError(path, "nested too deeply: not ours") from None
    if not isinstance(obj, dict):
        raise CheckpointError(path, f"not a JSON object but {type(obj).__name__}")
    version = obj.get("version")
    if version != FORMAT_VERSION:
        raise CheckpointError(
            path, f"wrong version {version!r} (this compd reads version {FORMAT_VERSION})")
    stored = obj.get("checksum")
    if not isinstance(stored, str):
        raise CheckpointError(path, "no checksum")
    saved = obj.get("saved_wall_s")
    if not isinstance(saved, int | float) or isinstance(saved, bool) or not math.isfinite(saved):
        raise CheckpointError(path, f"bad saved_wall_s {saved!r}")
    payload = {k: v for k, v in obj.items() if k != "checksum"}
    if _checksum(payload) != stored:
        raise CheckpointError(path, "checksum mismatch (corrupt or edited)")
    return obj
