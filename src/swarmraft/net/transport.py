"""Moving datagrams between drones: the `Transport` protocol the runtime codes against, and
`UDPTransport`, one UDP socket on an asyncio event loop.

A transport sends bytes to an address and hands every datagram it receives, with the sender's
address, to the callback it was built with; it does not look inside (that is `net.auth`'s
job). ``send`` never blocks and never raises: a datagram it cannot send is counted in
``dropped`` (UDP may lose it anyway). Addresses are numeric (ip, port), so no send waits on DNS.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
from collections.abc import Callable
from typing import Protocol, runtime_checkable

from swarmraft.net.wire import MAX_DATAGRAM

Address = tuple[str, int]
Receive = Callable[[bytes, Address], None]

#: the most datagrams `UDPTransport.drain` hands over at once (a flood cannot hold the loop)
DRAIN_LIMIT = 256
#: bytes read per datagram (asyncio's own datagram transport reads up to this too)
MAX_RECEIVE = 256 * 1024

_logger = logging.getLogger(__name__)


class BindError(RuntimeError):
    """The socket could not be bound; the message names the address and the reason."""


@runtime_checkable
class Transport(Protocol):
    def send(self, addr: Address, data: bytes) -> None: ...

    def close(self) -> None: ...


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, owner: UDPTransport) -> None:
        self.owner = owner

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        self.owner._received(data, (addr[0], addr[1]))

    def error_received(self, exc: Exception) -> None:
        self.owner._error(exc)

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.owner._closed.done():
            self.owner._closed.set_result(None)


class UDPTransport:
    """One bound UDP socket. Build it with ``await UDPTransport.bind(host, port, on_receive)``
    (port 0: any free port, see ``local_address``); ``on_receive(data, addr)`` runs on the
    event loop for each datagram, and an exception in it is logged, not raised into the loop.
    ``sent``, ``received`` and ``dropped`` count datagrams; ``bytes_sent`` and
    ``bytes_received`` the bytes of the datagrams in ``sent`` and ``received``."""

    def __init__(self, on_receive: Receive) -> None:
        self._on_receive = on_receive
        self._transport: asyncio.DatagramTransport | None = None
        self._sock: socket.socket | None = None
        self._closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._numeric: set[str] = set()
        self.local_address: Address = ("", 0)
        self.sent = self.received = self.dropped = 0
        self.bytes_sent = self.bytes_received = 0

    @classmethod
    async def bind(cls, host: str, port: int, on_receive: Receive) -> UDPTransport:
        """A transport bound to ``host:port``; BindError if that address cannot be bound."""
        t = cls(on_receive)
        loop = asyncio.get_running_loop()
        sock = None
        try:
            family, _, _, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
            sock = socket.socket(family, socket.SOCK_DGRAM)
            sock.setblocking(False)
            sock.bind(addr)
            transport, _ = await loop.create_datagram_endpoint(lambda: _Datagrams(t), sock=sock)
        except OSError as exc:
            if sock is not None:
                sock.close()
            reason = exc.strerror or str(exc) or type(exc).__name__
            raise BindError(f"cannot bind UDP {host}:{port}: {reason}") from None
        t._transport, t._sock = transport, sock
        sockname = transport.get_extra_info("sockname")
        t.local_address = (sockname[0], sockname[1])
        return t

    def send(self, addr: Address, data: bytes) -> None:
        """Queue ``data`` for ``addr``; returns at once."""
        if self._transport is None or self._transport.is_closing() or len(data) > MAX_DATAGRAM:
            self.dropped += 1
            return
        host = addr[0]
        if host not in self._numeric:
            try:
                ipaddress.ip_address(host)
            except ValueError:
                self.dropped += 1
                _logger.debug("not sent: %r is not a numeric IP address", host)
                return
            self._numeric.add(host)
        self._transport.sendto(data, addr)
        self.sent += 1
        self.bytes_sent += len(data)

    def drain(self, limit: int = DRAIN_LIMIT) -> int:
        """Hand every datagram already waiting in the socket (at most ``limit``) to the
        callback now; returns how many. The event loop reads one datagram per pass and runs
        the timers that are due after it, so on a loaded machine a timer can act while
        datagrams that came before its moment still wait: a leader whose step deadline fired
        with a queue of reports decided without them (`DroneHost._deadline` drains first)."""
        if self._sock is None or self._transport is None or self._transport.is_closing():
            return 0
        count = 0
        for _ in range(limit):
            try:
                data, addr = self._sock.recvfrom(MAX_RECEIVE)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                self._error(exc)
                continue
            count += 1
            self._received(data, (addr[0], addr[1]))
        return count

    def _error(self, exc: Exception) -> None:
        # an earlier send failed (e.g. ICMP port unreachable): UDP promised nothing
        self.dropped += 1
        _logger.debug("UDP error on %s: %s", self.local_address, exc)

    def _received(self, data: bytes, addr: Address) -> None:
        self.received += 1
        self.bytes_received += len(data)
        try:
            self._on_receive(data, addr)
        except Exception:  # a bug in the host must not stop the transport
            _logger.exception("receive callback failed on a datagram from %s", addr)

    def close(self) -> None:
        """Release the socket (at the loop's next iteration; ``await wait_closed()`` for it)."""
        if self._transport is not None:
            self._transport.close()

    async def wait_closed(self) -> None:
        if self._transport is not None:
            await self._closed
