"""A recorder file opened as data (`compd.store.reader` opens through it).

Before SQLite sees the file: a readable regular file (`compd.infiles.open_input`:
a FIFO, a device, a directory or a missing file is an InputError) whose first 16
bytes are SQLite's. Then opened read-only, and each table a reader reads must be
an ordinary table: a view's query may recurse without end (read-only mode does
not stop one), and a virtual table runs a module's code. Every refusal after the
first check is a `RecorderError` naming the file.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from compd.infiles import open_input
from compd.store.schema import RecorderError

MAGIC = b"SQLite format 3\x00"
#: the file is streamed: any size is read in the same memory
_ANY_SIZE = 1 << 62
#: the tables a reader reads: each must be an ordinary table (`check_tables`)
TABLES = ("samples", "meta", "probes", "axes")


def connect_readonly(path: Path, timeout_s: float) -> sqlite3.Connection:
    """`path` checked to be an SQLite file, then opened read-only, waiting up to
    `timeout_s` for a lock another process holds."""
    with open_input(path, "recorder database", _ANY_SIZE) as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise RecorderError(path, "not an SQLite database, so not a recorder compd wrote")
    try:
        return sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True,
                               timeout=timeout_s, check_same_thread=False)
    except sqlite3.Error as exc:
        raise RecorderError(path, f"cannot open: {exc}") from None


def check_tables(conn: sqlite3.Connection, path: Path) -> None:
    """Each table read is an ordinary table (``samples`` and ``meta`` there, ``probes``
    and ``axes`` there or absent), never a view or a virtual table: data, not a query."""
    kinds = {str(name): (str(kind), str(sql or "")) for name, kind, sql in conn.execute(
        "SELECT name, type, sql FROM sqlite_schema WHERE name IN "
        f"({', '.join('?' * len(TABLES))})", TABLES)}
    if "samples" not in kinds:
        raise RecorderError(path, "not a recorder database (no table samples)")
    for name, (kind, sql) in kinds.items():
        virtual = sql.lstrip().upper().startswith("CREATE VIRTUAL")
        if kind != "table" or virtual:
            what = "a virtual table" if virtual else f"a {kind}"
            raise RecorderError(path, f"not a recorder database ({name} is {what}, "
                                "not a table: compd reads data, never a query)")
