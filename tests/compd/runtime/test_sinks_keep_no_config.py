"""Sinks keep nothing from open but their resources: the config in force is the
tick's (or the caller's, for a save outside a cycle), and no sink holds another."""

from __future__ import annotations

import ast
from pathlib import Path

import compd.runtime.sinks

SINKS = Path(compd.runtime.sinks.__file__).parent


def _self_attributes_set(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Assign | ast.AnnAssign):
            continue
        targets = node.targets if isinstance(node, ast.Assign) else [node.target]
        for t in targets:
            if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Name) \
                    and t.value.id == "self":
                names.add(t.attr)
    return names


def test_no_sink_keeps_a_config_or_another_sink() -> None:
    kept = {path.name: sorted(n for n in _self_attributes_set(path)
                              if "cfg" in n or "config" in n or n.endswith("sink")
                              or n in {"telemetry", "recorder", "checkpoint", "_last_complete"})
            for path in sorted(SINKS.glob("*.py"))}
    # the recorder sink's `recorder` is its resource, the SQLite recorder it opened
    kept["recorder.py"] = [n for n in kept["recorder.py"] if n != "recorder"]
    assert {name: names for name, names in kept.items() if names} == {}
