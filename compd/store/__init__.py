"""The recorder's database file: its layout and the one reader of it.

Below the faces and the shell, so that everything that reads the recorder reads it
the same way: the writer (`compd.runtime.recorder`) takes the layout from here, the
status page (`compd.faces.status`), `compd export`, `fit` and `replay`
(`compd.offline`) read through `reader.RecorderReader`.

- `schema`  the tables, the statements the writer uses, the upgrade of an older file
- `opening` the file checked (regular, SQLite, the recorder's tables, never a view)
            and opened read-only
- `reader`  the file opened through `opening`, then its rows streamed a bounded
            batch at a time, cut to a wall-clock window
- `columns` a batch's rows as numpy columns; `axis_columns` the per-axis rows'
            columns and their ``<axis>.<column>`` names in an export; `axis_reads`
            the reader's reads of those rows (all at once, or a batch's)
"""
