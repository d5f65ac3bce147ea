"""The fault proxy itself, against a plain echo server on 127.0.0.1."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable

import pytest

from tests.faults.proxy import FaultProxy

#: bound on anything expected to happen "at once" (not a timing assertion)
SOON_S = 2.0


def _fixed_frames(buf: bytes) -> int | None:
    """Test framing: one length byte, then that many bytes."""
    return 1 + buf[0] if buf else None


@contextlib.asynccontextmanager
async def echo_proxy() -> AsyncIterator[FaultProxy]:
    handlers: set[asyncio.Task[None]] = set()

    async def echo(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            handlers.add(task)
        try:
            while data := await reader.read(4096):
                writer.write(data)
                await writer.drain()
        except OSError:
            pass
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()

    server = await asyncio.start_server(echo, "127.0.0.1", 0)
    port = int(server.sockets[0].getsockname()[1])
    try:
        async with FaultProxy("127.0.0.1", port, frame_length=_fixed_frames) as proxy:
            yield proxy
    finally:
        server.close()
        for task in handlers:
            task.cancel()
        await asyncio.gather(*handlers, return_exceptions=True)
        await server.wait_closed()


@contextlib.asynccontextmanager
async def client(proxy: FaultProxy) -> AsyncIterator[tuple[asyncio.StreamReader,
                                                           asyncio.StreamWriter]]:
    reader, writer = await asyncio.open_connection("127.0.0.1", proxy.port)
    try:
        yield reader, writer
    finally:
        writer.close()
        with contextlib.suppress(OSError):
            await writer.wait_closed()


async def _wait_for(cond: Callable[[], bool], what: str) -> None:
    for _ in range(int(SOON_S / 0.01)):
        if cond():
            return
        await asyncio.sleep(0.01)
    pytest.fail(f"not within {SOON_S} s: {what}")


async def test_pass_forwards_and_counts() -> None:
    async with echo_proxy() as proxy, client(proxy) as (reader, writer):
        writer.write(b"\x03abc\x01z")
        got = await asyncio.wait_for(reader.readexactly(6), SOON_S)
        assert got == b"\x03abc\x01z"
        assert proxy.connections_accepted == 1
        assert proxy.open_connections == 1
        assert proxy.bytes_forwarded == {"up": 6, "down": 6}
        assert proxy.frames_received == [b"\x03abc", b"\x01z"]
        assert proxy.frames_forwarded == [b"\x03abc", b"\x01z"]
    await _wait_for(lambda: proxy.open_connections == 0, "the proxy drops a closed connection")


async def test_latency_holds_data_then_delivers_in_order() -> None:
    async with echo_proxy() as proxy, client(proxy) as (reader, writer):
        proxy.latency(0.3, 0.0)
        writer.write(b"\x01a")
        writer.write(b"\x01b")
        with pytest.raises(TimeoutError):
            await asyncio.wait_for(reader.readexactly(1), 0.05)
        assert proxy.frames_forwarded == []
        got = await asyncio.wait_for(reader.readexactly(4), SOON_S)
        assert got == b"\x01a\x01b"


async def test_slow_start_holds_the_first_chunks_of_new_connections_only() -> None:
    async with echo_proxy() as proxy, client(proxy) as (r_old, w_old):
        # held 0.3 s: the 0.05 s wait below begins before the proxy even reads the
        # chunk (one event loop), so it always ends first
        proxy.slow_start(0.3, 1)
        async with client(proxy) as (reader, writer):
            w_old.write(b"\x01o")  # a connection open before the switch: not held
            assert await asyncio.wait_for(r_old.readexactly(2), SOON_S) == b"\x01o"
            writer.write(b"\x01a")  # the new connection's first chunk: held
            with pytest.raises(TimeoutError):
                await asyncio.wait_for(reader.readexactly(1), 0.05)
            assert await asyncio.wait_for(reader.readexactly(2), SOON_S) == b"\x01a"
            writer.write(b"\x01b")  # its next one: passes
            assert await asyncio.wait_for(reader.readexactly(2), 0.5) == b"\x01b"


async def test_blackhole_forwards_nothing_and_its_connections_stay_dead() -> None:
    async with echo_proxy() as proxy:
        async with client(proxy) as (reader, writer):
            proxy.blackhole()
            writer.write(b"\x02hi")
            with pytest.raises(TimeoutError):
                await asyncio.wait_for(reader.readexactly(1), 0.2)
            assert len(proxy.frames_received) == 1
            assert proxy.frames_forwarded == []
            proxy.pass_through()
            writer.write(b"\x02yo")
            with pytest.raises(TimeoutError):
                await asyncio.wait_for(reader.readexactly(1), 0.2)
        async with client(proxy) as (reader, writer):  # a new connection works
            writer.write(b"\x02ok")
            assert await asyncio.wait_for(reader.readexactly(3), SOON_S) == b"\x02ok"


async def test_reset_sends_rst_to_open_and_new_connections() -> None:
    async with echo_proxy() as proxy:
        async with client(proxy) as (reader, writer):
            writer.write(b"\x01a")
            await asyncio.wait_for(reader.readexactly(2), SOON_S)
            proxy.reset()
            with pytest.raises(ConnectionResetError):
                await asyncio.wait_for(reader.read(10), SOON_S)
        async with client(proxy) as (reader, _writer):
            with pytest.raises(ConnectionResetError):
                await asyncio.wait_for(reader.read(10), SOON_S)
        await _wait_for(lambda: proxy.open_connections == 0, "reset connections dropped")


async def test_cut_after_k_bytes_then_eof() -> None:
    async with echo_proxy() as proxy, client(proxy) as (reader, writer):
        proxy.cut_after(5, "down")
        writer.write(b"\x07abcdefg")
        got = await asyncio.wait_for(reader.read(100), SOON_S)
        rest = await asyncio.wait_for(reader.read(100), SOON_S)
        assert got == b"\x07abcd"
        assert rest == b""  # EOF: the proxy closed the connection
        assert proxy.bytes_forwarded["down"] == 5


async def test_stop_closes_connections_and_leaves_no_task() -> None:
    before = asyncio.all_tasks()
    async with echo_proxy() as proxy:
        reader, writer = await asyncio.open_connection("127.0.0.1", proxy.port)
        writer.write(b"\x01a")
        await asyncio.wait_for(reader.readexactly(2), SOON_S)
        proxy.latency(10.0)
        writer.write(b"\x01b")  # held in the proxy when it stops
    assert await asyncio.wait_for(reader.read(10), SOON_S) == b""
    writer.close()
    await writer.wait_closed()
    assert asyncio.all_tasks() - before - {asyncio.current_task()} == set()
