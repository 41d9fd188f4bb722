"""A running drone's status over the network (`swarmraft status`): the request and the
signed answer (`net.wire` kinds 3 and 4), what a drone puts in it, and the client that asks
every drone of a swarm file.

Anyone may ask (a request is an unsigned header whose sequence number is a nonce), so a drone
answers at most `REPLIES_PER_S` requests a second: an answer is a few hundred bytes against a
request's 84, and the limit keeps a drone from being used to flood another address. The
answer is signed by the drone and echoes the nonce, so the client knows who answered and that
the answer is fresh. Like everything on this radio, it is not encrypted.
"""

from __future__ import annotations

import json
import secrets
import socket
import time
from dataclasses import dataclass
from typing import Any

from nacl.exceptions import BadSignatureError
from nacl.signing import VerifyKey

from swarmraft.net import wire
from swarmraft.net.swarmfile import SwarmFile
from swarmraft.net.transport import Address

#: A drone answers at most this many status requests a second (the rest are counted and dropped).
REPLIES_PER_S = 20
#: The client asks a drone that has not answered this many times, spread over its timeout
#: (a lossy radio loses requests and answers).
ASKS = 3


class ReplyLimit:
    """At most ``per_second`` answers in any one-second window of ``clock()``."""

    def __init__(self, clock: Any = time.monotonic, per_second: int = REPLIES_PER_S) -> None:
        self.clock, self.per_second = clock, per_second
        self._start, self._count = -1.0, 0

    def allow(self) -> bool:
        now = self.clock()
        if now - self._start >= 1.0:
            self._start, self._count = now, 0
        self._count += 1
        return self._count <= self.per_second


def encode_reply(fields: dict[str, Any]) -> bytes:
    """A status answer's payload: compact UTF-8 JSON."""
    return json.dumps(fields, separators=(",", ":"), allow_nan=False).encode()


@dataclass(frozen=True)
class Answer:
    """One drone's answer (``fields`` as it sent them), or why there is none (``problem``)."""

    drone: int
    address: Address
    fields: dict[str, Any] | None
    problem: str | None = None


def check_reply(data: bytes, nonce: int, key: VerifyKey, drone: int) -> dict[str, Any] | str:
    """The fields of drone ``drone``'s answer to the request with ``nonce``, or what is wrong."""
    try:
        d = wire.parse(data)
    except wire.WireError as exc:
        return f"malformed answer ({exc})"
    if d.kind != wire.Kind.STATUS_REPLY:
        return f"a datagram of kind {int(d.kind)}, not a status answer"
    if d.sender != drone:
        return f"answered as drone {d.sender}"
    try:
        key.verify(d.signed, d.signature)
    except BadSignatureError:
        return "bad signature"
    try:
        fields = json.loads(d.payload)
    except ValueError:
        return "an answer that is not JSON"
    if not isinstance(fields, dict) or fields.get("nonce") != nonce:
        return "an answer to another request"
    return fields


def ask(swarm: SwarmFile, publics: dict[int, bytes], timeout_s: float = 1.0) -> dict[int, Answer]:
    """Ask every drone of ``swarm`` (at its advertised address) for its status at once, again
    at a third and two thirds of ``timeout_s`` if it has not answered; wait until all answered
    or ``timeout_s``. Answers that are forged, stale or malformed are not
    taken (the drone's entry says why, if no good answer came)."""
    v6 = any(":" in d.advertise_address[0] for d in swarm.drones.values())
    family = socket.AF_INET6 if v6 else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.bind(("::" if family == socket.AF_INET6 else "0.0.0.0", 0))
        nonces = {i: secrets.randbits(63) for i in swarm.drones}
        by_addr = {d.advertise_address: i for i, d in swarm.drones.items()}
        got: dict[int, dict[str, Any]] = {}
        problems: dict[int, str] = {}
        start = time.monotonic()
        sends = [start + timeout_s * k / ASKS for k in range(ASKS)]  # asked again if unanswered
        while len(got) < len(swarm.drones) and (now := time.monotonic()) < start + timeout_s:
            if sends and now >= sends[0]:
                sends.pop(0)
                for i, d in swarm.drones.items():
                    if i not in got:
                        try:
                            sock.sendto(wire.status_request(nonces[i]), d.advertise_address)
                        except OSError:
                            pass  # unreachable: no answer
            wake = min(sends[0] if sends else start + timeout_s, start + timeout_s)
            sock.settimeout(max(wake - time.monotonic(), 0.001))
            try:
                data, addr = sock.recvfrom(65535)
            except (TimeoutError, OSError):
                continue
            drone = _sender_of(data, by_addr, addr)
            if drone is None or drone in got:
                continue
            result = check_reply(data, nonces[drone], VerifyKey(publics[drone]), drone)
            if isinstance(result, dict):
                got[drone] = result
                problems.pop(drone, None)
            else:
                problems[drone] = result
    finally:
        sock.close()
    return {
        i: Answer(i, d.advertise_address, got.get(i), None if i in got else problems.get(i, "no answer"))
        for i, d in sorted(swarm.drones.items())
    }


def _sender_of(data: bytes, by_addr: dict[Address, int], addr: Any) -> int | None:
    """Which drone an answer claims to be from (its header), if that drone is in the swarm;
    the address it came from is no proof (a relay or NAT may stand between)."""
    try:
        d = wire.parse(data)
    except wire.WireError:
        return by_addr.get((addr[0], addr[1]))
    return d.sender if d.sender in by_addr.values() else None
