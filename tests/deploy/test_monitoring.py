"""deploy/monitoring/: the alert rules pass promtool's check and their unit
tests (Debian package `prometheus`), and the dashboard and the rules use only
metrics that compd exports (`compd.faces.telemetry.Metrics`)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.faces.telemetry import Metrics

REPO = Path(__file__).resolve().parents[2]
MONITORING = REPO / "deploy" / "monitoring"
RULES = MONITORING / "compd.rules.yml"
RULE_TESTS = MONITORING / "compd.rules.test.yml"
DASHBOARD = MONITORING / "compd-dashboard.json"

PROMTOOL = shutil.which("promtool")
needs_promtool = pytest.mark.skipif(
    PROMTOOL is None,
    reason="promtool not found (Debian package `prometheus`; .ci/run installs it)")

#: a metric name in an expression (not a label value: those are inside quotes)
_NAME = re.compile(r"\bcompd_[a-z0-9_]+\b")
_SUFFIXES = {"counter": ("_total",), "histogram": ("_bucket", "_count", "_sum"),
             "info": ("_info",), "gauge": ("",)}


def exported_names() -> set[str]:
    """Every series name compd's `Metrics` can expose."""
    names: set[str] = set()
    for family in Metrics().registry.collect():
        names |= {family.name + suffix for suffix in _SUFFIXES[family.type]}
    return names


def _promtool(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    assert PROMTOOL is not None
    return subprocess.run([PROMTOOL, *args], capture_output=True, text=True, timeout=120,
                          check=False, cwd=cwd)


def _panels(panels: list[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    for p in panels:
        yield p
        yield from _panels(p.get("panels", []))


def dashboard_exprs(dashboard: dict[str, Any]) -> list[str]:
    exprs = [t["expr"] for p in _panels(dashboard["panels"]) for t in p.get("targets", [])]
    exprs += [v["query"]["query"] for v in dashboard["templating"]["list"]
              if isinstance(v.get("query"), dict)]
    return exprs


def rule_exprs() -> list[str]:
    groups = yaml.safe_load(RULES.read_text())["groups"]
    return [r["expr"] for g in groups for r in g["rules"]]


def test_exported_names_are_what_prometheus_sees() -> None:
    names = exported_names()
    assert {"compd_offset_micrometres", "compd_overruns_total", "compd_cycle_seconds_bucket",
            "compd_build_info", "compd_model_output_micrometres",
            "compd_channel_valid"} <= names
    assert "compd_overruns" not in names  # a counter is only seen with _total


def test_dashboard_parses_and_uses_only_exported_metrics() -> None:
    dashboard = json.loads(DASHBOARD.read_text(encoding="utf-8"))
    exprs = dashboard_exprs(dashboard)
    used = {name for e in exprs for name in _NAME.findall(e)}
    assert used - exported_names() == set()
    # what the dashboard is for: one row per machine through the `machine` variable
    variables = {v["name"]: v for v in dashboard["templating"]["list"]}
    assert variables["machine"]["multi"] and variables["machine"]["includeAll"]
    rows = [p for p in dashboard["panels"] if p["type"] == "row"]
    assert [r.get("repeat") for r in rows] == ["machine"]
    for name in ("compd_offset_micrometres", "compd_model_output_micrometres",
                 "compd_fault_state", "compd_channel_valid", "compd_cycle_seconds_bucket",
                 "compd_overruns_total", "compd_recorder_alarm",
                 "compd_records_dropped_total"):
        assert name in used, name
    # every panel after the repeated row is about that one machine
    after = dashboard["panels"][dashboard["panels"].index(rows[0]) + 1:]
    assert after and all('machine="$machine"' in t["expr"] for p in after
                         for t in p["targets"])
    ids = [p["id"] for p in _panels(dashboard["panels"])]
    assert len(ids) == len(set(ids))


def test_rules_use_only_exported_metrics_and_name_the_machine() -> None:
    exprs = rule_exprs()
    used = {name for e in exprs for name in _NAME.findall(e)}
    assert used - exported_names() == set()
    assert used == {"compd_fault_state", "compd_last_complete_cycle_age_seconds",
                    "compd_period_seconds", "compd_recorder_alarm",
                    "compd_records_dropped_total", "compd_overruns_total",
                    "compd_certificate_expiry_timestamp_seconds", "compd_probes_total",
                    "compd_model_worse_than_none", "compd_offset_not_in_force"}
    for group in yaml.safe_load(RULES.read_text())["groups"]:
        for rule in group["rules"]:
            assert "machine" in rule["labels"], rule["alert"]
            assert rule["annotations"]["summary"] and rule["annotations"]["description"]


def test_the_name_check_is_not_vacuous() -> None:
    assert _NAME.findall('rate(compd_overrun_total{machine="compd_x"}[5m])') == [
        "compd_overrun_total", "compd_x"]
    assert "compd_overrun_total" not in exported_names()


@needs_promtool
def test_promtool_checks_the_rules() -> None:
    proc = _promtool("check", "rules", RULES.name, cwd=MONITORING)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "SUCCESS: 11 rules found" in proc.stdout


@needs_promtool
def test_promtool_unit_tests_of_the_rules_pass() -> None:
    proc = _promtool("test", "rules", RULE_TESTS.name, cwd=MONITORING)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "SUCCESS" in proc.stdout


@needs_promtool
def test_promtool_unit_tests_catch_a_changed_rule(tmp_path: Path) -> None:
    # the unit tests bite: an alert that waits 10 minutes instead of 1 fails them
    rules = RULES.read_text()
    changed = rules.replace("expr: compd_fault_state >= 2\n        for: 1m",
                            "expr: compd_fault_state >= 2\n        for: 10m")
    assert changed != rules
    (tmp_path / RULES.name).write_text(changed)
    shutil.copy(RULE_TESTS, tmp_path / RULE_TESTS.name)
    proc = _promtool("test", "rules", RULE_TESTS.name, cwd=tmp_path)
    assert proc.returncode != 0
    assert "CompdCompensationNotActive" in proc.stdout + proc.stderr


@needs_promtool
def test_promtool_checks_the_example_prometheus_config() -> None:
    proc = _promtool("check", "config", "prometheus.yml", cwd=MONITORING)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "SUCCESS: 11 rules found" in proc.stdout  # it loads compd.rules.yml
