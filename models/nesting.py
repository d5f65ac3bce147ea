"""TOML and JSON text read with its nesting bounded (pure; no I/O).

`tomllib` and `json` parse nested arrays and tables by recursion: a file of
``a = [[[[…]]]]`` some 900 levels deep ends a command in a `RecursionError`
(a traceback, not a refusal). No model, config, drive map or checkpoint of
compd nests deeper than a few levels, so the text is scanned first (brackets
and braces outside strings and comments, one pass, no recursion) and
refused beyond `MAX_NESTING`; the parsed document is measured again
(dotted keys and table headers nest without brackets), and a
`RecursionError` that still happens is turned into the same refusal.
Every refusal is one `NestingError` (a ValueError) saying how deep.
"""

from __future__ import annotations

import json
import re
import tomllib
from collections.abc import Callable
from typing import Any

#: deeper than any file compd reads (a config nests 4 levels, a model 3)
MAX_NESTING = 32


class NestingError(ValueError):
    """The text nests arrays and tables (objects) too deep to be read."""


#: the next character that matters to the scan outside a string (TOML, JSON), and
#: inside one (basic strings escape with a backslash, literal ones do not)
_TOML_MARK = re.compile(r"""[\[\]{}"'#]""")
_JSON_MARK = re.compile(r"""[\[\]{}"]""")
_BASIC_END = re.compile(r"""["\\\n]""")
_LITERAL_END = re.compile(r"""['\n]""")
_LONG_BASIC_END = re.compile(r'''"""|\\''')
_LONG_LITERAL_END = re.compile(r"""'''""")


def _skip_string(text: str, i: int, quote: str) -> int:
    """The index after the string that opens at `i` (one quote or three)."""
    n = len(text)
    if text.startswith(quote * 3, i):
        end = _LONG_BASIC_END if quote == '"' else _LONG_LITERAL_END
        i += 3
        while (m := end.search(text, i)) is not None:
            if m.group() == "\\":
                i = m.end() + 1  # past the escaped character
                continue
            i = m.end()
            extra = 0
            while i < n and text[i] == quote and extra < 2:  # """a"""" ends in a quote
                i += 1
                extra += 1
            return i
        return n
    end = _BASIC_END if quote == '"' else _LITERAL_END
    i += 1
    while (m := end.search(text, i)) is not None:
        if m.group() == "\\":
            i = m.end() + 1
            continue
        return m.end()  # the closing quote, or the line's end (an unclosed string)
    return n


def text_depth(text: str, *, toml: bool = True, stop_at: int | None = None) -> int:
    """The deepest nesting of brackets and braces outside strings (and, in
    TOML, comments); scanning stops once it passes `stop_at`."""
    mark = _TOML_MARK if toml else _JSON_MARK
    depth = deepest = 0
    i, n = 0, len(text)
    while (m := mark.search(text, i)) is not None:
        i = m.start()
        c = text[i]
        if c in "[{":
            depth += 1
            if depth > deepest:
                deepest = depth
                if stop_at is not None and deepest > stop_at:
                    return deepest
        elif c in "]}":
            depth = max(depth - 1, 0)
        elif c in "\"'":
            i = _skip_string(text, i, c)
            continue
        else:  # a TOML comment, to the line's end
            end = text.find("\n", i)
            i = n if end < 0 else end
            continue
        i += 1
    return deepest


def document_depth(doc: object) -> int:
    """How deep tables and arrays nest in a parsed document (its root is 0)."""
    deepest = 0
    stack: list[tuple[object, int]] = [(doc, 0)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict):
            children: Any = node.values()
        elif isinstance(node, list):
            children = node
        else:
            continue
        for child in children:
            if isinstance(child, dict | list):
                deepest = max(deepest, depth + 1)
                stack.append((child, depth + 1))
    return deepest


def _too_deep(depth: int, max_depth: int) -> NestingError:
    levels = f"{depth}" if depth <= 10 * max_depth else f"more than {10 * max_depth}"
    return NestingError(f"arrays and tables nested {levels} levels deep; at most "
                        f"{max_depth} are accepted")


def _bounded(parse: Callable[[str], Any], text: str, *, toml: bool, max_depth: int) -> Any:
    depth = text_depth(text, toml=toml, stop_at=10 * max_depth)
    if depth > max_depth:
        raise _too_deep(depth, max_depth)
    try:
        doc = parse(text)
    except RecursionError:  # the last resort: the scan above should have refused it
        raise NestingError(f"arrays and tables nested too deep to parse; at most "
                           f"{max_depth} levels are accepted") from None
    depth = document_depth(doc)
    if depth > max_depth:
        raise _too_deep(depth, max_depth)
    return doc


def loads_toml(text: str, max_depth: int = MAX_NESTING) -> dict[str, Any]:
    """`tomllib.loads` with the nesting bounded (NestingError); a syntax
    error propagates as tomllib raised it (TOMLDecodeError)."""
    doc: dict[str, Any] = _bounded(tomllib.loads, text, toml=True, max_depth=max_depth)
    return doc


def loads_json(text: str, max_depth: int = MAX_NESTING,
               parse: Callable[[str], Any] = json.loads) -> Any:
    """`json.loads` (or `parse`) with the nesting bounded; a syntax error
    propagates as the parser raised it (json.JSONDecodeError)."""
    return _bounded(parse, text, toml=False, max_depth=max_depth)
