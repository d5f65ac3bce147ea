"""`compd sim --write-config PATH`: the shipped example config of the protocol,
pointed at the simulated controller this command serves.

The example (`compd/examples/<protocol>.toml`) is copied line by line, its
comments kept, with only what ties it to this server changed: the endpoint
(the port the server took), ``[machine] time_scale`` (``--speedup``), the I/O
timeout when the speed-up makes a cycle shorter than the example's timeout
allows, for FOCAS the stand-in library the server built, and ``[model]
reference``: the simulated plant's rest temperatures for its seed (the state
in which its growth is zero, as a shop's touch-off state), so a daemon that
starts on a plant already warm estimates its state instead of taking the warm
temperatures as zero. Its state
directory is relative (``state-<protocol>``), so it lands beside the written
file: every user and checkout has its own.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

from compd import __version__

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
_HEADER = re.compile(r"^\s*\[([^\]]+)\]\s*(#.*)?$")
_KEY = re.compile(r"^(\s*)([A-Za-z0-9_]+)(\s*=\s*)")


def example_path(protocol: str) -> Path:
    return EXAMPLES / f"{protocol}.toml"


def _replace(text: str, values: dict[tuple[str, str], str]) -> str:
    """`text` with each ``key = …`` line of a (section, key) in `values` replaced
    (the value is TOML text); every one must be found exactly once."""
    section = ""
    seen: set[tuple[str, str]] = set()
    out: list[str] = []
    for line in text.splitlines():
        section = _section(line) or section
        key = _KEY.match(line)
        if key and (section, key.group(2)) in values:
            where = (section, key.group(2))
            if where in seen:
                raise RuntimeError(f"[{section}] {key.group(2)} given twice in the example")
            seen.add(where)
            out.append(f"{key.group(1)}{key.group(2)}{key.group(3)}{values[where]}")
        else:
            out.append(line)
    missing = set(values) - seen
    if missing:
        raise RuntimeError(f"the example lacks {sorted(missing)}")
    return "\n".join(out) + "\n"


def _section(line: str) -> str | None:
    """The table a ``[header]`` line opens, None for any other line."""
    header = _HEADER.match(line)
    return header.group(1).strip() if header else None


def _get(doc: dict[str, Any], section: str, key: str) -> Any:
    table: Any = doc
    for part in section.split("."):
        table = table[part]
    return table[key]


def config_for(protocol: str, endpoint: str, speedup: float, library_path: str | None,
               command: str, rest_c: float | None = None) -> str:
    """The example config of `protocol` for a simulated controller at `endpoint`
    running `speedup` machine seconds per real second; `rest_c`: the plant's rest
    temperature, written as the model's reference (None: a plant-less server)."""
    text = example_path(protocol).read_text(encoding="utf-8")
    doc = tomllib.loads(text)
    period_s = float(doc["machine"]["period_s"])
    timeout_s = min(float(doc["controller"]["timeout_s"]), 0.5 * period_s / speedup)
    values = {("controller", "endpoint"): f'"{endpoint}"',
              ("machine", "time_scale"): f"{float(speedup)!r}",
              ("controller", "timeout_s"): f"{timeout_s!r}"}
    if library_path is not None:
        values[("controller.focas", "library_path")] = f'"{library_path}"'
    body = _replace(text, values)
    if rest_c is not None:
        body = _with_reference(body, doc, rest_c)
    written = tomllib.loads(body)
    for (section, key), value in values.items():  # what was meant is what is read
        if _get(written, section, key) != tomllib.loads(f"v = {value}")["v"]:
            raise RuntimeError(f"[{section}] {key} was not replaced")
    if rest_c is not None and set(written["model"]["reference"].values()) != {rest_c}:
        raise RuntimeError("[model] reference was not written")
    header = (f"# Written by `{command}` (compd {__version__}):\n"
              f"# {example_path(protocol).name} for the simulated controller at {endpoint},\n"
              f"# {speedup:g} machine seconds per real second. Run it with\n"
              f"#   compd run <this file>\n"
              f"# while that compd sim serves. The example's own notes follow.\n#\n")
    return header + body


def _with_reference(body: str, doc: dict[str, Any], rest_c: float) -> str:
    """`body` with ``reference = {…}`` (every relative input channel of the
    example's model at `rest_c`) as the first key of its ``[model]`` table."""
    from compd.infiles import load_model

    if "reference" in doc.get("model", {}):
        raise RuntimeError("the example sets [model] reference itself")
    channels = sorted(load_model(str(doc["model"]["file"])).reference_channels)
    table = ", ".join(f"{ch} = {rest_c!r}" for ch in channels)
    lines = body.splitlines()
    at = next(i for i, line in enumerate(lines) if _section(line) == "model")
    lines[at + 1:at + 1] = [
        "# the simulated plant's rest temperatures (its growth is zero there, as at a",
        "# shop's touch-off): the model's zero, whatever the plant's state at start",
        f"reference = {{ {table} }}"]
    return "\n".join(lines) + "\n"
