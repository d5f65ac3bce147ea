"""Every mistake of a config at once, each with its key path, and a "did you
mean" for an unknown key (the closest known key at that place, by difflib).

`errors_of(exc, root)` turns a pydantic ValidationError into ``(key, reason)``
pairs; the known keys are read from the pydantic models of
`compd.config.schema` along the error's path (a table of channels skips the
channel's own name, a union offers every branch's keys).
"""

from __future__ import annotations

import difflib
import types
import typing
from typing import Any

from pydantic import BaseModel, ValidationError


def _models(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation may hold (through Optional, unions,
    Annotated); for dict/list/tuple the element's."""
    origin = typing.get_origin(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    if origin is typing.Annotated:
        return _models(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return [m for a in typing.get_args(annotation) for m in _models(a)]
    return []


def _element(annotation: Any) -> Any:
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _element(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        return _element(args[0]) if len(args) == 1 else annotation
    if origin in (dict, list, tuple):
        return typing.get_args(annotation)[-1]
    return annotation


def known_keys(root: type[BaseModel], loc: tuple[int | str, ...]) -> list[str]:
    """The keys allowed in the table at `loc` (the unknown key's parents)."""
    level: list[Any] = [root]
    for part in loc:
        nxt: list[Any] = []
        for item in level:
            models = _models(item)
            if not models:  # a dict/list level: the part is a name or an index
                nxt.append(_element(item))
                continue
            for model in models:
                field = model.model_fields.get(str(part))
                if field is not None:
                    nxt.append(field.annotation)
        level = nxt
    return sorted({k for item in level for m in _models(item) for k in m.model_fields})


def did_you_mean(key: str, known: list[str]) -> str:
    close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def errors_of(exc: ValidationError, root: type[BaseModel] | None,
              reason: typing.Callable[[Any], str]) -> list[tuple[tuple[int | str, ...], str]]:
    """Each error's path (tagged-union branch names dropped) and reason."""
    out: list[tuple[tuple[int | str, ...], str]] = []
    for err in exc.errors(include_url=False):
        loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and p[:1].isupper()))
        why = reason(err)
        if err.get("type") == "extra_forbidden" and root is not None and loc:
            why += did_you_mean(str(loc[-1]), known_keys(root, loc[:-1]))
        out.append((loc, why))
    return out
