"""A fault relay for drone processes on one machine: an asyncio UDP relay between every pair of
drones that applies the simulator's radio model (`sim.network.Network`: per-link delay, loss,
duplication, reordering, one-way cuts, partitions) to real datagrams, changeable while it runs.
(netem and toxiproxy are not available here, and the simulator's model is the one to match.)

Each drone i gets a relay port R_i, which the swarm file gives as its *advertised* address
while it binds B_i: a datagram for drone i reaches R_i, the relay names its sender from the
source address (drone j binds B_j and sends from it), draws the copies that arrive and their
delays from the link j -> i, and sends each from R_i to B_i. A datagram from an address that is
no drone's is forwarded as if from drone 0, a sender in no group: it passes when there is no
partition, and counts as ``foreign``; what drone i sends to its own relay port R_i (its answer
to such a datagram: it answers the address it heard from) goes back to the last outside
address that reached R_i, as a NAT would (`swarmraft status` through the relay). The relay
does not look inside datagrams.

`Relay` lives on an asyncio loop; `RelayThread` runs one on a loop of its own in a background
thread, so a synchronous program (``swarmraft launch``) can start it and change the network
from its own thread (`RelayThread.call`).
"""

from __future__ import annotations

import asyncio
import random
import threading
from collections import Counter
from collections.abc import Callable, Iterable
from typing import Any

from swarmraft.net.transport import Address
from swarmraft.sim.network import LinkModel, Network

#: The sender id of a datagram from an address that is no drone's bind address.
FOREIGN = 0


class _Port(asyncio.DatagramProtocol):
    def __init__(self, relay: Relay, to: int) -> None:
        self.relay, self.to = relay, to
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[Any, ...]) -> None:
        self.relay._forward(self.to, data, (addr[0], addr[1]))

    def error_received(self, exc: Exception) -> None:  # e.g. ICMP port unreachable from a dead drone
        self.relay.counters["send_errors"] += 1


class Relay:
    """The relay for drones ``targets`` (id -> the address the drone binds), on ``network``
    (the simulator's model, changed in place by the methods below), drawing from ``rng``.
    ``await start()`` binds one port per drone and returns the addresses to advertise."""

    def __init__(self, targets: dict[int, Address], network: Network, rng: random.Random) -> None:
        self.targets = dict(targets)
        self.network = network
        self.rng = rng
        self.sender_of = {(host, port): i for i, (host, port) in self.targets.items()}
        self.ports: dict[int, _Port] = {}
        self.counters: Counter[str] = Counter()
        self._stranger: dict[int, Address] = {}  # drone -> the last outside address that sent to it
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self, host: str = "127.0.0.1", ports: dict[int, int] | None = None) -> dict[int, Address]:
        """Bind a relay port for every drone (``ports[i]``, or a free one); their addresses."""
        self._loop = asyncio.get_running_loop()
        for i in sorted(self.targets):
            _, proto = await self._loop.create_datagram_endpoint(
                lambda i=i: _Port(self, i), local_addr=(host, (ports or {}).get(i, 0))
            )
            self.ports[i] = proto
        return self.addresses

    @property
    def addresses(self) -> dict[int, Address]:
        out = {}
        for i, p in self.ports.items():
            assert p.transport is not None
            host, port = p.transport.get_extra_info("sockname")[:2]
            out[i] = (host, port)
        return out

    def close(self) -> None:
        for p in self.ports.values():
            if p.transport is not None:
                p.transport.close()

    def _forward(self, to: int, data: bytes, source: Address) -> None:
        frm = self.sender_of.get(source, FOREIGN)
        self.counters["received"] += 1
        if frm == FOREIGN:
            self.counters["foreign"] += 1
            self._stranger[to] = source
        elif frm == to:  # drone `to` answers whoever last reached it from outside (a NAT's way)
            port, back = self.ports[to], self._stranger.get(to)
            if back is not None and port.transport is not None and not port.transport.is_closing():
                port.transport.sendto(data, back)
                self.counters["answered_outside"] += 1
            return
        delays = self.network.delays(self.rng, frm, to)
        if not delays:
            cut = (self.network.cuts or self.network.groups) and not self.network.connected(frm, to)
            self.counters["cut" if cut else "lost"] += 1
            return
        if len(delays) > 1:
            self.counters["duplicated"] += len(delays) - 1
        assert self._loop is not None
        for d in delays:
            self._loop.call_later(d / 1000, self._send, to, data)

    def _send(self, to: int, data: bytes) -> None:
        port = self.ports[to]
        if port.transport is None or port.transport.is_closing():
            return
        port.transport.sendto(data, self.targets[to])
        self.counters["forwarded"] += 1

    # -- changing the network (on the relay's loop) ------------------------------------------
    def partition(self, groups: Iterable[Iterable[int]]) -> None:
        """Drones talk only within their group; a drone in no group is cut off."""
        self.network.groups = [frozenset(g) for g in groups]

    def heal(self) -> None:
        """Remove partitions and cuts (loss, delay and the rest stay)."""
        self.network.groups = []
        self.network.cuts.clear()

    def cut(self, a: int, b: int) -> None:
        """Drop everything from a to b (one way)."""
        self.network.cuts.add((a, b))

    def set_all(self, **changes: Any) -> None:
        """Change every link: ``loss=0.2``, ``delay_ms=(5, 10)``, ``duplicate=``, ``reorder=``."""
        self.network.set_all(**changes)

    def set_link(self, a: int, b: int, **changes: Any) -> None:
        """Change both directions of link a-b."""
        self.network.set_link(a, b, **changes)


class RelayThread:
    """A `Relay` on its own event loop in a daemon thread. ``start()`` returns the advertised
    addresses; ``call(method, *args)`` runs a `Relay` method on its loop and waits for it;
    ``stop()`` closes the ports and ends the thread."""

    def __init__(self, targets: dict[int, Address], link: LinkModel, seed: int) -> None:
        self.relay = Relay(targets, Network(link), random.Random(seed))
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="fault-relay", daemon=True)

    def start(self, host: str = "127.0.0.1", ports: dict[int, int] | None = None) -> dict[int, Address]:
        self._thread.start()
        return asyncio.run_coroutine_threadsafe(self.relay.start(host, ports), self._loop).result(10)

    def call(self, method: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        async def run() -> Any:
            return method(*args, **kwargs)

        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(10)

    def counters(self) -> Counter[str]:
        return self.call(lambda: Counter(self.relay.counters))

    def stop(self) -> None:
        if not self._thread.is_alive():
            return
        self.call(self.relay.close)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        self._loop.close()
