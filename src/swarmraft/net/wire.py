"""The datagram format of the networked runtime: a versioned header, a payload, a signature.

Pure functions, bytes in and bytes out: ``frame(kind, sender, seq, payload)`` gives the bytes
to sign, the caller appends the 64-byte Ed25519 signature; ``parse(data)`` checks the layout
and gives a `Datagram`; ``encode_payload``/``decode_payload`` turn Raft messages and reports
into payload bytes and back. Anything malformed raises `WireError` (never another
exception); no I/O, no clock, no keys (signing and checking are `swarmraft.net.auth`'s).

Layout (little-endian, as `swarmraft.protocol.records`), offsets in bytes:

    0  magic    2  b"SR"
    2  version  1  VERSION (1)
    3  kind     1  Kind: 1 RAFT, 2 REPORT, 3 STATUS_REQUEST, 4 STATUS_REPLY, 5 REPORT_ACK
                   (0 and 6-255 reserved)
    4  sender   4  u32 sender id (the Raft node id, 1..n)
    8  seq      8  u64 per-sender sequence number, increasing
   16  length   4  u32 payload length in bytes
   20  payload  length bytes
   20+length  signature  64  Ed25519 over bytes [0, 20+length)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from swarmraft.protocol.records import Report
from swarmraft.raft.types import Entry, EntryKind, Message, MsgType, Snapshot

MAGIC = b"SR"
VERSION = 1
SIGNATURE_SIZE = 64
#: Largest datagram accepted or produced, in bytes. The largest UDP payload over IPv4 is
#: 65,507 bytes (65,535 less the 20-byte IP and 8-byte UDP headers); 60,000 leaves room for IP
#: options and IPv6 extension headers, so every datagram fits one UDP packet and one 64 KiB
#: receive buffer, and a larger one is refused before any parsing.
MAX_DATAGRAM = 60_000

_HEADER = struct.Struct("<2sBBIQI")  # magic, version, kind, sender, seq, payload length
HEADER_SIZE = _HEADER.size  # 20
#: Largest payload a datagram can carry.
MAX_PAYLOAD = MAX_DATAGRAM - HEADER_SIZE - SIGNATURE_SIZE

_U32 = 2**32 - 1
_U64 = 2**64 - 1

# Raft message: type, flags (bit 0: reject, bit 1: force), frm, to, term, log_term, index, commit,
# reject_hint, number of entries; then each entry: term, index, kind, data length, data;
# then, for MsgSnap only, the snapshot: index, term, number of voters, of learners, data
# length, the voter and learner ids (u32 each), the data.
_MESSAGE = struct.Struct("<BBIIQQQQQI")
_ENTRY = struct.Struct("<QQBI")
_SNAPSHOT = struct.Struct("<QQHHI")
_REJECT = 0x01
_FORCE = 0x02

# Codes are fixed here, not taken from enum order, so a new member cannot shift old codes.
_MSG_CODES: dict[MsgType, int] = {
    MsgType.PROP: 1,
    MsgType.APP: 2,
    MsgType.APP_RESP: 3,
    MsgType.VOTE: 4,
    MsgType.VOTE_RESP: 5,
    MsgType.PRE_VOTE: 6,
    MsgType.PRE_VOTE_RESP: 7,
    MsgType.HEARTBEAT: 8,
    MsgType.HEARTBEAT_RESP: 9,
    MsgType.TIMEOUT_NOW: 10,
    MsgType.READ_INDEX: 11,
    MsgType.READ_INDEX_RESP: 12,
    MsgType.SNAP: 13,
}
_MSG_TYPES = {code: t for t, code in _MSG_CODES.items()}
_KIND_CODES: dict[EntryKind, int] = {EntryKind.NORMAL: 0, EntryKind.NOOP: 1, EntryKind.CONF_CHANGE: 2}
_ENTRY_KINDS = {code: k for k, code in _KIND_CODES.items()}


class Kind(IntEnum):
    """What a datagram's payload holds."""

    RAFT = 1  # a raft.types.Message
    REPORT = 2  # a protocol.records.Report, as Report.encode() writes it (signed)
    STATUS_REQUEST = 3  # `swarmraft status` asking a drone: sender 0, seq a nonce, no payload, no signature
    STATUS_REPLY = 4  # a drone's answer: UTF-8 JSON (net.status), signed by the drone
    REPORT_ACK = 5  # the leader's acknowledgement of a report: a ReportAck
    CHUNK = 6  # a piece of a Raft message too big for one datagram: a Chunk


#: Largest Raft message sent in pieces (a MsgSnap carrying a drone's state, `Chunk`).
MAX_MESSAGE = 16 * 2**20
_CHUNK = struct.Struct("<QHHI")  # message id, piece index, number of pieces, message length
#: Bytes of the message each piece but the last carries.
CHUNK_DATA = MAX_PAYLOAD - _CHUNK.size


@dataclass(frozen=True, slots=True)
class Chunk:
    """Piece ``index`` of ``count`` of a Raft message of ``length`` bytes (its
    `encode_message` bytes) that does not fit one datagram. ``message`` names the whole: the
    sender's sequence number of the first piece, so it grows with every message a drone
    sends and a receiver can tell a newer message from an older one. Every piece but the last
    carries CHUNK_DATA bytes; each piece is a datagram signed on its own."""

    message: int
    index: int
    count: int
    length: int
    data: bytes


@dataclass(frozen=True, slots=True)
class ReportAck:
    """The leader took drone ``to``'s report of ``step`` (so the drone need not resend it)."""

    step: int
    to: int


_ACK = struct.Struct("<QI")  # step, the drone id it acknowledges


class WireError(ValueError):
    """A datagram or payload that does not follow the format. ``reason`` is a short code
    (``truncated``, ``bad_magic``, ``bad_version``, ``unknown_kind``, ``length_mismatch``,
    ``oversized``, ``bad_value``, ``trailing_bytes``, ``bad_report``); the message says more."""

    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        super().__init__(f"{reason}: {detail}")


@dataclass(frozen=True, slots=True)
class Datagram:
    """A parsed datagram. ``signed`` is the exact header+payload bytes the signature covers."""

    kind: Kind
    sender: int
    seq: int
    payload: bytes
    signed: bytes
    signature: bytes


def frame(kind: Kind, sender: int, seq: int, payload: bytes) -> bytes:
    """Header + payload: the bytes to sign. The datagram is these bytes + the signature."""
    _check_int("sender", sender, _U32)
    _check_int("seq", seq, _U64)
    if len(payload) > MAX_PAYLOAD:
        raise WireError("oversized", f"payload of {len(payload)} bytes, the most is {MAX_PAYLOAD}")
    return _HEADER.pack(MAGIC, VERSION, Kind(kind), sender, seq, len(payload)) + payload


def parse(data: bytes) -> Datagram:
    """The datagram in ``data``, its layout checked (not its signature, not its payload)."""
    size = len(data)
    if size > MAX_DATAGRAM:
        raise WireError("oversized", f"{size} bytes, the most is {MAX_DATAGRAM}")
    if size < HEADER_SIZE + SIGNATURE_SIZE:
        raise WireError("truncated", f"{size} bytes, shorter than header and signature")
    magic, version, kind, sender, seq, length = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise WireError("bad_magic", f"starts with {bytes(magic)!r}, not {MAGIC!r}")
    if version != VERSION:
        raise WireError("bad_version", f"version {version}, this program speaks {VERSION}")
    if kind not in Kind._value2member_map_:
        raise WireError("unknown_kind", f"kind {kind}")
    end = HEADER_SIZE + length
    if end + SIGNATURE_SIZE != size:
        held = size - HEADER_SIZE - SIGNATURE_SIZE
        raise WireError("length_mismatch", f"header says {length} payload bytes, the datagram holds {held}")
    data = bytes(data)
    return Datagram(Kind(kind), sender, seq, data[HEADER_SIZE:end], data[:end], data[end:])


def chunks(payload: bytes, message: int) -> list[Chunk]:
    """A Raft message's bytes (at most MAX_MESSAGE) in pieces of CHUNK_DATA bytes."""
    if len(payload) > MAX_MESSAGE:
        raise WireError("oversized", f"message of {len(payload)} bytes, the most in pieces is {MAX_MESSAGE}")
    size, d = len(payload), CHUNK_DATA
    count = -(-size // d)
    return [Chunk(message, i, count, size, payload[i * d : (i + 1) * d]) for i in range(count)]


def encode_chunk(c: Chunk) -> bytes:
    _check_int("chunk message", c.message, _U64)
    return _CHUNK.pack(c.message, c.index, c.count, c.length) + c.data


def decode_chunk(payload: bytes) -> Chunk:
    """A piece, checked against its own header: a piece number below the count, the count
    the length needs (at least 2: a message that fits one datagram is not sent in pieces), and
    CHUNK_DATA bytes in every piece but the last, the rest in the last."""
    if len(payload) < _CHUNK.size:
        raise WireError("truncated", f"a piece of {len(payload)} bytes, the header is {_CHUNK.size}")
    message, index, count, length = _CHUNK.unpack_from(payload)
    if not MAX_PAYLOAD < length <= MAX_MESSAGE:
        raise WireError("bad_value", f"a message of {length} bytes is not sent in pieces")
    if count != -(-length // CHUNK_DATA) or index >= count:
        raise WireError("bad_value", f"piece {index} of {count} for a message of {length} bytes")
    want = CHUNK_DATA if index < count - 1 else length - (count - 1) * CHUNK_DATA
    if (held := len(payload) - _CHUNK.size) != want:
        raise WireError("length_mismatch", f"piece {index} holds {held} bytes, not {want}")
    return Chunk(message, index, count, length, bytes(payload[_CHUNK.size :]))


def encode_payload(obj: Message | Report | ReportAck) -> tuple[Kind, bytes]:
    """A Raft message, a signed report or a report's acknowledgement as (kind, payload bytes)."""
    if isinstance(obj, Message):
        return Kind.RAFT, encode_message(obj)
    if isinstance(obj, Report):
        return Kind.REPORT, encode_report(obj)
    if isinstance(obj, ReportAck):
        _check_int("step", obj.step, _U64)
        _check_int("to", obj.to, _U32)
        return Kind.REPORT_ACK, _ACK.pack(obj.step, obj.to)
    raise WireError("bad_value", f"cannot encode a {type(obj).__name__}")


def decode_payload(kind: Kind, payload: bytes) -> Message | Report | ReportAck | Chunk:
    """The Raft message, report, acknowledgement or piece of a message a payload holds; a
    status datagram is not for a drone."""
    if kind == Kind.RAFT:
        return decode_message(payload)
    if kind == Kind.CHUNK:
        return decode_chunk(payload)
    if kind == Kind.REPORT:
        return decode_report(payload)
    if kind == Kind.REPORT_ACK:
        if len(payload) != _ACK.size:
            raise WireError("length_mismatch", f"an acknowledgement of {len(payload)} bytes, not {_ACK.size}")
        return ReportAck(*_ACK.unpack(payload))
    raise WireError("unknown_kind", f"kind {kind} ({kind.name}) is not for a drone")


def status_request(nonce: int) -> bytes:
    """A status request: a header of kind STATUS_REQUEST, sender 0, the nonce as its sequence
    number, no payload, and 64 zero bytes where a signature would be (it is not signed: anyone
    may ask; the answer is signed)."""
    return frame(Kind.STATUS_REQUEST, 0, nonce, b"") + bytes(SIGNATURE_SIZE)


def status_request_nonce(data: bytes) -> int | None:
    """The nonce of a well-formed status request, or None if ``data`` is not one."""
    if len(data) != HEADER_SIZE + SIGNATURE_SIZE:
        return None
    magic, version, kind, sender, seq, length = _HEADER.unpack_from(data)
    if (magic, version, kind, sender, length) != (MAGIC, VERSION, Kind.STATUS_REQUEST, 0, 0):
        return None
    return seq


def encode_message(msg: Message, limit: int = MAX_PAYLOAD) -> bytes:
    """A Raft message as bytes: every field, entries with their term, index, kind and data;
    WireError ``oversized`` past ``limit`` bytes (MAX_MESSAGE: for a message sent in pieces)."""
    if msg.type not in _MSG_CODES:
        raise WireError("bad_value", f"message type {msg.type!r}")
    for name in ("frm", "to"):
        _check_int(name, getattr(msg, name), _U32)
    for name in ("term", "log_term", "index", "commit", "reject_hint"):
        _check_int(name, getattr(msg, name), _U64)
    for name in ("reject", "force"):
        if not isinstance(getattr(msg, name), bool):
            raise WireError("bad_value", f"{name} = {getattr(msg, name)!r}, not a bool")
    parts = [
        _MESSAGE.pack(
            _MSG_CODES[msg.type],
            (_REJECT if msg.reject else 0) | (_FORCE if msg.force else 0),
            msg.frm,
            msg.to,
            msg.term,
            msg.log_term,
            msg.index,
            msg.commit,
            msg.reject_hint,
            len(msg.entries),
        )
    ]
    for e in msg.entries:
        _check_int("entry term", e.term, _U64)
        _check_int("entry index", e.index, _U64)
        if e.kind not in _KIND_CODES:
            raise WireError("bad_value", f"entry kind {e.kind!r}")
        if not isinstance(e.data, bytes):
            raise WireError("bad_value", f"entry data is a {type(e.data).__name__}, not bytes")
        parts.append(_ENTRY.pack(e.term, e.index, _KIND_CODES[e.kind], len(e.data)))
        parts.append(e.data)
    if (msg.type == MsgType.SNAP) != (msg.snapshot is not None):
        raise WireError("bad_value", "a snapshot goes with MsgSnap, and only with it")
    if (s := msg.snapshot) is not None:
        _check_int("snapshot index", s.index, _U64)
        _check_int("snapshot term", s.term, _U64)
        for i in (*s.voters, *s.learners):
            _check_int("snapshot member", i, _U32)
        parts.append(_SNAPSHOT.pack(s.index, s.term, len(s.voters), len(s.learners), len(s.data)))
        parts.append(struct.pack(f"<{len(s.voters) + len(s.learners)}I", *s.voters, *s.learners))
        parts.append(s.data)
    out = b"".join(parts)
    if len(out) > limit:
        raise WireError("oversized", f"message of {len(out)} bytes, the most is {limit}")
    return out


def decode_message(payload: bytes) -> Message:
    if len(payload) < _MESSAGE.size:
        raise WireError("truncated", f"Raft message of {len(payload)} bytes, the header is {_MESSAGE.size}")
    code, flags, frm, to, term, log_term, index, commit, hint, count = _MESSAGE.unpack_from(payload)
    if code not in _MSG_TYPES:
        raise WireError("bad_value", f"message type code {code}")
    if flags & ~(_REJECT | _FORCE):
        raise WireError("bad_value", f"unknown flag bits {flags:#04x}")
    off = _MESSAGE.size
    if count > (len(payload) - off) // _ENTRY.size:
        raise WireError("bad_value", f"{count} entries cannot fit in {len(payload) - off} bytes")
    entries = []
    for _ in range(count):
        if off + _ENTRY.size > len(payload):
            raise WireError("truncated", f"entry {len(entries)} header runs past the payload")
        e_term, e_index, e_kind, length = _ENTRY.unpack_from(payload, off)
        off += _ENTRY.size
        if e_kind not in _ENTRY_KINDS:
            raise WireError("bad_value", f"entry kind code {e_kind}")
        if off + length > len(payload):
            raise WireError("truncated", f"entry {len(entries)} data runs past the payload")
        entries.append(Entry(e_term, e_index, bytes(payload[off : off + length]), _ENTRY_KINDS[e_kind]))
        off += length
    snap = None
    if _MSG_TYPES[code] == MsgType.SNAP:
        snap, off = _decode_snapshot(payload, off)
    if off != len(payload):
        raise WireError("trailing_bytes", f"{len(payload) - off} bytes after the last entry")
    return Message(
        _MSG_TYPES[code],
        frm,
        to,
        term,
        log_term,
        index,
        tuple(entries),
        commit,
        bool(flags & _REJECT),
        hint,
        bool(flags & _FORCE),
        snap,
    )


def _decode_snapshot(payload: bytes, off: int) -> tuple[Snapshot, int]:
    if off + _SNAPSHOT.size > len(payload):
        raise WireError("truncated", "the snapshot header runs past the payload")
    index, term, n_voters, n_learners, length = _SNAPSHOT.unpack_from(payload, off)
    off += _SNAPSHOT.size
    ids_end = off + 4 * (n_voters + n_learners)
    if ids_end + length > len(payload):
        raise WireError("truncated", "the snapshot's members or data run past the payload")
    ids = struct.unpack_from(f"<{n_voters + n_learners}I", payload, off)
    data = bytes(payload[ids_end : ids_end + length])
    return Snapshot(index, term, data, tuple(ids[:n_voters]), tuple(ids[n_voters:])), ids_end + length


def encode_report(report: Report) -> bytes:
    """A signed report as `Report.encode` writes it."""
    if len(report.signature) != SIGNATURE_SIZE:
        raise WireError("bad_report", f"report signature of {len(report.signature)} bytes, not 64")
    try:
        out = report.encode()
    except (struct.error, ValueError, TypeError) as exc:
        raise WireError("bad_value", f"report does not encode: {exc}") from None
    if len(out) > MAX_PAYLOAD:
        raise WireError("oversized", f"report of {len(out)} bytes, the most is {MAX_PAYLOAD}")
    return out


def decode_report(payload: bytes) -> Report:
    """A signed report. `Report.decode` checks nothing, so the decoded report must encode
    back to exactly ``payload`` with a 64-byte signature: no field out of range, no bytes
    missing or left over."""
    try:
        report = Report.decode(payload)
    except (struct.error, ValueError, IndexError, TypeError) as exc:
        raise WireError("bad_report", f"report does not decode: {exc}") from None
    if len(report.signature) != SIGNATURE_SIZE:
        raise WireError("bad_report", f"{len(report.signature)} bytes after the report body, not a signature")
    if report.encode() != payload:
        raise WireError("bad_report", "report fields out of range (it does not encode back to its bytes)")
    return report


def _check_int(name: str, value: object, top: int) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= top:
        raise WireError("bad_value", f"{name} = {value!r}, not an integer in [0, {top}]")
