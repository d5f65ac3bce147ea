"""The HTTP faces' bounded server: a fixed number of threads
whatever the clients do, slow request heads closed after the header timeout,
idle kept-alive connections after the idle timeout, a cap on connections that
still lets a scrape in, a cap on the request head, and no traceback ever.

Time is a `FakeClock` moved by the test (`HttpServer.wake` makes the I/O
thread look at it); waits are on conditions (an answer, an end of file), the
timeouts only a safety net."""

from __future__ import annotations

import http.client
import socket
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import pytest

from compd.faces.http_server import HttpLimits, HttpServer, limits_from
from compd.faces.telemetry import Metrics
from compd.testing import FakeClock
from drivers.sim.modbus_server import ModbusSimController

SAFETY_S = 30.0


def _wait_for(condition: Callable[[], bool], what: str) -> None:
    """Until `condition()` (polled); fails after SAFETY_S, a net for a hung server."""
    give_up = time.monotonic() + SAFETY_S
    while not condition():
        if time.monotonic() > give_up:
            pytest.fail(f"never: {what}")
        time.sleep(0.005)


def _hello(environ: dict[str, Any], start_response: Callable[..., Any]) -> list[bytes]:
    body = f"hello {environ['PATH_INFO']}\n".encode()
    start_response("200 OK", [("Content-Type", "text/plain"),
                              ("Content-Length", str(len(body)))])
    return [body]


@contextmanager
def _server(app: Callable[..., Any] = _hello, limits: HttpLimits | None = None,
            clock: Callable[[], float] = time.monotonic) -> Iterator[HttpServer]:
    server = HttpServer(app, "127.0.0.1", 0, limits, clock=clock)
    server.start()
    try:
        yield server
    finally:
        server.stop()


def _get(port: int, path: str = "/") -> tuple[int, bytes]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=SAFETY_S) as resp:
        return resp.status, resp.read()


def _raw(port: int, data: bytes) -> bytes:
    """Send `data`, read until the server closes."""
    with socket.create_connection(("127.0.0.1", port), timeout=SAFETY_S) as s:
        s.sendall(data)
        out = b""
        while chunk := s.recv(65536):
            out += chunk
        return out


def _closed_by_server(s: socket.socket) -> bool:
    """True when the server has closed `s` (end of file; blocks until it has)."""
    s.settimeout(SAFETY_S)
    try:
        return s.recv(1) == b""
    except ConnectionResetError:
        return True


def _partial(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=SAFETY_S)
    s.sendall(b"GET /metrics HTTP/1.1\r\nHost: x\r\n")  # never the blank line
    return s


def test_thread_count_does_not_grow_with_connections() -> None:
    """800 slowloris sockets made 803 threads: now the server's threads are
    started once and every connection lives in one selector."""
    metrics = Metrics()
    metrics.start_http(0)
    port = metrics.port
    assert port is not None
    before = threading.active_count()
    try:
        with ExitStack() as stack:
            sockets = [stack.enter_context(_partial(port)) for _ in range(150)]
            # /metrics still answers; its connection came after the 150, so they are
            # all accepted by the time it is answered
            status, body = _get(port, "/metrics")
            assert status == 200 and b"compd_offset_micrometres" in body
            assert threading.active_count() == before
            server = metrics.http_server
            assert server is not None
            assert server.counts["evicted"] >= len(sockets) - 64
            assert server.open_connections <= 64  # the default cap
    finally:
        metrics.stop()
    assert metrics.port is None


def test_a_slow_head_is_closed_after_the_header_timeout() -> None:
    clock = FakeClock(start_s=100.0)
    with _server(limits=HttpLimits(header_timeout_s=5.0), clock=clock) as server:
        with _partial(server.port) as slow:
            _wait_for(lambda: server.open_connections == 1, "the connection accepted")
            clock.advance(4.0)
            slow.sendall(b"X-Trickle: 1\r\n")  # a byte now and then buys no time
            server.wake()
            # a full request answered after the wake: the loop has seen 104 s
            assert _get(server.port, "/a") == (200, b"hello /a\n")
            assert server.counts["header_timeout"] == 0
            clock.advance(1.5)
            server.wake()
            assert _closed_by_server(slow)
        assert server.counts["header_timeout"] == 1
        _wait_for(lambda: server.open_connections == 0, "the connection forgotten")


def test_an_idle_kept_alive_connection_is_closed_after_the_idle_timeout() -> None:
    clock = FakeClock()
    limits = HttpLimits(header_timeout_s=2.0, idle_timeout_s=30.0)
    with _server(limits=limits, clock=clock) as server:
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=SAFETY_S)
        for path in ("/one", "/two"):  # two requests on one connection (keep-alive)
            conn.request("GET", path)
            resp = conn.getresponse()
            assert (resp.status, resp.read()) == (200, f"hello {path}\n".encode())
        _wait_for(lambda: server.served == 2, "the second answer counted")
        assert server.open_connections == 1
        sock = conn.sock
        assert sock is not None
        clock.advance(10.0)  # past the header timeout: an idle connection is not a slow head
        server.wake()
        assert _get(server.port) == (200, b"hello /\n")
        assert server.counts["header_timeout"] == 0 and server.counts["idle_timeout"] == 0
        clock.advance(25.0)
        server.wake()
        assert _closed_by_server(sock)
        assert server.counts["idle_timeout"] == 1
        conn.close()


def test_at_the_cap_the_oldest_waiting_connection_makes_room_for_a_scrape() -> None:
    metrics = Metrics()
    metrics.start_http(0, limits=HttpLimits(max_connections=4))
    port = metrics.port
    server = metrics.http_server
    assert port is not None and server is not None
    try:
        with ExitStack() as stack:
            first = stack.enter_context(_partial(port))
            _wait_for(lambda: server.open_connections == 1, "the first accepted")
            others = [stack.enter_context(_partial(port)) for _ in range(3)]
            _wait_for(lambda: server.open_connections == 4, "the cap reached")
            status, body = _get(port, "/metrics")
            assert status == 200
            assert 'compd_http_limited_total{reason="evicted"} 1.0' in body.decode()
            assert _closed_by_server(first)  # the one that waited longest
            for s in others:
                s.setblocking(False)
                with pytest.raises(BlockingIOError):
                    s.recv(1)  # still open: nothing to read, no end of file
    finally:
        metrics.stop()


def test_when_every_connection_is_being_answered_a_new_one_gets_503() -> None:
    release = threading.Event()
    entered = threading.Semaphore(0)

    def slow(environ: dict[str, Any], start_response: Callable[..., Any]) -> list[bytes]:
        entered.release()
        release.wait(SAFETY_S)
        return _hello(environ, start_response)

    with _server(slow, HttpLimits(max_connections=2, workers=2)) as server:
        answers: list[tuple[int, bytes]] = []
        clients = [threading.Thread(target=lambda: answers.append(_get(server.port)))
                   for _ in range(2)]
        for t in clients:
            t.start()
        for _ in range(2):
            assert entered.acquire(timeout=SAFETY_S)
        reply = _raw(server.port, b"")  # (a request unread at the close: a reset)
        assert reply.startswith(b"HTTP/1.1 503 ")
        assert server.counts["refused"] == 1
        release.set()
        for t in clients:
            t.join(SAFETY_S)
        assert answers == [(200, b"hello /\n")] * 2


def test_bad_heads_are_answered_and_closed_without_a_traceback(
        capsys: pytest.CaptureFixture[str]) -> None:
    def broken(environ: dict[str, Any], start_response: Callable[..., Any]) -> list[bytes]:
        if environ["PATH_INFO"] == "/boom":
            raise ZeroDivisionError("boom")
        return _hello(environ, start_response)

    with _server(broken, HttpLimits(max_head_bytes=1024)) as server:
        port = server.port
        big = b"GET / HTTP/1.1\r\n" + b"X-Big: " + b"y" * 2000 + b"\r\n\r\n"
        assert _raw(port, big).startswith(b"HTTP/1.1 431 ")
        assert _raw(port, b"GET /" + b"x" * 2000 + b" HTTP/1.1\r\n\r\n").startswith(
            b"HTTP/1.1 414 ")
        for garbage in (b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03\r\n\r\n",
                        b"GET / HTTP/9.9\r\n\r\n", b"GET / HTTP/1.1\r\nno colon\r\n\r\n",
                        b"GET / HTTP/1.1\r\nContent-Length: -1\r\n\r\n"):
            assert _raw(port, garbage).startswith(b"HTTP/1.1 400 "), garbage
        assert _raw(port, b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n"
                    ).startswith(b"HTTP/1.1 501 ")
        assert _raw(port, b"POST / HTTP/1.1\r\nContent-Length: 99999\r\n\r\n"
                    ).startswith(b"HTTP/1.1 413 ")
        assert _raw(port, b"GET /boom HTTP/1.1\r\n\r\n").startswith(b"HTTP/1.1 500 ")
        # HEAD: the length of the body, not the body
        head = _raw(port, b"HEAD /x HTTP/1.0\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 200 ") and head.endswith(b"\r\n\r\n")
        assert b"Content-Length: 9\r\n" in head
        assert _get(port, "/still") == (200, b"hello /still\n")
        assert server.counts["bad_request"] == 4 and server.counts["app_error"] == 1
        assert server.counts["head_too_large"] == 2
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err


def test_log_lines_are_rate_limited() -> None:
    import structlog.testing

    clock = FakeClock()
    with structlog.testing.capture_logs() as logs, _server(clock=clock) as server:
        for _ in range(5):
            _raw(server.port, b"BAD\r\n\r\n")
        clock.advance(61.0)
        _raw(server.port, b"BAD\r\n\r\n")
    lines = [e for e in logs if e["event"] == "http_connection_limited"]
    assert [(e["reason"], e["more_since_last"]) for e in lines] == [
        ("bad_request", 0), ("bad_request", 4)]


def test_the_limits_come_from_the_telemetry_section(tmp_path: Path) -> None:
    from compd.config.loader import load_config
    from compd.errors import ConfigError
    from compd.runtime.reload import diff
    from tests.configs import write_config

    path = write_config(tmp_path, "modbus://127.0.0.1:1502")
    old = load_config(path)
    assert limits_from(old.raw.telemetry) == HttpLimits()
    text = path.read_text()
    path.write_text(text.replace("[telemetry]\n", "[telemetry]\nmetrics_max_connections = 8\n"
                                 "metrics_header_timeout_s = 2.5\n"
                                 "metrics_idle_timeout_s = 10\n"))
    new = load_config(path)
    assert limits_from(new.raw.telemetry) == HttpLimits(max_connections=8,
                                                        header_timeout_s=2.5,
                                                        idle_timeout_s=10.0)
    assert diff(old, new).metrics  # a reload restarts the server with its new bounds
    path.write_text(text.replace("[telemetry]\n", "[telemetry]\nmetrics_max_connections = 0\n"))
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.key == "telemetry.metrics_max_connections"


_LOW_NOFILE_SERVER = """
import json, resource, sys
from compd.faces.http_server import HttpLimits, HttpServer
resource.setrlimit(resource.RLIMIT_NOFILE, (40, 40))
box = {}
def app(environ, start_response):
    body = json.dumps(box["server"].counts).encode()
    start_response("200 OK", [("Content-Type", "application/json")])
    return [body]
box["server"] = server = HttpServer(app, "127.0.0.1", 0, HttpLimits(max_connections=500))
server.start()
print(server.port, flush=True)
sys.stdin.read()
server.stop()
"""


def test_out_of_file_descriptors_pauses_accepting_without_a_traceback() -> None:
    """Past the process's descriptor limit (NOFILE), accept fails with EMFILE:
    counted, the oldest waiting connection closed, no busy loop, no traceback;
    the server answers again once descriptors are free."""
    import json
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", _LOW_NOFILE_SERVER], text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stdin is not None
    try:
        port = int(proc.stdout.readline())
        with ExitStack() as stack:
            for _ in range(60):  # more than 40 descriptors' worth
                stack.enter_context(_partial(port))
            # its log line (structlog's default: stdout), once and not a line per accept
            while "accept_failed" not in (line := proc.stdout.readline()):
                assert line, "the server ended"
        status, body = _get(port, "/counts")
        assert status == 200
        assert json.loads(body)["accept_failed"] >= 1
    finally:
        out, err = proc.communicate("", timeout=SAFETY_S)
    assert proc.returncode == 0
    assert "accept_failed" not in out  # rate-limited: one line a minute
    assert "Traceback" not in out + err


async def test_a_daemon_at_its_connection_cap_is_still_healthy_by_url(
        sim: ModbusSimController, tmp_path: Path) -> None:
    """`[telemetry] metrics_max_connections` reaches the daemon's server: with the
    cap filled by sockets that never finish a head, `compd health --url` and the
    page still answer, and the cycle goes on."""
    import argparse
    import asyncio

    from compd.commands import health
    from compd.config.loader import load_config
    from compd.runtime.daemon import Daemon
    from compd.runtime.sdnotify import Notifier
    from drivers.sim.ports import free_tcp_port
    from tests.compd.faces.status_helpers import get
    from tests.configs import write_config
    from tests.harness import healthy_within, until

    path = write_config(tmp_path, sim.endpoint, time_scale=10.0)
    port = free_tcp_port("127.0.0.1")
    path.write_text(path.read_text() + f"metrics_port = {port}\nmetrics_max_connections = 3\n"
                    "\n[faces.http]\nenabled = true\n", encoding="utf-8")
    daemon = Daemon(load_config(path), notifier=Notifier(None))
    task = asyncio.create_task(daemon.run())
    try:
        await until(lambda: daemon.telemetry.complete_cycles >= 3 or task.done())
        server = daemon.metrics.http_server
        assert server is not None and server.limits.max_connections == 3
        with ExitStack() as stack:
            for _ in range(10):
                stack.enter_context(_partial(port))
            await until(lambda: server.counts["evicted"] >= 7)
            assert server.open_connections == 3
            args = argparse.Namespace(url=f"http://127.0.0.1:{port}/metrics", state_dir=None,
                                      max_age_s=60.0, timeout_s=5.0)
            assert await healthy_within(lambda: health.run(args),
                                        lambda: daemon.telemetry.complete_cycles) == 0
            code, _, _ = await asyncio.to_thread(get, f"http://127.0.0.1:{port}/")
            assert code == 200
            before = daemon.telemetry.complete_cycles
            await until(lambda: daemon.telemetry.complete_cycles >= before + 3)
    finally:
        daemon.request_stop()
        assert await asyncio.wait_for(task, 20.0) == 0


def test_a_head_is_parsed_when_whole_and_taken_off_the_buffer() -> None:
    from compd.faces.http_wire import BadRequest, environ, parse_request

    buf = bytearray(b"GET /status.json?x=1 HTTP/1.1\r\nHost: a\r\nAccept: text/plain\r\n")
    assert parse_request(buf, 1024) is None  # no blank line yet
    buf += b"Accept: */*\r\n\r\nGET /metrics HTTP/1.0\r\n\r\n"  # and a second one behind
    first = parse_request(buf, 1024)
    assert first is not None and first.keep_alive  # HTTP/1.1: kept alive by default
    env = environ(first, "127.0.0.1", 9105, "127.0.0.1")
    assert (env["PATH_INFO"], env["QUERY_STRING"], env["HTTP_ACCEPT"]) == (
        "/status.json", "x=1", "text/plain, */*")
    second = parse_request(buf, 1024)
    assert second is not None and second.target == "/metrics" and not second.keep_alive
    assert buf == b""
    body = bytearray(b"POST / HTTP/1.1\r\nContent-Length: 4\r\nConnection: close\r\n\r\nab")
    assert parse_request(body, 1024) is None  # the body is still coming
    body += b"cd"
    request = parse_request(body, 1024)
    assert request is not None and request.body == b"abcd" and not request.keep_alive
    with pytest.raises(BadRequest) as info:
        parse_request(bytearray(b"GET / HTTP/1.1\r\nX: " + b"y" * 2000), 1024)
    assert (info.value.code, info.value.reason) == (431, "head_too_large")
