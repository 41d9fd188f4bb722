"""The UDP transport on loopback: two transports exchange a signed datagram that a Verifier
accepts, close() frees the port, a failed bind is one BindError naming the address, and
sending never raises or blocks. Every test ends within a few seconds (asyncio.wait_for)."""

import asyncio
import logging

import pytest

from swarmraft.net.auth import Accepted, Signer, Verifier, public_key
from swarmraft.net.transport import BindError, Transport, UDPTransport
from swarmraft.net.wire import MAX_DATAGRAM
from swarmraft.raft.types import Message, MsgType

SEEDS = {1: bytes([1]) * 32, 2: bytes([2]) * 32}
TIMEOUT_S = 5.0


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, TIMEOUT_S))


class Inbox:
    """A receive callback that queues what arrives."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue[tuple[bytes, tuple[str, int]]] = asyncio.Queue()

    def __call__(self, data: bytes, addr: tuple[str, int]) -> None:
        self.queue.put_nowait((data, addr))

    async def next(self) -> tuple[bytes, tuple[str, int]]:
        return await asyncio.wait_for(self.queue.get(), TIMEOUT_S)


def test_two_transports_on_loopback_exchange_a_datagram_the_verifier_accepts():
    async def scenario():
        inbox_a, inbox_b = Inbox(), Inbox()
        a = await UDPTransport.bind("127.0.0.1", 0, inbox_a)
        b = await UDPTransport.bind("127.0.0.1", 0, inbox_b)
        try:
            heartbeat = Message(MsgType.HEARTBEAT, frm=1, to=2, term=3, commit=4)
            a.send(b.local_address, Signer(1, SEEDS[1]).seal(heartbeat))
            data, source = await inbox_b.next()
            got = Verifier({i: public_key(s) for i, s in SEEDS.items()}, own_id=2).check(data)
            assert got == Accepted(1, 1, got.kind, heartbeat)
            assert source == a.local_address
            b.send(source, b"reply")
            assert (await inbox_a.next())[0] == b"reply"
            assert (a.sent, b.received) == (1, 1)
            assert a.bytes_sent == b.bytes_received == len(data)
            assert (a.bytes_received, b.bytes_sent) == (5, 5)
        finally:
            a.close()
            b.close()

    run(scenario())


def test_a_transport_is_a_transport():
    async def scenario():
        t = await UDPTransport.bind("127.0.0.1", 0, Inbox())
        t.close()
        assert isinstance(t, Transport)

    run(scenario())


def test_close_releases_the_socket():
    async def scenario():
        t = await UDPTransport.bind("127.0.0.1", 0, Inbox())
        port = t.local_address[1]
        t.close()
        await t.wait_closed()
        again = await UDPTransport.bind("127.0.0.1", port, Inbox())
        assert again.local_address[1] == port
        again.close()
        t.close()  # closing twice is harmless

    run(scenario())


def test_a_port_in_use_is_one_bind_error_naming_the_address():
    async def scenario():
        t = await UDPTransport.bind("127.0.0.1", 0, Inbox())
        port = t.local_address[1]
        try:
            with pytest.raises(BindError, match=f"127.0.0.1:{port}"):
                await UDPTransport.bind("127.0.0.1", port, Inbox())
        finally:
            t.close()

    run(scenario())


@pytest.mark.parametrize("host", ["256.0.0.1", "192.0.2.1"])  # not an address; not this machine's
def test_an_address_that_cannot_be_bound_is_one_bind_error(host):
    async def scenario():
        with pytest.raises(BindError, match=f"{host}:0"):
            await UDPTransport.bind(host, 0, Inbox())

    run(scenario())


def test_sending_after_close_or_to_nowhere_never_raises():
    async def scenario():
        t = await UDPTransport.bind("127.0.0.1", 0, Inbox())
        t.send(("127.0.0.1", 9), b"to the discard port")
        t.send(("256.0.0.1", 9), b"to no address")
        t.close()
        t.send(("127.0.0.1", 9), b"after close")
        await asyncio.sleep(0.05)
        assert t.dropped >= 2

    run(scenario())


def test_an_oversized_datagram_is_not_sent():
    async def scenario():
        inbox = Inbox()
        t = await UDPTransport.bind("127.0.0.1", 0, inbox)
        try:
            t.send(t.local_address, bytes(MAX_DATAGRAM + 1))
            t.send(t.local_address, b"small")
            assert (await inbox.next())[0] == b"small"
            assert (t.sent, t.dropped) == (1, 1)
            assert t.bytes_sent == t.bytes_received == len(b"small")  # a datagram not sent counts no bytes
        finally:
            t.close()

    run(scenario())


def test_a_failing_receive_callback_is_logged_and_does_not_reach_the_event_loop(caplog):
    async def scenario():
        inbox = Inbox()
        loop_errors = []
        asyncio.get_running_loop().set_exception_handler(lambda loop, ctx: loop_errors.append(ctx))

        def flaky(data: bytes, addr: tuple[str, int]) -> None:
            if data == b"boom":
                raise RuntimeError("callback bug")
            inbox(data, addr)

        t = await UDPTransport.bind("127.0.0.1", 0, flaky)
        try:
            t.send(t.local_address, b"boom")
            t.send(t.local_address, b"after")
            assert (await inbox.next())[0] == b"after"
            assert t.received == 2
        finally:
            t.close()
        assert loop_errors == []

    with caplog.at_level(logging.ERROR, logger="swarmraft.net.transport"):
        run(scenario())
    assert "receive callback failed" in caplog.text


def test_drain_hands_over_every_datagram_already_waiting_in_order():
    """The event loop reads one datagram per pass and runs the timers due after it: a leader's
    step deadline could fire with reports still waiting. ``drain`` reads them all now, in
    order, at most ``limit``; with nothing waiting it returns 0."""

    async def scenario():
        inbox = Inbox()
        a = await UDPTransport.bind("127.0.0.1", 0, Inbox())
        b = await UDPTransport.bind("127.0.0.1", 0, inbox)
        try:
            for i in range(5):
                a.send(b.local_address, bytes([i]) * 10)
            # no await since the sends: b's loop has not read any of them
            assert inbox.queue.empty()
            assert b.drain(limit=3) == 3
            assert b.drain() == 2
            assert b.drain() == 0
            got = [inbox.queue.get_nowait()[0] for _ in range(5)]
            assert got == [bytes([i]) * 10 for i in range(5)]
            assert b.received == 5
        finally:
            a.close()
            b.close()

    run(scenario())
