"""One careful reader for every input file: model and config TOML, drive maps,
calibration records (CSV or the recorder's SQLite database).

Every input is opened without blocking (a FIFO does not hang the command),
must be a regular file (not a directory, device such as /dev/zero, FIFO or
socket), and is capped in size: a model or config file of megabytes is
wrong, and a record beyond `MAX_RECORD_BYTES` is refused instead of eating
the machine's memory. Text must be UTF-8. Each refusal is one `InputError`
naming the file, with the exit code it ends the command with (66 no input,
65 data error); `compd.cli` prints it as one line.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
import tomllib
from pathlib import Path
from typing import IO, TYPE_CHECKING

from compd.errors import CompdError
from compd.sysexits import EX_DATAERR, EX_NOINPUT
from models.nesting import NestingError, loads_toml

if TYPE_CHECKING:
    from models.compensation import CompensationModel

#: a model file holds a few coefficients: 1 MiB is far beyond any real one
MAX_MODEL_BYTES = 1 << 20
#: a daemon config or drive map: a page or two of TOML
MAX_CONFIG_BYTES = 1 << 20
#: a calibration record (CSV): 1 GiB is ~20 million rows, years at 1 s
MAX_RECORD_BYTES = 1 << 30
#: one field of a record: a CSV cell (the csv module's own default field_size_limit, which
#: the records' reader keeps) or a recorder database's column; no number, name list or
#: row of channel values is near it
MAX_FIELD_CHARS = 128 * 1024


class InputError(CompdError):
    """An input file cannot be read as it is; `code` is the exit code."""

    def __init__(self, message: str, code: int = EX_NOINPUT) -> None:
        self.code = code
        super().__init__(message)


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _size(n: int) -> str:
    return f"{n / (1 << 20):.1f} MiB" if n >= 1 << 20 else f"{n} bytes"


def open_input(path: str | os.PathLike[str], what: str, max_bytes: int) -> IO[bytes]:
    """The file opened for binary reading, once it is known to be a regular
    file of at most `max_bytes`."""
    where = os.fspath(path)
    if not where:
        raise InputError(f"no {what} file named (empty path)")
    try:
        fd = os.open(where, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        reason = "a symbolic link loop" if exc.errno == errno.ELOOP else exc.strerror
        raise InputError(f"{where}: cannot read the {what} ({reason})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"{where}: the {what} is {_kind(st.st_mode)}, not a regular file")
        if st.st_size > max_bytes:
            raise InputError(f"{where}: the {what} is {_size(st.st_size)}; at most "
                             f"{_size(max_bytes)} is accepted", EX_DATAERR)
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def check_input(path: str | os.PathLike[str], what: str, max_bytes: int) -> None:
    """Refuse what `open_input` refuses, for files another library opens."""
    open_input(path, what, max_bytes).close()


def read_bytes(path: str | os.PathLike[str], what: str, max_bytes: int) -> bytes:
    with open_input(path, what, max_bytes) as f:
        try:
            data = f.read(max_bytes + 1)
        except OSError as exc:
            raise InputError(f"{os.fspath(path)}: cannot read the {what} ({exc.strerror})"
                             ) from None
    if len(data) > max_bytes:  # it grew while we read
        raise InputError(f"{os.fspath(path)}: the {what} is over {_size(max_bytes)}",
                         EX_DATAERR)
    return data


def decode_text(data: bytes, path: str | os.PathLike[str], what: str) -> str:
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{os.fspath(path)}: the {what} is not UTF-8 text (byte "
                         f"{exc.start})", EX_DATAERR) from None


def read_text(path: str | os.PathLike[str], what: str, max_bytes: int) -> str:
    """A small UTF-8 text file (a BOM is dropped)."""
    return decode_text(read_bytes(path, what, max_bytes), path, what)


def read_toml_document(path: str | os.PathLike[str], what: str,
                       max_bytes: int = MAX_CONFIG_BYTES) -> tuple[bytes, dict[str, object]]:
    """The file's bytes and its TOML document: the one reading of a config or
    model file (`compd run` and `compd check` both); not UTF-8 text, a
    syntax error or arrays and tables nested deeper than
    `models.nesting.MAX_NESTING` is an InputError (65) naming the file."""
    data = read_bytes(path, what, max_bytes)
    text = decode_text(data, path, what)
    try:
        return data, loads_toml(text)
    except NestingError as exc:
        raise InputError(f"{os.fspath(path)}: the {what} has {exc}", EX_DATAERR) from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{os.fspath(path)}: the {what} is not valid TOML ({exc})",
                         EX_DATAERR) from None


def read_toml(path: str | os.PathLike[str], what: str,
              max_bytes: int = MAX_CONFIG_BYTES) -> dict[str, object]:
    """A TOML document; a syntax error is an InputError (65) naming the file."""
    return read_toml_document(path, what, max_bytes)[1]


def load_model(path: str | Path) -> CompensationModel:
    """A model file, or a bundled library model by name (``sp2``), read with
    the limits above (not TOML is an InputError, 65, as `compd check` says);
    its content is checked by `models.modelfile` (ModelError)."""
    from models.modelfile import library_path, parse_model

    if not os.fspath(path):
        raise InputError("no model file named (empty path)")
    p = Path(path)
    if not os.path.lexists(p) and p.suffix == "" and library_path(str(path)) is not None:
        p = Path(str(library_path(str(path))))
    text = read_text(p, "model file", MAX_MODEL_BYTES)
    try:
        doc = loads_toml(text)
    except NestingError as exc:
        raise InputError(f"{path}: the model file has {exc}", EX_DATAERR) from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: the model file is not valid TOML ({exc})",
                         EX_DATAERR) from None
    return parse_model(doc)
