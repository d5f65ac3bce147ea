"""The Modbus TCP client (`drivers.modbus_tcp`) against a scripted peer on
127.0.0.1: the frames it sends, answers split over segments, exception answers,
and what ends a request (a wrong answer, no answer, a closed connection, a
cancel), each leaving no connection a late answer could reach."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import AsyncIterator, Callable

import pytest

from drivers.modbus_tcp import READ_HOLDING, READ_INPUT, ModbusTcpClient, Reply

#: what the peer does with one request frame: the bytes to send back, in segments
Script = Callable[[bytes], list[bytes]]


class Peer:
    """A TCP server that answers each request frame as `script` says."""

    def __init__(self, script: Script) -> None:
        self.script = script
        self.frames: list[bytes] = []
        self.got = asyncio.Event()
        self.closed = asyncio.Event()
        self.server: asyncio.Server | None = None
        self.writer: asyncio.StreamWriter | None = None

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.writer = writer
        try:
            while True:
                head = await reader.readexactly(7)
                frame = head + await reader.readexactly(struct.unpack(">H", head[4:6])[0] - 1)
                self.frames.append(frame)
                self.got.set()
                for part in self.script(frame):
                    writer.write(part)
                    await writer.drain()
                    await asyncio.sleep(0)
        except (asyncio.IncompleteReadError, ConnectionError):
            self.closed.set()
        finally:
            writer.close()

    @property
    def port(self) -> int:
        assert self.server is not None
        return int(self.server.sockets[0].getsockname()[1])


@pytest.fixture
async def peer_of() -> AsyncIterator[Callable[[Script], asyncio.Future[Peer]]]:
    peers: list[Peer] = []

    async def start(script: Script) -> Peer:
        p = Peer(script)
        p.server = await asyncio.start_server(p.serve, "127.0.0.1", 0)
        peers.append(p)
        return p

    yield lambda script: asyncio.ensure_future(start(script))
    for p in peers:
        assert p.server is not None
        p.server.close()
        if p.writer is not None:
            p.writer.close()
        await p.server.wait_closed()


def answer(frame: bytes, pdu: bytes, *, tid: int | None = None) -> bytes:
    got_tid, _, _, unit = struct.unpack(">HHHB", frame[:7])
    return struct.pack(">HHHB", got_tid if tid is None else tid, 0, len(pdu) + 1, unit) + pdu


def registers(*words: int) -> Script:
    def script(frame: bytes) -> list[bytes]:
        return [answer(frame, bytes([frame[7], 2 * len(words)])
                       + struct.pack(f">{len(words)}H", *words))]
    return script


async def connected(peer: Peer, timeout_s: float = 30.0) -> ModbusTcpClient:
    return await ModbusTcpClient.open("127.0.0.1", peer.port, timeout_s)


async def test_read_frames_and_answers(peer_of: Callable[[Script], asyncio.Future[Peer]]
                                       ) -> None:
    peer = await peer_of(registers(0x1234, 0xFFFF))
    client = await connected(peer)
    try:
        assert await client.read_registers(7, READ_INPUT, 16, 2) == Reply(0, (0x1234, 0xFFFF))
        assert await client.read_registers(7, READ_HOLDING, 3, 2) == Reply(0, (0x1234, 0xFFFF))
    finally:
        client.close()
    # MBAP: transaction 1, 2; protocol 0; length 6; unit 7; then function, start, count
    assert peer.frames == [bytes.fromhex("0001 0000 0006 07 04 0010 0002"),
                           bytes.fromhex("0002 0000 0006 07 03 0003 0002")]


async def test_write_frame(peer_of: Callable[[Script], asyncio.Future[Peer]]) -> None:
    peer = await peer_of(lambda f: [answer(f, f[7:12])])  # echo function, start, quantity
    client = await connected(peer)
    try:
        assert await client.write_registers(1, 2, [1, 0xABCD]) == Reply(0, ())
    finally:
        client.close()
    assert peer.frames == [bytes.fromhex("0001 0000 000b 01 10 0002 0002 04 0001 abcd")]


async def test_answer_in_segments(peer_of: Callable[[Script], asyncio.Future[Peer]]) -> None:
    def split(frame: bytes) -> list[bytes]:
        whole = registers(1, 2, 3)(frame)[0]
        return [whole[:3], whole[3:8], whole[8:]]

    peer = await peer_of(split)
    client = await connected(peer)
    try:
        for _ in range(3):
            assert await client.read_registers(1, READ_INPUT, 0, 3) == Reply(0, (1, 2, 3))
    finally:
        client.close()


async def test_exception_answer(peer_of: Callable[[Script], asyncio.Future[Peer]]) -> None:
    peer = await peer_of(lambda f: [answer(f, bytes([f[7] | 0x80, 2]))])
    client = await connected(peer)
    try:
        assert await client.read_registers(1, READ_HOLDING, 0, 1) == Reply(2, ())
        assert client.connected  # the controller answered: the link is fine
    finally:
        client.close()


@pytest.mark.parametrize("bad", [
    lambda f: answer(f, bytes([f[7], 2, 0, 1]), tid=999),  # another transaction
    lambda f: answer(f, bytes([3 if f[7] == 4 else 4, 2, 0, 1])),  # another function
    lambda f: answer(f, bytes([f[7], 3, 0, 1, 2])),  # odd byte count
    lambda f: answer(f, bytes([f[7] | 0x80])),  # exception without its code
])
async def test_a_wrong_answer_fails_the_request_and_closes(
        peer_of: Callable[[Script], asyncio.Future[Peer]],
        bad: Callable[[bytes], bytes]) -> None:
    peer = await peer_of(lambda f: [bad(f)])
    client = await connected(peer)
    with pytest.raises(ConnectionError, match="not a Modbus answer"):
        await client.read_registers(1, READ_INPUT, 0, 1)
    assert not client.connected
    await peer.closed.wait()


async def test_no_answer_times_out_and_closes(
        peer_of: Callable[[Script], asyncio.Future[Peer]]) -> None:
    peer = await peer_of(lambda f: [])
    client = await connected(peer, timeout_s=0.05)
    with pytest.raises(TimeoutError):
        await client.read_registers(1, READ_INPUT, 0, 1)
    assert not client.connected  # a late answer can never be taken for another request
    await peer.closed.wait()


async def test_closed_under_a_request_fails_at_once(
        peer_of: Callable[[Script], asyncio.Future[Peer]]) -> None:
    peer = await peer_of(lambda f: [])
    client = await connected(peer, timeout_s=3600.0)  # no timeout could end this test
    request = asyncio.ensure_future(client.read_registers(1, READ_INPUT, 0, 1))
    await peer.got.wait()
    assert peer.writer is not None
    peer.writer.close()
    with pytest.raises(ConnectionError, match="closed by the controller"):
        await request
    assert not client.connected


async def test_a_cancelled_request_closes(peer_of: Callable[[Script], asyncio.Future[Peer]]
                                          ) -> None:
    peer = await peer_of(lambda f: [])
    client = await connected(peer, timeout_s=3600.0)
    request = asyncio.ensure_future(client.read_registers(1, READ_INPUT, 0, 1))
    await peer.got.wait()
    request.cancel()
    with pytest.raises(asyncio.CancelledError):
        await request
    assert not client.connected
    await peer.closed.wait()
    with pytest.raises(ConnectionError, match="not connected"):
        await client.read_registers(1, READ_INPUT, 0, 1)


async def test_transaction_zero_and_unit_zero_are_taken(
        peer_of: Callable[[Script], asyncio.Future[Peer]]) -> None:
    """As pymodbus's client: a device that answers every request with transaction 0,
    and a gateway that answers a request for unit 0 as another unit."""
    def odd(frame: bytes) -> list[bytes]:
        pdu = bytes([frame[7], 2, 0, 9])
        return [struct.pack(">HHHB", 0, 0, len(pdu) + 1, 17) + pdu]

    peer = await peer_of(odd)
    client = await connected(peer)
    try:
        assert await client.read_registers(0, READ_INPUT, 0, 1) == Reply(0, (9,))
        with pytest.raises(ConnectionError, match="unit 17"):  # unit 5 asked: not its answer
            await client.read_registers(5, READ_INPUT, 0, 1)
    finally:
        client.close()
