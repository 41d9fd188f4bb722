"""Hostile datagrams for a drone's `Verifier`, each labelled with the reason it must be dropped:
what the tests and benchmarks send at running drones (``tests/test_net_hostile.py``,
``benchmarks/bench_hostile.py``). No sockets, no clock: every draw from the generator passed in.
Two helpers do I/O, for a sender on the same Linux machine: `udp_socket_queue` reads what the
kernel holds for a local UDP socket (and how many datagrams it dropped: its buffer was full),
and `PacedSender` waits for room in it, so the kernel drops none of what it sends.

The attacker holds one swarm member's private key (a compromised drone) and knows the others'
ids. The kinds, in equal shares and a seeded random order, each with the drop reason the
target's Verifier must count:

- ``random_bytes``: 1-1,400 random bytes, never starting with the magic ``SR`` -> ``malformed``
- ``truncated``: a datagram the attacker signed, cut to 0 .. all but one byte -> ``malformed``
- ``oversized``: 60,001-65,507 bytes behind a plausible header -> ``oversized``
- ``forged_signature``: a datagram the attacker signed, one bit flipped after the header
  -> ``bad_signature``
- ``replayed``: the attacker's last datagram whose signature verified, again -> ``replayed``
- ``other_sender``: a header claiming another drone, signed with the attacker's key
  -> ``bad_signature``; an id with no key -> ``unknown_sender``; the attacker's own signed
  datagram carrying another drone's Raft message or report -> ``sender_mismatch``

`HostileFlood.primer` is one harmless valid datagram from the attacker (a heartbeat response of
term 0, which Raft ignores as stale) that the target must receive, and accept, before the
flood: it gives the replays something to replay. The labels hold for a target whose window
for the attacker has seen only the primer and the flood, in order (loopback keeps the order of
one socket's datagrams); forged sequence numbers of other drones are above any real one.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from swarmraft.net import wire
from swarmraft.net.auth import Signer
from swarmraft.protocol import Keyring, Report
from swarmraft.raft import Message, MsgType

KINDS = ("random_bytes", "truncated", "oversized", "forged_signature", "replayed", "other_sender")
#: The largest UDP payload over IPv4 (65,535 less the IP and UDP headers).
MAX_UDP = 65_507
#: Sequence numbers of forged datagrams claiming another drone: above any real one (a real
#: drone starts at the wall clock in microseconds, about 1.8e15), so the target's replay window
#: passes them on to the signature check.
FORGED_SEQ = 2**62


@dataclass(frozen=True, slots=True)
class Hostile:
    kind: str  # one of KINDS
    reason: str  # the Verifier's drop reason it must get
    data: bytes


@dataclass
class HostileFlood:
    """``count`` hostile datagrams from drone ``attacker`` (whose private key, ``seed``, it
    holds; its own datagrams numbered from ``first_seq``) at drone ``target`` of an ``n``-drone
    swarm. Send ``primer`` first, then iterate for the flood (lazily: the oversized ones are
    60 KB each); each one's ``reason`` is what the target's Verifier must count."""

    count: int
    rng: np.random.Generator
    attacker: int
    seed: bytes
    target: int
    n: int
    first_seq: int = 1
    primer: bytes = field(init=False)
    kinds: list[str] = field(init=False)

    def __post_init__(self) -> None:
        if not 1 <= self.target <= self.n or not 1 <= self.attacker <= self.n or self.target == self.attacker:
            raise ValueError("attacker and target must be two different drones of the swarm")
        self._signer = Signer(self.attacker, self.seed, self.first_seq)
        self.primer = self._signer.seal(self._stale(self.attacker))
        self._last_valid = self.primer
        self._others = [i for i in range(1, self.n + 1) if i not in (self.attacker, self.target)] or [
            self.target
        ]
        self._forger = {i: Signer(i, self.seed, first_seq=FORGED_SEQ) for i in self._others}
        self._stranger = Signer(self.n + 1, self.seed)
        self._reports = Keyring.generate(self.n, self.rng)  # throwaway keys: signatures of the right size
        order = np.arange(self.count) % len(KINDS)
        self.kinds = [KINDS[i] for i in self.rng.permutation(order)]

    def _stale(self, frm: int) -> Message:
        return Message(MsgType.HEARTBEAT_RESP, frm=frm, to=self.target, term=0)

    def __iter__(self) -> Iterator[Hostile]:
        for kind in self.kinds:
            yield getattr(self, f"_{kind}")()

    def _random_bytes(self) -> Hostile:
        data = bytearray(self.rng.bytes(int(self.rng.integers(1, 1401))))
        if data[:2] == wire.MAGIC[: len(data)]:
            data[0] ^= 0xFF
        return Hostile("random_bytes", "malformed", bytes(data))

    def _truncated(self) -> Hostile:
        whole = self._signer.seal(self._stale(self.attacker))
        return Hostile("truncated", "malformed", whole[: int(self.rng.integers(0, len(whole)))])

    def _oversized(self) -> Hostile:
        size = int(self.rng.integers(wire.MAX_DATAGRAM + 1, MAX_UDP + 1))
        head = wire.frame(wire.Kind.RAFT, self.attacker, self._signer.next_seq, b"")[:16]
        return Hostile("oversized", "oversized", head + self.rng.bytes(size - len(head)))

    def _forged_signature(self) -> Hostile:
        data = bytearray(self._signer.seal(self._stale(self.attacker)))
        bit = int(self.rng.integers(wire.HEADER_SIZE * 8, len(data) * 8))
        data[bit // 8] ^= 1 << (bit % 8)
        return Hostile("forged_signature", "bad_signature", bytes(data))

    def _replayed(self) -> Hostile:
        return Hostile("replayed", "replayed", self._last_valid)

    def _other_sender(self) -> Hostile:
        other = self._others[int(self.rng.integers(len(self._others)))]
        way = int(self.rng.integers(4))
        if way == 0:  # the header claims another drone; the attacker's key signed it
            return Hostile("other_sender", "bad_signature", self._forger[other].seal(self._stale(other)))
        if way == 1:  # an id with no key in the swarm
            return Hostile("other_sender", "unknown_sender", self._stranger.seal(self._stale(self.n + 1)))
        if way == 2:  # the attacker's own datagram carrying another drone's Raft message
            data = self._signer.seal(self._stale(other))
        else:  # ... or another drone's report
            n = self.n
            report = Report(0, other - 1, np.zeros(3), "gnss", np.zeros(n), None)
            data = self._signer.seal(self._reports.sign(report))
        self._last_valid = data  # its signature verifies: the target's window moves to it
        return Hostile("other_sender", "sender_mismatch", data)


def udp_socket_queue(port: int, host: str = "127.0.0.1") -> tuple[int, int] | None:
    """(bytes queued, datagrams dropped so far) of the IPv4 UDP socket bound to ``host:port``,
    as Linux reports them in /proc/net/udp (``rx_queue``, ``drops``: the receive buffer was
    full); None where there is no such file or socket."""
    want = f"{int.from_bytes(bytes(map(int, host.split('.'))), 'little'):08X}:{port:04X}"
    try:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return None
    for line in lines:
        f = line.split()
        if f[1] == want:
            return int(f[4].split(":")[1], 16), int(f[-1])
    return None


#: Bytes a target's socket may hold before `PacedSender` sends it more; a large datagram waits for
#: an empty queue. The default receive buffer is about 208 KiB, and a datagram takes more of it
#: than its size (2.3 KiB for 1,000 bytes, 65-130 KiB for 64 KB).
QUEUE_LIMIT = 64 * 1024
#: Bytes of small datagrams sent between two looks at the queue (each look reads /proc/net/udp).
LOOK_EVERY = 32 * 1024


class PacedSender:
    """Sends datagrams to a local UDP socket at ``addr`` no faster than its owner reads them, so
    the kernel drops none: before a large one (over 4 KiB) it waits for an empty queue, and
    every LOOK_EVERY bytes of small ones for a queue under QUEUE_LIMIT (without /proc/net/udp,
    it sends at once). ``send`` raises TimeoutError if the queue does not drain within
    ``timeout_s``: its owner stopped reading."""

    def __init__(self, sock: socket.socket, addr: tuple[str, int], timeout_s: float = 10.0) -> None:
        self.sock, self.addr, self.timeout_s = sock, addr, timeout_s
        self._unlooked = 0

    def send(self, data: bytes) -> None:
        if len(data) > 4096:
            self._wait_for(0)
        elif self._unlooked >= LOOK_EVERY:
            self._wait_for(QUEUE_LIMIT)
        self.sock.sendto(data, self.addr)
        self._unlooked += len(data) + 1024  # the kernel's overhead per datagram, roughly

    def _wait_for(self, limit: int) -> None:
        end = time.monotonic() + self.timeout_s
        while (q := udp_socket_queue(self.addr[1], self.addr[0])) is not None and q[0] > limit:
            if time.monotonic() > end:
                raise TimeoutError(
                    f"{self.addr[0]}:{self.addr[1]} held {q[0]} bytes for {self.timeout_s:g} s"
                )
            time.sleep(0.001)
        self._unlooked = 0
