"""One careful writer for every file a command creates: a model (`fit -o`),
a record (`sim --record`), a figure (`--plot`).

`check_output` runs before any work: the directory must exist and be
writable; an existing target must be a regular file (never a directory,
device such as /dev/full, FIFO or symbolic link), must not be one of the
command's inputs (compared by device and inode, so hard and symbolic links
are caught too), and is replaced only with ``--force``. `write_atomically`
writes a temporary file in the same directory, fsyncs it, renames it over the
target and fsyncs the directory: a reader sees the old file or the new one,
never half of one, and a failed write leaves the old file as it was. Each
refusal is one `OutputError` with its exit code (73 cannot create, 74 I/O,
64 a name that is not text in the file system's encoding, 69 a figure without
matplotlib).
"""

from __future__ import annotations

import contextlib
import os
import stat
import sys
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

from compd.errors import CompdError
from compd.sysexits import EX_CANTCREAT, EX_IOERR, EX_UNAVAILABLE, EX_USAGE


class OutputError(CompdError):
    """An output file cannot or must not be written; `code` is the exit code."""

    def __init__(self, message: str, code: int = EX_CANTCREAT) -> None:
        self.code = code
        super().__init__(message)


def _identity(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def _check_target(p: Path, what: str, force: bool, inputs: Iterable[str | os.PathLike[str]],
                  ) -> None:
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise OutputError(f"{p}: cannot write the {what} ({exc.strerror})") from None
    if stat.S_ISLNK(st.st_mode):
        raise OutputError(f"{p}: is a symbolic link; name the {what} file itself")
    if not stat.S_ISREG(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
        raise OutputError(f"{p}: is {kind}; the {what} must be a regular file")
    for source in inputs:
        if _identity(source) == (st.st_dev, st.st_ino):
            raise OutputError(f"{p}: is the input {os.fspath(source)}; refusing to "
                              f"overwrite it with the {what}")
    if not force:
        raise OutputError(f"{p}: exists; give --force to replace it with the {what}")


def _check_name(text: str, what: str) -> None:
    """A name the file system encoding cannot represent as text (bytes that
    are not UTF-8, which Python carries as lone surrogates) is refused: the
    file could be created, but not named again in a config, a model's
    provenance or a message. The name is shown with its bytes escaped."""
    encoding = sys.getfilesystemencoding()
    try:
        text.encode(encoding)
    except UnicodeEncodeError:
        shown = ascii(os.fsencode(text))[1:]  # b'\xfe.toml' -> '\xfe.toml'
        raise OutputError(f"{shown}: the {what}'s name is not {encoding} text; give it a "
                          "name of characters, not raw bytes", EX_USAGE) from None


def check_output(path: str | os.PathLike[str], what: str, *, force: bool = False,
                 inputs: Iterable[str | os.PathLike[str]] = ()) -> Path:
    """The target as a Path, once it is known that the {what} can be written
    there (see the module docstring); call before the work starts."""
    text = os.fspath(path)
    if not text:
        raise OutputError(f"no file named for the {what} (empty path)")
    _check_name(text, what)
    if text.endswith(os.sep):
        raise OutputError(f"{text}: names a directory; the {what} must be a file")
    p = Path(text)
    parent = p.parent
    try:
        if not stat.S_ISDIR(os.stat(parent).st_mode):
            raise OutputError(f"{p}: {parent} is not a directory")
    except FileNotFoundError:
        raise OutputError(f"{p}: directory {parent} does not exist") from None
    except OSError as exc:
        raise OutputError(f"{p}: cannot use directory {parent} ({exc.strerror})") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{p}: no permission to create files in {parent}")
    _check_target(p, what, force, inputs)
    _probe(p)
    return p


#: bytes of the target's name and suffix kept in a temporary file's name: a
#: target name near the file system's limit (255 bytes) still leaves room for
#: the temporary one's dot, random part and ".part"
_TMP_NAME_BYTES = 96
_TMP_SUFFIX_BYTES = 16


def _tmp_prefix(p: Path) -> str:
    """The temporary file's prefix: a dot and the target's name, cut to
    `_TMP_NAME_BYTES` (whole characters), so it is recognisably the target's."""
    head = p.name.encode("utf-8", "surrogateescape")[:_TMP_NAME_BYTES]
    return "." + head.decode("utf-8", "ignore") + "."


def _tmp_suffix(p: Path) -> str:
    """The target's suffix when it is a plausible format suffix (a figure's format
    is read from it), else none."""
    suffix = p.suffix
    return suffix if len(suffix.encode("utf-8", "surrogateescape")) <= _TMP_SUFFIX_BYTES else ""


def _probe(p: Path) -> None:
    """Create (and remove) a temporary file beside the target: a read-only or
    pseudo file system says no now, not after the work (root passes `access`)."""
    try:
        fd, name = tempfile.mkstemp(prefix=_tmp_prefix(p), suffix=".probe", dir=p.parent)
    except OSError as exc:
        raise OutputError(f"{p}: cannot create files in {p.parent} ({exc.strerror})") from None
    os.close(fd)
    os.unlink(name)


#: figure formats the plotting library writes, by file suffix
FIGURE_SUFFIXES = frozenset({".png", ".pdf", ".svg", ".svgz", ".eps", ".ps", ".jpg", ".jpeg",
                             ".tif", ".tiff", ".webp"})


def check_figure(path: str | os.PathLike[str], *, force: bool = False,
                 inputs: Iterable[str | os.PathLike[str]] = ()) -> Path:
    """`check_output` for a figure, whose suffix also says its format; and the library
    that draws it, matplotlib (the ``plot`` extra), loaded now: without it the command
    ends here (exit 69), before its work, not in a traceback after it."""
    p = check_output(path, "figure", force=force, inputs=inputs)
    if p.suffix.lower() not in FIGURE_SUFFIXES:
        raise OutputError(f"{p}: a figure is written as one of "
                          f"{', '.join(sorted(FIGURE_SUFFIXES))}; name it so")
    try:
        import compd.offline.plots  # noqa: F401  (matplotlib, its Agg backend set)
    except ImportError as exc:
        root = (exc.name or "matplotlib").partition(".")[0]
        why = "" if root == "matplotlib" else f" ({root!r}, which it needs, is missing)"
        raise OutputError(f"a figure (--plot) needs matplotlib{why}: pip install "
                          "'compd[plot]'", EX_UNAVAILABLE) from None
    return p


def _fsync(path: str | os.PathLike[str], flags: int) -> None:
    fd = os.open(path, flags | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _mode_for(p: Path) -> int:
    try:
        return stat.S_IMODE(os.stat(p).st_mode)  # replacing: keep the file's mode
    except OSError:
        mask = os.umask(0o022)
        os.umask(mask)
        return 0o666 & ~mask


def write_atomically(path: str | os.PathLike[str], write: Callable[[Path], object], what: str,
                     *, force: bool = False,
                     inputs: Iterable[str | os.PathLike[str]] = ()) -> Path:
    """Check the target again, let `write` fill a temporary file (its path,
    same directory and suffix), then fsync and rename it over the target."""
    inputs = list(inputs)
    p = check_output(path, what, force=force, inputs=inputs)
    try:
        fd, name = tempfile.mkstemp(prefix=_tmp_prefix(p), suffix=f".part{_tmp_suffix(p)}",
                                    dir=p.parent)
    except OSError as exc:
        raise OutputError(f"{p}: cannot create files in {p.parent} ({exc.strerror})") from None
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        os.chmod(tmp, _mode_for(p))
        _fsync(tmp, os.O_RDONLY)
        _check_target(p, what, force, inputs)  # nothing planted there meanwhile
        os.replace(tmp, p)
        with contextlib.suppress(OSError):
            _fsync(p.parent, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{p}: cannot write the {what} ({exc.strerror or exc})",
                          EX_IOERR) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return p
