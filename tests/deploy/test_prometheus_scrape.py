"""A real Prometheus (Debian's `prometheus`) on 127.0.0.1 scrapes two real
compd metrics endpoints with the example config's relabelling and the alert
rules: each series gets its `machine` label (given, or the target's address),
the rules load and evaluate, a pending alert carries the machine, and the
dashboard's expressions are PromQL it accepts."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import time
import urllib.parse
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.faces.telemetry import Metrics

MONITORING = Path(__file__).resolve().parents[2] / "deploy" / "monitoring"
PROMETHEUS = shutil.which("prometheus")
pytestmark = pytest.mark.skipif(
    PROMETHEUS is None,
    reason="prometheus not found (Debian package `prometheus`; .ci/run installs it)")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def endpoints() -> Iterator[tuple[Metrics, Metrics]]:
    named, unnamed = Metrics(), Metrics()
    for m in (named, unnamed):
        m.configure({"bearing": "degC"}, ["offset"], version="0.1.0", model_sha256="a",
                    config_sha256="b")
        m.period_seconds.set(1.0)
        m.start_http(0)
    named.fault_state.set(2)
    unnamed.fault_state.set(0)
    try:
        yield named, unnamed
    finally:
        named.stop()
        unnamed.stop()


def _config(tmp_path: Path, named: int, unnamed: int) -> Path:
    """The example config, pointed at the two endpoints, scraping every second."""
    cfg = yaml.safe_load((MONITORING / "prometheus.yml").read_text())
    cfg["global"] = {"scrape_interval": "1s", "evaluation_interval": "1s"}
    job = next(j for j in cfg["scrape_configs"] if j["job_name"] == "compd")
    cfg["scrape_configs"] = [job]  # the per-machine job (compd-fleet: a fleet endpoint)
    job["static_configs"] = [
        {"targets": [f"127.0.0.1:{named}"], "labels": {"machine": "mill-1"}},
        {"targets": [f"127.0.0.1:{unnamed}"]},
    ]
    shutil.copy(MONITORING / "compd.rules.yml", tmp_path / "compd.rules.yml")
    out = tmp_path / "prometheus.yml"
    out.write_text(yaml.safe_dump(cfg))
    return out


def _api(port: int, path: str, **query: str) -> Any:
    url = f"http://127.0.0.1:{port}/api/v1/{path}"
    if query:
        url += "?" + urllib.parse.urlencode(query)
    with urllib.request.urlopen(url, timeout=5) as resp:
        body = json.loads(resp.read())
    assert body["status"] == "success", body
    return body["data"]


def _wait(predicate: Any, proc: subprocess.Popen[str], limit_s: float = 60.0) -> Any:
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"prometheus exited {proc.returncode}")
        try:
            value = predicate()
        except OSError:  # not listening yet
            value = None
        if value:
            return value
        time.sleep(0.2)
    pytest.fail("prometheus did not get there")


def test_prometheus_scrapes_compd_with_machine_labels_and_the_rules(
        endpoints: tuple[Metrics, Metrics], tmp_path: Path) -> None:
    named, unnamed = endpoints
    assert named.port is not None and unnamed.port is not None
    config = _config(tmp_path, named.port, unnamed.port)
    web = _free_port()
    assert PROMETHEUS is not None
    proc = subprocess.Popen(
        [PROMETHEUS, f"--config.file={config}", f"--storage.tsdb.path={tmp_path / 'data'}",
         f"--web.listen-address=127.0.0.1:{web}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        series = _wait(lambda: (r := _api(web, "query", query="compd_fault_state"))
                       and len(r["result"]) == 2 and r["result"], proc)
        machines = {s["metric"]["machine"]: float(s["value"][1]) for s in series}
        assert machines == {"mill-1": 2.0, f"127.0.0.1:{unnamed.port}": 0.0}
        groups = _wait(lambda: _api(web, "rules")["groups"], proc)
        rules = {r["name"]: r for g in groups for r in g["rules"]}
        assert len(rules) == 11 and {r["health"] for r in rules.values()} <= {"ok", "unknown"}
        # mill-1 ramps (fault state 2): CompdCompensationNotActive is pending for its
        # minute (firing after it, on a machine slow enough), labelled with the machine
        alerts = _wait(lambda: [a for a in _api(web, "alerts")["alerts"]
                                if a["labels"]["alertname"] == "CompdCompensationNotActive"],
                       proc)
        assert [a["labels"]["machine"] for a in alerts] == ["mill-1"]
        assert alerts[0]["state"] in {"pending", "firing"}
        # neither has completed a cycle (age +Inf > 3 periods): CompdNoSample pends for
        # both, the one without a machine label named by its address
        beats = _wait(lambda: (b := [a for a in _api(web, "alerts")["alerts"]
                                     if a["labels"]["alertname"] == "CompdNoSample"])
                      and len(b) == 2 and b, proc)
        assert {a["labels"]["machine"] for a in beats} == set(machines)
        # every expression of the dashboard is PromQL this Prometheus accepts, and
        # the per-machine ones find mill-1's series
        dashboard = json.loads((MONITORING / "compd-dashboard.json").read_text("utf-8"))
        answered = set()
        for panel in dashboard["panels"]:
            for target in panel.get("targets", []):
                expr = (target["expr"].replace("$machine", "mill-1")
                        .replace("$__rate_interval", "1m"))
                result = _api(web, "query", query=expr)["result"]  # a parse error: 400
                if result:
                    answered.add(panel["title"])
        assert {"Fault state, every machine", "Metrics endpoint up", "Fault state",
                "Last complete cycle", "Recorder", "Build"} <= answered
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        finally:
            if proc.stderr is not None:
                proc.stderr.close()
