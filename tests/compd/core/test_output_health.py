"""The output's health owns its transitions: each change of its state is one of
its methods, and nothing else in the core writes its fields."""

from __future__ import annotations

import ast
from pathlib import Path

import compd.core
from compd.core.events import Event
from compd.core.faults import FaultState
from compd.core.health import OutputHealth

CORE = Path(compd.core.__file__).parent


def test_nothing_in_the_core_but_the_health_writes_its_fields() -> None:
    """`x.health.field = ...` (or `+=`) anywhere in compd/core is a transition the
    state machine does not own."""
    writes = []
    for path in sorted(CORE.rglob("*.py")):
        if path.name == "health.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.Assign | ast.AugAssign | ast.AnnAssign):
                continue
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Attribute) \
                        and t.value.attr == "health":
                    writes.append(f"{path.name}:{node.lineno} .health.{t.attr}")
    assert writes == []


def test_a_foreign_read_back_is_alarmed_until_the_output_has_settled() -> None:
    h = OutputHealth(30.0)
    h.foreign_settled(moving=True)
    assert not h.foreign  # nothing seen: nothing to settle
    h.foreign_seen()
    h.foreign_settled(moving=True)
    assert h.foreign  # still ramping back: still alarmed
    h.foreign_settled(moving=False)
    assert not h.foreign


def test_the_model_range_is_a_latch_told_once_each_way() -> None:
    h, events = OutputHealth(30.0), list[Event]()
    assert h.model_in_range(10.0, 500.0, events) and events == []
    assert not h.model_in_range(600.0, 500.0, events)
    assert not h.model_in_range(-700.0, 500.0, events)
    assert h.model_in_range(1.0, 500.0, events)
    assert [e.name for e in events] == ["model_out_of_range", "model_in_range"]
    assert h.model_range is False


def test_the_operators_hold_and_the_shutdown_are_transitions_of_their_own() -> None:
    h, events = OutputHealth(30.0), list[Event]()
    assert h.set_operator_hold(True) and not h.set_operator_hold(True)
    assert h.operator_hold and h.set_operator_hold(False) and not h.operator_hold
    h.begin_shutdown()
    decision = h.decide(1.0, None, 12.0, events)
    assert decision.state == FaultState.SHUTDOWN and decision.target_um == 0.0
    assert [e.name for e in events] == ["shutdown_ramp_to_zero"]
