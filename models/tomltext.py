"""Write the subset of TOML our files use (model files, generated configs).

Top-level tables become ``[section]`` headers, nested tables ``[a.b]``,
lists of tables ``[[section]]``; tables inside a list or a value (addresses,
term inputs) are written inline. Strings, finite floats (shortest repr, so
they read back bit-for-bit), ints, bools, lists.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from models.errors import ModelError


def value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ModelError(f"cannot write a non-finite number ({v!r}) to TOML")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{key(k)} = {value(x)}" for k, x in v.items()) + " }"
    raise ModelError(f"cannot write {type(v).__name__} to TOML")


def key(k: str) -> str:
    """A bare key when TOML allows one (A-Z a-z 0-9 _ -: ASCII only; ``bearing_µ`` is
    quoted, or the file written could not be read back), else a quoted one."""
    bare = k.replace("_", "").replace("-", "")
    return k if k and (not bare or (bare.isascii() and bare.isalnum())) else value(k)


def _is_table_list(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, Mapping) for x in v)


def _table(lines: list[str], path: list[str], doc: Mapping[str, Any], inline_depth: int) -> None:
    """Scalars of `doc` first, then its sub-tables (headers) and lists of tables."""
    scalars = {k: v for k, v in doc.items()
               if not (isinstance(v, Mapping) and len(path) < inline_depth)
               and not _is_table_list(v)}
    lines += [f"{key(k)} = {value(v)}" for k, v in scalars.items()]
    for k, v in doc.items():
        if isinstance(v, Mapping) and len(path) < inline_depth:
            lines += ["", "[" + ".".join(key(p) for p in [*path, k]) + "]"]
            _table(lines, [*path, k], v, inline_depth)
        elif _is_table_list(v):
            for item in v:
                lines += ["", "[[" + ".".join(key(p) for p in [*path, k]) + "]]"]
                _table(lines, [*path, k], item, 0)


def dumps(doc: Mapping[str, Any], *, header_depth: int = 2) -> str:
    """TOML text; tables nested up to `header_depth` get headers, deeper ones are inline."""
    lines: list[str] = []
    _table(lines, [], doc, header_depth)
    return "\n".join(lines).lstrip("\n") + "\n"
