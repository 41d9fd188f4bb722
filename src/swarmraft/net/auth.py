"""Signing outgoing datagrams and checking incoming ones: `Signer`, `Verifier` with its per-sender
anti-replay `ReplayWindow`, and `RateLimitedLog` for the drops.

A drone's `Signer` seals a Raft message or a signed report into a datagram with its id and the
next sequence number (a Raft message too large for one datagram in several, `wire.Chunk`). A
`Verifier` holds every drone's public key; ``check(data)`` returns `Accepted` (the decoded
message), `Partial` (an authentic piece of a larger message, held until the message is whole)
or `Dropped` (a reason), counts each outcome and never raises.
No sockets, no clock except the log's rate limit. Ed25519 with PyNaCl (benchmarks/bench_crypto.py).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from nacl.exceptions import BadSignatureError
from nacl.signing import SigningKey, VerifyKey

from swarmraft.net import wire
from swarmraft.net.chunks import Reassembler
from swarmraft.net.wire import WireError
from swarmraft.protocol.records import Report
from swarmraft.raft.types import Message

#: Width of the anti-replay window in sequence numbers (RFC 6479 suggests at least 1024 for
#: IPsec on fast links; at 10 Hz steps a drone sends a few hundred datagrams a second at most).
WINDOW = 1024
KEY_SIZE = 32

_logger = logging.getLogger(__name__)


def public_key(seed: bytes) -> bytes:
    """The 32-byte Ed25519 public key of a 32-byte private key (seed)."""
    return SigningKey(seed).verify_key.encode()


class Signer:
    """One drone's private key: seals messages into signed datagrams from ``sender`` with
    sequence numbers ``first_seq``, ``first_seq + 1``, ... A restarted drone must start above
    every sequence number it sent before (its peers drop the rest as replays), e.g. from a
    persisted counter or the wall clock in microseconds."""

    def __init__(self, sender: int, seed: bytes, first_seq: int = 1) -> None:
        if len(seed) != KEY_SIZE:
            raise ValueError(f"an Ed25519 private key is {KEY_SIZE} bytes, got {len(seed)}")
        self.sender = sender
        self.next_seq = first_seq
        self._key = SigningKey(seed)

    def seal(self, obj: Message | Report | wire.ReportAck) -> bytes:
        """The datagram carrying a Raft message, a signed report or a report's acknowledgement."""
        return self.seal_payload(*wire.encode_payload(obj))

    def seal_all(self, obj: Message | Report | wire.ReportAck) -> list[bytes]:
        """The datagrams carrying ``obj``: one, or for a Raft message larger than one
        datagram (a MsgSnap with a large state, up to `wire.MAX_MESSAGE`) one per piece
        (`wire.Chunk`), each signed."""
        if not isinstance(obj, Message):
            return [self.seal(obj)]
        payload = wire.encode_message(obj, limit=wire.MAX_MESSAGE)
        if len(payload) <= wire.MAX_PAYLOAD:
            return [self.seal_payload(wire.Kind.RAFT, payload)]
        pieces = wire.chunks(payload, self.next_seq)
        return [self.seal_payload(wire.Kind.CHUNK, wire.encode_chunk(c)) for c in pieces]

    def seal_payload(self, kind: wire.Kind, payload: bytes) -> bytes:
        signed = wire.frame(kind, self.sender, self.next_seq, payload)
        self.next_seq += 1
        return signed + self._key.sign(signed).signature


class ReplayWindow:
    """The sequence numbers seen from one sender, as in IPsec and DTLS anti-replay (RFC 4303
    section 3.4.3, RFC 6347 section 4.1.2.6): the highest seen, ``top``, and a bitmap of the
    ``width`` numbers up to it. A number above ``top`` is new; one within the window is new if
    its bit is clear; one older than the window is refused, since it cannot be told apart
    from a replay. ``check`` before the signature is verified, ``mark`` after."""

    def __init__(self, width: int = WINDOW) -> None:
        if width < 1:
            raise ValueError("the replay window must be at least 1 wide")
        self.width = width
        self.top: int | None = None
        self._bits = 0  # bit i: top - i was seen

    def check(self, seq: int) -> str | None:
        """None if ``seq`` is new, else the drop reason: ``replayed`` or ``too_old``."""
        if self.top is None or seq > self.top:
            return None
        behind = self.top - seq
        if behind >= self.width:
            return "too_old"
        return "replayed" if self._bits >> behind & 1 else None

    def mark(self, seq: int) -> None:
        if self.top is None or seq > self.top:
            shift = self.width if self.top is None else min(seq - self.top, self.width)
            self._bits = (self._bits << shift | 1) & ((1 << self.width) - 1)
            self.top = seq
        else:
            self._bits |= 1 << (self.top - seq)


class RateLimitedLog:
    """At most ``per_second`` lines per reason in any one-second window of ``clock``; the
    lines over it are counted in ``suppressed`` and summed up in one line when that reason
    next logs in a new window."""

    def __init__(
        self, logger: logging.Logger, per_second: int = 5, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.logger, self.per_second, self.clock = logger, per_second, clock
        self.suppressed: Counter[str] = Counter()
        self._window: dict[str, tuple[float, int, int]] = {}  # reason: start, written, held back

    def log(self, level: int, reason: str, message: str) -> None:
        now = self.clock()
        start, written, held = self._window.get(reason, (now, 0, 0))
        if now - start >= 1.0:
            if held:
                self.logger.log(level, "%s: %d more lines suppressed", reason, held)
            start, written, held = now, 0, 0
        if written < self.per_second:
            self.logger.log(level, "%s", message)
            written += 1
        else:
            held += 1
            self.suppressed[reason] += 1
        self._window[reason] = (start, written, held)

    def warning(self, reason: str, message: str) -> None:
        self.log(logging.WARNING, reason, message)

    def info(self, reason: str, message: str) -> None:
        self.log(logging.INFO, reason, message)


@dataclass(frozen=True, slots=True)
class Accepted:
    """An authentic, fresh datagram and what it carries."""

    sender: int
    seq: int
    kind: wire.Kind
    message: Message | Report | wire.ReportAck


@dataclass(frozen=True, slots=True)
class Partial:
    """An authentic piece (``index`` of ``count``) of a message not yet whole."""

    sender: int
    index: int
    count: int


@dataclass(frozen=True, slots=True)
class Dropped:
    reason: str  # one of Verifier.REASONS
    detail: str
    sender: int | None = None  # the claimed sender, once the header was read


# Duplicates and misrouted datagrams happen on a lossy radio; the rest point at a fault or an attack.
_QUIET = frozenset({"replayed", "too_old", "wrong_recipient"})


class Verifier:
    """Checks incoming datagrams against every drone's public key, in this order: size
    (``oversized``), layout (``malformed``, ``wrong_version``), sender known
    (``unknown_sender``), sequence fresh (``replayed``, ``too_old``), signature over the exact
    header and payload bytes by the key of the *claimed* sender (``bad_signature``), then the
    payload (``malformed``), that it speaks for the sender (``sender_mismatch``: a Raft
    message's ``frm`` is the sender, a report's drone index is sender - 1, as in the simulator)
    and, given ``own_id``, that a Raft message is addressed here (``wrong_recipient``).
    The window moves only for datagrams whose signature verified."""

    REASONS = (
        "oversized",
        "malformed",
        "wrong_version",
        "unknown_sender",
        "replayed",
        "too_old",
        "bad_signature",
        "sender_mismatch",
        "wrong_recipient",
        "internal_error",  # a bug: counted and logged, never raised (tests pin it at 0)
    )

    def __init__(
        self,
        public_keys: Mapping[int, bytes],
        own_id: int | None = None,
        window: int = WINDOW,
        log: RateLimitedLog | None = None,
    ) -> None:
        self._keys: dict[int, VerifyKey] = {}
        for drone, key in public_keys.items():
            if len(key) != KEY_SIZE:
                raise ValueError(f"drone {drone}: an Ed25519 public key is {KEY_SIZE} bytes, got {len(key)}")
            self._keys[drone] = VerifyKey(bytes(key))
        self.own_id = own_id
        self.width = window
        self._windows: dict[int, ReplayWindow] = {}
        self.log = log or RateLimitedLog(_logger)
        self.counters: Counter[str] = Counter(dict.fromkeys((*self.REASONS, "accepted", "pieces"), 0))
        self.pieces = Reassembler()

    def check(self, data: bytes, origin: str | tuple = "") -> Accepted | Partial | Dropped:
        """What ``data`` carries (a message made whole by its last piece included), a piece
        held, or why it was dropped; ``origin`` (an address: text, or a
        (host, port) tuple, formatted only for a drop's log line) is for the log."""
        try:
            result = self._check(data)
        except Exception as exc:  # one datagram must never stop the node
            result = Dropped("internal_error", f"{type(exc).__name__}: {exc}")
        if isinstance(result, Accepted):
            self.counters["accepted"] += 1
            return result
        if isinstance(result, Partial):
            self.counters["pieces"] += 1
            return result
        self.counters[result.reason] += 1
        who = f" from drone {result.sender}" if result.sender is not None else ""
        if isinstance(origin, tuple):
            origin = ":".join(map(str, origin[:2]))
        where = f" ({origin})" if origin else ""
        line = f"dropped datagram{who}{where}: {result.reason}: {result.detail}"
        if result.reason == "internal_error":
            self.log.log(logging.ERROR, result.reason, line)
        elif result.reason in _QUIET:
            self.log.info(result.reason, line)
        else:
            self.log.warning(result.reason, line)
        return result

    def _check(self, data: bytes) -> Accepted | Partial | Dropped:
        if len(data) > wire.MAX_DATAGRAM:
            return Dropped("oversized", f"{len(data)} bytes, the most is {wire.MAX_DATAGRAM}")
        try:
            d = wire.parse(data)
        except WireError as exc:
            return Dropped("wrong_version" if exc.reason == "bad_version" else "malformed", str(exc))
        key = self._keys.get(d.sender)
        if key is None:
            return Dropped("unknown_sender", "no public key for this id", d.sender)
        window = self._windows.get(d.sender)
        if window is None:
            window = self._windows[d.sender] = ReplayWindow(self.width)
        if (stale := window.check(d.seq)) is not None:
            return Dropped(stale, f"sequence {d.seq}, highest seen {window.top}", d.sender)
        try:
            key.verify(d.signed, d.signature)
        except BadSignatureError:
            return Dropped("bad_signature", f"sequence {d.seq}", d.sender)
        window.mark(d.seq)
        try:
            message = wire.decode_payload(d.kind, d.payload)
        except WireError as exc:
            return Dropped("malformed", f"signed payload: {exc}", d.sender)
        kind = d.kind
        if isinstance(message, wire.Chunk):
            whole = self.pieces.add(d.sender, message)
            if whole is None:
                return Partial(d.sender, message.index, message.count)
            try:
                message, kind = wire.decode_message(whole), wire.Kind.RAFT
            except WireError as exc:
                return Dropped("malformed", f"message in {message.count} pieces: {exc}", d.sender)
        if isinstance(message, Message):
            if message.frm != d.sender:
                return Dropped("sender_mismatch", f"Raft message from {message.frm}", d.sender)
            if self.own_id is not None and message.to != self.own_id:
                return Dropped("wrong_recipient", f"Raft message to {message.to}", d.sender)
        elif isinstance(message, wire.ReportAck):
            if self.own_id is not None and message.to != self.own_id:
                return Dropped("wrong_recipient", f"acknowledgement for drone {message.to}", d.sender)
        elif message.drone + 1 != d.sender:
            return Dropped("sender_mismatch", f"report of drone index {message.drone}", d.sender)
        return Accepted(d.sender, d.seq, kind, message)
