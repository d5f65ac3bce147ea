"""Logging: JSON lines off a terminal, key=value on one, secrets redacted
(secret-named keys and registered secret strings, exception text included).
Metrics: served on 127.0.0.1, read back over HTTP, port freed by stop()."""

from __future__ import annotations

import asyncio
import io
import json
import logging
import math
import socket
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog

from compd.faces.telemetry import Metrics, clear_secrets, configure_logging, register_secret
from drivers.sim.modbus_server import ModbusSimController

PASSWORD = "hunter2-Zq9!"


@pytest.fixture(autouse=True)
def _reset_logging() -> Iterator[None]:
    yield
    clear_secrets()
    structlog.reset_defaults()
    root = logging.getLogger()
    for handler in [h for h in root.handlers if h.get_name() == "compd"]:
        root.removeHandler(handler)
    root.setLevel(logging.WARNING)


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def _json_lines(text: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def test_json_lines_on_stderr_when_not_a_tty(capsys: pytest.CaptureFixture[str]) -> None:
    configure_logging()  # captured stderr is not a TTY -> JSON
    log = structlog.get_logger()
    log.info("controller_connected", endpoint="opc.tcp://127.0.0.1:4840", period_s=0.1)
    log.debug("not_shown")
    err = capsys.readouterr().err
    lines = _json_lines(err)
    assert len(lines) == 1
    line = lines[0]
    assert line["event"] == "controller_connected"
    assert line["level"] == "info"
    assert line["period_s"] == 0.1
    assert "timestamp" in line


def test_key_value_on_a_tty() -> None:
    tty = _Tty()
    configure_logging(stream=tty, level="debug")
    structlog.get_logger().debug("cycle_overrun", late_s=0.25)
    out = tty.getvalue()
    assert "cycle_overrun" in out and "late_s=0.25" in out
    with pytest.raises(json.JSONDecodeError):
        json.loads(out)
    # the parameter wins over the stream
    plain = io.StringIO()
    configure_logging(json=False, stream=plain)
    structlog.get_logger().info("started", offset_um=1.5)
    assert "offset_um=1.5" in plain.getvalue()
    forced = _Tty()
    configure_logging(json=True, stream=forced)
    structlog.get_logger().info("started")
    assert _json_lines(forced.getvalue())[0]["event"] == "started"


def test_secret_keys_and_registered_secrets_are_redacted() -> None:
    buf = io.StringIO()
    configure_logging(json=True, stream=buf)
    register_secret(PASSWORD)
    register_secret("")  # ignored, does not redact everything
    log = structlog.get_logger()
    log.info("login", user="operator", password="plain-text-pw", api_token="t0k",
             Credentials={"a": 1})
    log.warning("connect_failed", error=f"BadUserAccessDenied for operator:{PASSWORD}@host",
                nested={"url": f"opc.tcp://operator:{PASSWORD}@127.0.0.1", "ok": 3,
                        "secret_file": "/etc/x"},
                items=[PASSWORD, 2], exc=ValueError(f"bad {PASSWORD}"))
    try:
        raise RuntimeError(f"server said {PASSWORD}")
    except RuntimeError:
        log.exception("write_failed")
    text = buf.getvalue()
    assert PASSWORD not in text and "plain-text-pw" not in text and "t0k" not in text
    first, second, third = _json_lines(text)
    assert first["password"] == "***" and first["api_token"] == "***"
    assert first["Credentials"] == "***" and first["user"] == "operator"
    assert second["error"] == "BadUserAccessDenied for operator:***@host"
    assert second["nested"] == {"url": "opc.tcp://***@127.0.0.1", "ok": 3,
                                "secret_file": "***"}
    assert second["items"] == ["***", 2]
    assert second["exc"] == "bad ***"
    assert "server said ***" in str(third["exception"])


def test_stdlib_records_share_format_and_redaction() -> None:
    buf = io.StringIO()
    configure_logging(json=True, stream=buf)
    register_secret(PASSWORD)
    logging.getLogger("asyncua.client").warning("auth failed with %s", PASSWORD)
    (line,) = _json_lines(buf.getvalue())
    assert line["event"] == "auth failed with ***"
    assert line["logger"] == "asyncua.client" and line["level"] == "warning"


def test_bad_level_refused() -> None:
    with pytest.raises(ValueError, match="level"):
        configure_logging(level="chatty", stream=io.StringIO())


def _scrape(port: int) -> str:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as resp:
        body: bytes = resp.read()
    return body.decode()


def _value(text: str, sample: str) -> float:
    for line in text.splitlines():
        if line.startswith(sample + " "):
            return float(line.split()[-1])
    raise AssertionError(f"{sample} not in metrics:\n{text}")


def test_metrics_over_http_and_port_freed() -> None:
    metrics = Metrics()
    other = Metrics()  # a second instance: own registry, no duplicate-name clash
    metrics.cycle_seconds.observe(0.004)
    metrics.cycle_seconds.observe(0.03)
    metrics.overruns.inc()
    metrics.read_errors.labels(channel="t_spindle_c").inc(2)
    metrics.write_errors.labels(output="z_offset").inc()
    metrics.offset_um.set(-12.5)
    metrics.configure({"t_spindle_c": "degC", "speed": "rpm"}, ["z_offset"],
                      version="0.1.0", model_sha256="ab", config_sha256="cd")
    metrics.channel("t_spindle_c", 31.25)
    metrics.channel("speed", 4000.0)
    metrics.fault_state.set(1)
    metrics.records_dropped.inc(7)
    metrics.certificate_expiry.labels(role="client").set(1.9e9)
    other.offset_um.set(99)
    metrics.start_http(0)
    port = metrics.port
    assert port is not None and port > 0
    try:
        text = _scrape(port)
    finally:
        metrics.stop()
    assert _value(text, "compd_cycle_seconds_count") == 2
    assert _value(text, 'compd_cycle_seconds_bucket{le="0.005"}') == 1
    assert _value(text, "compd_overruns_total") == 1
    assert _value(text, 'compd_read_errors_total{channel="t_spindle_c"}') == 2
    assert _value(text, 'compd_write_errors_total{output="z_offset"}') == 1
    assert _value(text, "compd_offset_micrometres") == -12.5
    assert _value(text, 'compd_channel_temperature_celsius{channel="t_spindle_c"}') == 31.25
    assert _value(text, 'compd_channel_value{channel="speed",unit="rpm"}') == 4000.0
    assert _value(text, "compd_fault_state") == 1
    assert _value(text, "compd_records_dropped_total") == 7
    assert _value(text, 'compd_certificate_expiry_timestamp_seconds{role="client"}') == 1.9e9
    assert _value(text, 'compd_build_info{config_sha256="cd",model_sha256="ab",'
                        'version="0.1.0"}') == 1
    assert metrics.port is None
    # the port is free again: nobody answers, and we can listen on it ourselves
    # (SO_REUSEADDR only for the scrape's TIME_WAIT; Linux still refuses a live listener)
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
        s.listen()
    metrics.stop()  # idempotent
    # and can serve again on the same port
    other.start_http(port)
    try:
        assert _value(_scrape(port), "compd_offset_micrometres") == 99
        with pytest.raises(RuntimeError, match="already"):
            other.start_http(0)
    finally:
        other.stop()


def test_counters_exist_at_zero_and_no_certificate_series_without_one() -> None:
    """An error counter that first appears at 1 is invisible to rate(); a
    certificate gauge at 0 on a Modbus machine fired the expiry alert."""
    from prometheus_client import generate_latest

    m = Metrics()
    m.configure({"bearing": "degC", "ambient": "K"}, ["offset", "heartbeat"],
                version="0.1.0", model_sha256="a", config_sha256="b")
    text = generate_latest(m.registry).decode()
    for sample in ('compd_read_errors_total{channel="bearing"}',
                   'compd_read_errors_total{channel="ambient"}',
                   'compd_write_errors_total{output="offset"}',
                   'compd_write_errors_total{output="heartbeat"}', "compd_overruns_total"):
        assert _value(text, sample) == 0
    assert "compd_certificate_expiry_timestamp_seconds{" not in text
    m.channel("ambient", 293.15)  # kelvin shown in degrees Celsius, the metric's one unit
    text = generate_latest(m.registry).decode()
    assert _value(text, 'compd_channel_temperature_celsius{channel="ambient"}') \
        == pytest.approx(20.0)
    # a reload that drops a channel drops its value series too
    m.configure({"bearing": "degC"}, ["offset"], version="0.1.0", model_sha256="c",
                config_sha256="d")
    text = generate_latest(m.registry).decode()
    assert 'compd_channel_temperature_celsius{channel="ambient"}' not in text
    assert 'compd_channel_temperature_celsius{channel="bearing"}' not in text  # never read
    assert _value(text, 'compd_build_info{config_sha256="d",model_sha256="c",'
                        'version="0.1.0"}') == 1
    assert 'model_sha256="a"' not in text


def test_model_output_and_channel_validity_gauges() -> None:
    """What the dashboard plots beside the offset: the model's own output (NaN
    when it did not step, a gap rather than a stale value) and 1/0 per channel."""
    from prometheus_client import generate_latest

    m = Metrics()
    m.configure({"bearing": "degC", "ambient": "degC"}, ["offset"], version="0.1.0",
                model_sha256="a", config_sha256="b")
    m.model_output(12.25, {"bearing": None, "ambient": "out_of_range"})
    text = generate_latest(m.registry).decode()
    assert _value(text, "compd_model_output_micrometres") == 12.25
    assert _value(text, 'compd_channel_valid{channel="bearing"}') == 1
    assert _value(text, 'compd_channel_valid{channel="ambient"}') == 0
    m.model_output(None, {"bearing": "read_failed", "ambient": "read_failed"})
    text = generate_latest(m.registry).decode()
    assert _value(text, "compd_model_output_micrometres") != _value(
        text, "compd_model_output_micrometres")  # NaN
    assert _value(text, 'compd_channel_valid{channel="bearing"}') == 0
    # a reload that drops a channel drops its validity series
    m.configure({"bearing": "degC"}, ["offset"], version="0.1.0", model_sha256="a",
                config_sha256="b")
    text = generate_latest(m.registry).decode()
    assert 'compd_channel_valid{channel="ambient"}' not in text
    assert 'compd_channel_valid{channel="bearing"}' in text


def test_channel_series_resolved_once_per_configuration(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A cycle sets each channel's value and validity series without `labels()`
    (a hash, a lock and a dict look-up each: 14 calls a cycle for seven channels,
    a measurable share of a 1,000-machine fleet's loop); a reload resolves them
    again, so a dropped series is never written to."""
    from prometheus_client import generate_latest

    m = Metrics()
    m.configure({"bearing": "degC", "ambient": "K", "speed": "rpm"}, ["offset"],
                version="0.1.0", model_sha256="a", config_sha256="b")
    calls: list[str] = []
    for gauge in (m.channel_temperature, m.channel_value, m.channel_valid):
        labels = gauge.labels

        def counted(*args: str, _labels: object = labels, **kw: str) -> object:
            calls.append(kw.get("channel", ""))
            return _labels(*args, **kw)  # type: ignore[operator]

        monkeypatch.setattr(gauge, "labels", counted)

    def cycle(bearing: float) -> None:
        for name, value in (("bearing", bearing), ("ambient", 293.15), ("speed", 1500.0)):
            m.channel(name, value)
        m.model_output(1.0, {"bearing": None, "ambient": None, "speed": "stale"})

    cycle(20.0)
    assert len(calls) == 6
    cycle(21.5)
    cycle(22.5)
    assert len(calls) == 6  # the later cycles resolved nothing
    text = generate_latest(m.registry).decode()
    assert _value(text, 'compd_channel_temperature_celsius{channel="bearing"}') == 22.5
    assert _value(text, 'compd_channel_temperature_celsius{channel="ambient"}') \
        == pytest.approx(20.0)
    assert _value(text, 'compd_channel_value{channel="speed",unit="rpm"}') == 1500.0
    assert _value(text, 'compd_channel_valid{channel="speed"}') == 0
    # a reload that gives speed another unit: its old series goes, the new one is set
    m.configure({"bearing": "degC", "ambient": "K", "speed": "percent"}, ["offset"],
                version="0.1.0", model_sha256="a", config_sha256="b")
    cycle(23.0)
    text = generate_latest(m.registry).decode()
    assert 'compd_channel_value{channel="speed",unit="rpm"}' not in text
    assert _value(text, 'compd_channel_value{channel="speed",unit="percent"}') == 1500.0
    assert _value(text, 'compd_channel_temperature_celsius{channel="bearing"}') == 23.0


async def test_daemon_exports_model_output_and_channel_validity(
        sim: ModbusSimController, tmp_path: Path) -> None:
    from prometheus_client import generate_latest

    from compd.config.loader import load_config
    from compd.runtime.daemon import Daemon
    from compd.runtime.sdnotify import Notifier
    from compd.testing import SteppedClock
    from tests.configs import write_config

    # in lockstep: the daemon cycles only when the clock is stepped (machine
    # seconds, time_scale 1, a request may take half a second of real time), so
    # the metrics read between two steps are those of the cycle just run
    clock = SteppedClock(period_s=1.0)
    daemon = Daemon(load_config(write_config(tmp_path, sim.endpoint, time_scale=1.0,
                                             timeout_s=0.5)),
                    notifier=Notifier(None), clock=clock, sleep=clock.sleep)
    task = asyncio.create_task(daemon.run())

    async def step(periods: int) -> None:
        for _ in range(periods):
            n = clock.sleeps + 1
            clock.tick()
            await clock.cycle_done(n)

    try:
        await clock.cycle_done(1)
        await step(2)
        assert daemon.telemetry.complete_cycles == 3
        text = generate_latest(daemon.metrics.registry).decode()
        last = daemon.loop.last_result
        assert last is not None and last.model_um is not None
        assert _value(text, 'compd_channel_valid{channel="bearing"}') == 1
        assert _value(text, 'compd_channel_valid{channel="ambient"}') == 1
        assert math.isfinite(_value(text, "compd_model_output_micrometres"))
        # period_s 1.0 at time_scale 1: one second of wall clock
        assert _value(text, "compd_period_seconds") == pytest.approx(1.0)
        await sim.publish({"bearing": 200.0})  # beyond the channel's range [-20, 150]
        await step(1)
        last = daemon.loop.last_result
        assert last is not None and last.validity.get("bearing") is not None
        text = generate_latest(daemon.metrics.registry).decode()
        assert _value(text, 'compd_channel_valid{channel="bearing"}') == 0
        assert _value(text, 'compd_channel_valid{channel="ambient"}') == 1
    finally:
        daemon.request_stop()
        assert await asyncio.wait_for(task, 120.0) == 0


def test_the_offset_gauges_help_says_it_is_the_stage_value_not_the_confirmed_one() -> None:
    """``compd_offset_micrometres`` is set from the output stage every cycle, a failed
    write included: its help says so, not "last written" (which reads as what the
    controller holds)."""
    from prometheus_client import generate_latest

    from compd.faces.telemetry import Metrics

    text = generate_latest(Metrics().registry).decode()
    help_line = next(ln for ln in text.splitlines()
                     if ln.startswith("# HELP compd_offset_micrometres "))
    assert "output stage" in help_line and "failed write" in help_line
    assert "last written" not in help_line


def test_the_confirmed_offset_has_its_own_gauge_apart_from_the_one_sent(
        tmp_path: Path) -> None:
    """A failed write: ``compd_offset_micrometres`` shows the stage's value (sent), and
    ``compd_offset_confirmed_micrometres`` what the controller still holds (the last
    confirmed offset); before any confirmed write it is NaN, never a made-up 0."""
    from prometheus_client import generate_latest

    from compd.config.loader import load_config
    from compd.core.cycle import Cycle, params_from_config
    from compd.core.plan import Outcome
    from compd.faces.status import StatusBoard
    from compd.runtime.clock import Clock
    from compd.runtime.journal import Journal
    from compd.runtime.sdnotify import Notifier
    from compd.runtime.sinks.base import Tick
    from compd.runtime.sinks.telemetry import TelemetrySink
    from tests.compd.core.cycle_helpers import samples
    from tests.configs import write_config

    cfg = load_config(write_config(tmp_path, "modbus://127.0.0.1:5020"))
    metrics = Metrics()
    board = StatusBoard()
    clock = Clock(mono=lambda: 0.0, wall=lambda: 1000.0)
    sink = TelemetrySink(metrics=metrics, notifier=Notifier(None), board=board,
                         journal=Journal(logging.getLogger("t"), board, clock), serve=False)
    cycle = Cycle(params_from_config(cfg), cfg.model)

    def gauges() -> tuple[float, float]:
        text = generate_latest(metrics.registry).decode()
        return (_value(text, "compd_offset_micrometres"),
                _value(text, "compd_offset_confirmed_micrometres"))

    controller, t = 0.0, 0.0
    cycle.plan(t, samples(t, 20.0), None)
    row = cycle.commit(Outcome.failed("offset", reason="timed out"))
    sink.feed(Tick(cfg, row, 0.0, None, False, False, cycle))
    assert math.isnan(gauges()[1])
    for k in range(20):
        t += 1.0
        cycle.plan(t, samples(t, 20.0 + 0.4 * k), controller)
        row = cycle.commit()
        controller = row.writes.get("offset", controller)
    sink.feed(Tick(cfg, row, 0.0, None, True, True, cycle))
    sent, confirmed = gauges()
    assert sent == pytest.approx(confirmed) == pytest.approx(controller)
    t += 1.0
    cycle.plan(t, samples(t, 28.0), controller)
    row = cycle.commit(Outcome.failed("offset", reason="timed out"))
    sink.feed(Tick(cfg, row, 0.0, None, False, True, cycle))
    sent, confirmed = gauges()
    assert sent == pytest.approx(row.stage_um) and sent != pytest.approx(controller)
    assert confirmed == pytest.approx(controller)


def test_processes_sharing_one_stderr_never_splice_their_log_lines(tmp_path: Path) -> None:
    """`compd run DIR --workers N`: the parent and its workers write JSON lines to one
    inherited stderr. Each line leaves a process in one write, so however the
    processes interleave, every line of the file is one whole JSON object (print
    writes a message and its newline apart: unbuffered, another process's line
    landed between them)."""
    import subprocess
    import sys

    script = (
        "import sys, structlog\n"
        "from compd.faces.telemetry import configure_logging\n"
        "sys.stderr.reconfigure(write_through=True)\n"
        "configure_logging(json=True, journal=False)\n"
        "log = structlog.get_logger()\n"
        "for i in range(2000):\n"
        "    log.info('daemon_stopped', machine=sys.argv[1], i=i)\n")
    out = tmp_path / "shared.log"
    with out.open("wb") as err:
        procs = [subprocess.Popen([sys.executable, "-c", script, name], stderr=err,
                                  stdout=subprocess.DEVNULL) for name in ("mill-a", "mill-b")]
        for p in procs:
            assert p.wait(timeout=120) == 0
    lines = out.read_text().splitlines()
    assert len(lines) == 4000
    docs = [json.loads(line) for line in lines]  # a spliced line is no JSON
    assert sorted((d["machine"], d["i"]) for d in docs) == sorted(
        (m, i) for m in ("mill-a", "mill-b") for i in range(2000))


def test_axis_series_follow_the_report_and_go_with_a_reloaded_away_axis() -> None:
    """An axis's gauges carry its line; an axis gone from the report (a reload
    without it) loses them, so no stale ``compd_axis_in_force`` 1 claims it."""
    from compd.core.axis_params import AxisRow, ParamRow
    from compd.core.faults import FaultState
    from compd.core.health import Cause

    def row(axis: str, value: float) -> AxisRow:
        return AxisRow(axis=axis, state=FaultState.OK, cause=Cause.IN_FORCE, status=0,
                       value=ParamRow(value, value, value, value),
                       slope=ParamRow(2.0, 2.0, 2.0, 2.0), reference_mm=0.0,
                       in_force=True, inputs_valid=True)

    m = Metrics()

    def sample(name: str, axis: str) -> float | None:
        return m.registry.get_sample_value(name, {"axis": axis})

    m.axes({"x": row("x", 12.0), "y": row("y", -3.0)})
    m.axes({"x": row("x", 12.5), "y": row("y", -3.0)})
    assert sample("compd_axis_value_micrometres", "x") == 12.5
    assert sample("compd_axis_slope_micrometres_per_metre", "y") == 2.0
    assert sample("compd_axis_in_force", "y") == 1.0
    m.axes({"x": row("x", 13.0)})  # y reloaded away
    assert sample("compd_axis_value_micrometres", "x") == 13.0
    for name in ("compd_axis_value_micrometres", "compd_axis_slope_micrometres_per_metre",
                 "compd_axis_in_force", "compd_axis_fault_state"):
        assert sample(name, "y") is None
    m.axes({})  # a reload without [output.axes]
    assert sample("compd_axis_in_force", "x") is None


def test_an_axis_series_is_set_only_when_its_value_changes(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Every cycle reports every axis; a series whose value is the same as last
    cycle's is not set again (a set takes its lock), and one that changed is."""
    import prometheus_client

    from compd.core.axis_params import AxisRow, ParamRow
    from compd.core.faults import FaultState
    from compd.core.health import Cause

    def row(value: float, state: FaultState = FaultState.OK) -> AxisRow:
        return AxisRow(axis="x", state=state, cause=Cause.IN_FORCE, status=0,
                       value=ParamRow(value, value, value, value),
                       slope=ParamRow(2.0, 2.0, 2.0, 2.0), reference_mm=0.0,
                       in_force=True, inputs_valid=True)

    m = Metrics()
    m.axes({"x": row(12.0)})
    sets: list[float] = []
    real = prometheus_client.Gauge.set

    def counted(self: prometheus_client.Gauge, value: float) -> None:
        sets.append(value)
        real(self, value)

    monkeypatch.setattr(prometheus_client.Gauge, "set", counted)
    m.axes({"x": row(12.0)})
    assert sets == []
    m.axes({"x": row(12.5, FaultState.HOLD)})
    assert sorted(sets) == [float(FaultState.HOLD.gauge), 12.5]
    assert m.registry.get_sample_value("compd_axis_value_micrometres", {"axis": "x"}) == 12.5
    assert m.registry.get_sample_value("compd_axis_slope_micrometres_per_metre",
                                       {"axis": "x"}) == 2.0
    assert m.registry.get_sample_value("compd_axis_fault_state", {"axis": "x"}) == 1.0
