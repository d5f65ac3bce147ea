"""The recorder database's layout: its tables, the writer's statements, and the
upgrade of a file an older compd wrote.

Table ``samples``, one row per cycle: ``seq`` INTEGER PRIMARY KEY (the
recorder's own contiguous numbering), ``cycle``, ``mono_s``, ``wall_s``,
``offset_um``, ``model_um``, ``state``, ``valid``, ``channels`` (JSON
{name: value}, null when missing or not finite), ``validity`` (JSON {name:
reason} of the channels refused this cycle; a valid channel is absent: rows of
an older compd list every channel, null when valid), ``contributions`` (JSON
{term: µm}), ``attempted_um``, ``complete``. Table ``meta`` (key, value):
``channels`` and ``terms``, JSON lists of every channel and term name seen, in
the order first seen. Table ``probes``: one row per probe ([adaptation]).
Table ``axes``: one row per sample and ``[output.axes]`` axis (`AXIS_COLUMNS`:
its state, cause, whether its line is in force, and its value's and slope's
stage, sent, confirmed and model values, its reference, and for an axis written
as one offset at its read position that position and the offset written at it);
a file of an older compd gets the empty table, or the columns added since.

Channel values are stored once, in the JSON column. ``channel_values`` (seq,
channel, value, validity) is a view over it for a SQL client or Grafana (one
row per sample and channel, value REAL). A file of an older layout holds a
table of that name beside the JSON, the same values twice (+40 % bytes per
row): `upgrade` drops it (its values are all in the JSON) and creates the
view, whose INSTEAD OF triggers let an older compd, run again on the
upgraded file, go on writing its rows (into the JSON).
"""

from __future__ import annotations

import json
import sqlite3

from compd.errors import CompdError

__all__ = ["AXIS_ADDED_COLUMNS", "AXIS_COLUMNS", "CHANNELS_KEY", "FIXED_COLUMNS",
           "INSERT_AXIS", "INSERT_PROBE",
           "INSERT_SAMPLE", "PROBE_COLUMNS", "SAMPLE_COLUMNS", "SCHEMA", "TERMS_KEY",
           "RecorderError", "meta_names", "scan_terms", "upgrade"]


class RecorderError(CompdError):
    """The recorder database cannot be opened or read. `path` is the file."""

    def __init__(self, path: object, reason: str) -> None:
        self.path = path
        self.reason = reason
        super().__init__(f"recorder {path}: {reason}")


SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (
    seq INTEGER PRIMARY KEY,
    cycle INTEGER,
    mono_s REAL NOT NULL,
    wall_s REAL NOT NULL,
    offset_um REAL,
    model_um REAL,
    state TEXT NOT NULL,
    valid INTEGER NOT NULL,
    channels TEXT NOT NULL,
    validity TEXT NOT NULL,
    contributions TEXT NOT NULL,
    attempted_um REAL,
    complete INTEGER
);
CREATE INDEX IF NOT EXISTS samples_wall_s ON samples (wall_s);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS probes (
    seq INTEGER PRIMARY KEY,
    counter REAL,
    value_um REAL,
    measured_um REAL,
    model_um REAL,
    innovation_um REAL,
    innovation_sigma_um REAL,
    accepted INTEGER NOT NULL,
    reason TEXT,
    bias_um REAL,
    bias_sigma_um REAL,
    mode TEXT
);
CREATE TABLE IF NOT EXISTS axes (
    seq INTEGER NOT NULL,
    axis TEXT NOT NULL,
    state TEXT NOT NULL,
    cause TEXT NOT NULL,
    in_force INTEGER NOT NULL,
    value_um REAL,
    value_sent_um REAL,
    value_confirmed_um REAL,
    value_model_um REAL,
    slope_um_m REAL,
    slope_sent_um_m REAL,
    slope_confirmed_um_m REAL,
    slope_model_um_m REAL,
    reference_mm REAL,
    position_mm REAL,
    offset_um REAL,
    PRIMARY KEY (seq, axis)
);
"""

_VIEW = (
    """CREATE VIEW IF NOT EXISTS channel_values (seq, channel, value, validity) AS
       SELECT s.seq, c.key, c.value, w.value
         FROM samples AS s JOIN json_each(s.channels) AS c
         LEFT JOIN json_each(s.validity) AS w ON w.key = c.key""",
    """CREATE TRIGGER IF NOT EXISTS channel_values_insert INSTEAD OF INSERT ON channel_values
       BEGIN SELECT 1; END""",
    """CREATE TRIGGER IF NOT EXISTS channel_values_delete INSTEAD OF DELETE ON channel_values
       BEGIN SELECT 1; END""",
)

#: the columns of ``samples`` every reader needs (a file without one is not a recorder)
SAMPLE_COLUMNS = ("seq", "cycle", "mono_s", "wall_s", "offset_um", "model_um", "state", "valid",
                  "channels", "validity", "contributions")

INSERT_SAMPLE = (f"INSERT INTO samples ({', '.join(SAMPLE_COLUMNS)}, attempted_um, complete)"
                 f" VALUES ({', '.join('?' * (len(SAMPLE_COLUMNS) + 2))})")

#: a probe's columns ([adaptation]): the sample's seq, then `RecordRow.probe`'s fields
PROBE_COLUMNS = ("counter", "value_um", "measured_um", "model_um", "innovation_um",
                 "innovation_sigma_um", "accepted", "reason", "bias_um", "bias_sigma_um", "mode")
INSERT_PROBE = (f"INSERT INTO probes (seq, {', '.join(PROBE_COLUMNS)})"
                f" VALUES ({', '.join('?' * (len(PROBE_COLUMNS) + 1))})")

#: an axis's columns ([output.axes]): the sample's seq, then these
AXIS_COLUMNS = ("axis", "state", "cause", "in_force", "value_um", "value_sent_um",
                "value_confirmed_um", "value_model_um", "slope_um_m", "slope_sent_um_m",
                "slope_confirmed_um_m", "slope_model_um_m", "reference_mm", "position_mm",
                "offset_um")
#: the ``axes`` columns a file of an older compd lacks (added by `upgrade`; NULL in
#: its older rows, and read as NaN from a file not yet upgraded)
AXIS_ADDED_COLUMNS = ("position_mm", "offset_um")
INSERT_AXIS = (f"INSERT INTO axes (seq, {', '.join(AXIS_COLUMNS)})"
               f" VALUES ({', '.join('?' * (len(AXIS_COLUMNS) + 1))})")

#: columns the reader always returns; channel names may not collide with them
FIXED_COLUMNS = ("seq", "cycle", "time_s", "mono_s", "wall_s", "offset_um", "model_um", "valid",
                 "state")

#: keys of table ``meta``
CHANNELS_KEY = "channels"
TERMS_KEY = "terms"


def scan_terms(conn: sqlite3.Connection, max_chars: int | None = None) -> list[str]:
    """Every term named in the rows' contributions, in the order first seen: for a
    file whose ``meta`` has no ``terms`` (an older compd's). One pass over the table
    inside SQLite (bounded memory); rows whose contributions are longer than
    `max_chars` (when given) are passed over. Raises sqlite3.Error on a row that is
    not JSON."""
    rows = conn.execute(
        "SELECT c.key FROM samples AS s JOIN json_each(s.contributions) AS c"
        " WHERE ?1 IS NULL OR length(s.contributions) <= ?1"
        " GROUP BY c.key ORDER BY MIN(s.rowid), MIN(c.id)", (max_chars,)).fetchall()
    return [str(r[0]) for r in rows]


def meta_names(conn: sqlite3.Connection, key: str,
               max_chars: int | None = None) -> list[str] | None:
    """The JSON list of names under `key` in table ``meta``; None when there is none.
    Raises ValueError when it is not a list of names (a file compd did not write), or
    is longer than `max_chars` (when given: read no further)."""
    row = conn.execute("SELECT CASE WHEN ? IS NOT NULL AND length(value) > ? THEN NULL "
                       "ELSE value END, length(value) FROM meta WHERE key = ?",
                       (max_chars, max_chars, key)).fetchone()
    if row is None:
        return None
    if row[0] is None and max_chars is not None and row[1] is not None:
        raise ValueError(f"meta {key!r} is {row[1]} characters long (more than "
                         f"{max_chars // 1024} KiB)")
    try:
        names = json.loads(row[0])
    except (ValueError, TypeError, RecursionError):
        names = None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise ValueError(f"meta {key!r} is not a JSON list of names")
    return names


def upgrade(conn: sqlite3.Connection) -> None:
    """Bring a file of any earlier layout to this one, inside one transaction (the
    writer's connection, in autocommit mode): the tables created, columns added
    since, the old ``channel_values`` table replaced by the view, ``terms`` listed."""
    conn.executescript(SCHEMA)
    conn.execute("BEGIN IMMEDIATE")
    try:
        columns = {r[1] for r in conn.execute("PRAGMA table_info(samples)")}
        if "attempted_um" not in columns:  # a database of an older compd
            conn.execute("ALTER TABLE samples ADD COLUMN attempted_um REAL")
        if "complete" not in columns:  # older rows: NULL (not known)
            conn.execute("ALTER TABLE samples ADD COLUMN complete INTEGER")
        axis_columns = {r[1] for r in conn.execute("PRAGMA table_info(axes)")}
        for name in AXIS_ADDED_COLUMNS:  # older rows: NULL (no position read)
            if name not in axis_columns:
                conn.execute(f"ALTER TABLE axes ADD COLUMN {name} REAL")
        kind = conn.execute("SELECT type FROM sqlite_schema WHERE name = 'channel_values'"
                            ).fetchone()
        if kind is not None and kind[0] == "table":  # the values twice: the JSON has them
            conn.execute("DROP TABLE channel_values")
        for statement in _VIEW:
            conn.execute(statement)
        if conn.execute("SELECT 1 FROM meta WHERE key = ?", (TERMS_KEY,)).fetchone() is None:
            conn.execute("INSERT INTO meta (key, value) VALUES (?, ?)",
                         (TERMS_KEY, json.dumps(scan_terms(conn))))
        conn.execute("COMMIT")
    except BaseException:
        if conn.in_transaction:
            conn.execute("ROLLBACK")
        raise
