"""sd_notify against a real AF_UNIX datagram socket standing in for systemd."""

from __future__ import annotations

import os
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from compd.runtime.sdnotify import Notifier, watchdog_interval_s


@pytest.fixture
def systemd(tmp_path: Path) -> Iterator[tuple[str, socket.socket]]:
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(5)
    try:
        yield str(path), sock
    finally:
        sock.close()


def _recv(sock: socket.socket) -> str:
    return sock.recv(4096).decode()


def test_messages_arrive_as_datagrams(systemd: tuple[str, socket.socket]) -> None:
    path, sock = systemd
    notifier = Notifier(path)
    assert notifier.enabled
    notifier.ready()
    assert _recv(sock) == f"READY=1\nMAINPID={os.getpid()}"
    notifier.watchdog()
    assert _recv(sock) == "WATCHDOG=1"
    notifier.status("offset_um=-12.5 state=ok\nsecond line")
    assert _recv(sock) == "STATUS=offset_um=-12.5 state=ok second line"
    notifier.stopping()
    assert _recv(sock) == "STOPPING=1"
    assert notifier.sent == 4 and notifier.errors == 0
    notifier.close()


def test_abstract_namespace() -> None:
    name = f"compd-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(5)
    try:
        notifier = Notifier("@" + name)
        notifier.watchdog()
        assert _recv(sock) == "WATCHDOG=1"
        notifier.close()
    finally:
        sock.close()


def test_socket_from_environment(systemd: tuple[str, socket.socket],
                                 monkeypatch: pytest.MonkeyPatch) -> None:
    path, sock = systemd
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    notifier = Notifier()
    notifier.stopping()
    assert _recv(sock) == "STOPPING=1"
    notifier.close()


def test_no_socket_is_disabled_and_silent(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    for notifier in (Notifier(), Notifier(None), Notifier("")):
        assert not notifier.enabled
        notifier.ready()
        notifier.watchdog()
        notifier.status("x")
        notifier.stopping()
        assert notifier.sent == 0 and notifier.errors == 0


def test_send_errors_never_raise(tmp_path: Path) -> None:
    notifier = Notifier(str(tmp_path / "nobody-listens.sock"))
    assert notifier.enabled
    notifier.ready()  # ENOENT
    notifier.watchdog()
    assert notifier.errors == 2 and notifier.sent == 0
    assert notifier.last_error is not None
    # a socket file whose receiver is gone: ECONNREFUSED
    gone = tmp_path / "gone.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(gone))
    sock.close()
    other = Notifier(str(gone))
    other.status("still fine")
    assert other.errors == 1
    # a path too long for sockaddr_un
    assert not Notifier("/" + "x" * 200).notify("READY=1")


def test_watchdog_interval(monkeypatch: pytest.MonkeyPatch) -> None:
    assert watchdog_interval_s({}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "30000000"}) == 30.0
    pid = os.getpid()
    assert watchdog_interval_s({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(pid)}) == 2.0
    assert watchdog_interval_s({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(pid + 1)}) \
        is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "junk"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "0"}) is None
    monkeypatch.setenv("WATCHDOG_USEC", "500000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    assert Notifier(None).watchdog_interval_s() == 0.5
