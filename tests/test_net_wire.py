"""The datagram format: every Raft message and report survives a round trip, the header is
laid out as docs/net.md says, and anything malformed is a WireError with a reason, never
another exception."""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmraft.net import wire
from swarmraft.net.wire import MAX_DATAGRAM, MAX_PAYLOAD, Kind, WireError
from swarmraft.protocol.records import Report
from swarmraft.raft.types import Entry, EntryKind, Message, MsgType, Snapshot

U32, U64 = 2**32 - 1, 2**64 - 1
SIG = bytes(range(64))

entries = st.builds(
    Entry,
    term=st.integers(0, U64),
    index=st.integers(0, U64),
    data=st.binary(max_size=300),
    kind=st.sampled_from(EntryKind),
)
snapshots = st.builds(
    Snapshot,
    index=st.integers(0, U64),
    term=st.integers(0, U64),
    data=st.binary(max_size=300),
    voters=st.lists(st.integers(0, U32), max_size=7).map(tuple),
    learners=st.lists(st.integers(0, U32), max_size=7).map(tuple),
)
messages = st.builds(
    Message,
    type=st.sampled_from([t for t in MsgType if t != MsgType.SNAP]),
    frm=st.integers(0, U32),
    to=st.integers(0, U32),
    term=st.integers(0, U64),
    log_term=st.integers(0, U64),
    index=st.integers(0, U64),
    entries=st.lists(entries, max_size=8).map(tuple),
    commit=st.integers(0, U64),
    reject=st.booleans(),
    reject_hint=st.integers(0, U64),
    force=st.booleans(),
)
# MsgSnap carries a snapshot (and only it does)
messages = messages | st.builds(
    lambda m, s: Message(MsgType.SNAP, m.frm, m.to, m.term, m.log_term, m.index, m.entries, snapshot=s),
    messages,
    snapshots,
)
floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@st.composite
def reports(draw) -> Report:
    n = draw(st.integers(0, 40))
    innovation = draw(st.one_of(st.none(), st.lists(floats, min_size=3, max_size=3)))
    return Report(
        step=draw(st.integers(-(2**31), 2**31 - 1)),
        drone=draw(st.integers(0, 2**31 - 1)),
        position=np.array(draw(st.lists(floats, min_size=3, max_size=3))),
        source=draw(st.sampled_from(["gnss", "ins"])),
        ranges=np.array(draw(st.lists(floats, min_size=n, max_size=n)), dtype=float),
        innovation=None if innovation is None else np.array(innovation),
        signature=draw(st.binary(min_size=64, max_size=64)),
    )


def datagram(kind: Kind, payload: bytes, sender: int = 3, seq: int = 1) -> bytes:
    return wire.frame(kind, sender, seq, payload) + SIG


def heartbeat() -> Message:
    return Message(MsgType.HEARTBEAT, frm=1, to=2, term=5, commit=9)


def a_report(n: int = 4) -> Report:
    return Report(7, 2, np.array([1.0, 2.0, 3.0]), "gnss", np.arange(n, dtype=float), None, SIG)


# --- round trips ---------------------------------------------------------------------------


@given(messages)
@settings(max_examples=300)
def test_every_raft_message_round_trips(msg):
    kind, payload = wire.encode_payload(msg)
    d = wire.parse(datagram(kind, payload, sender=msg.frm))
    assert d.kind == Kind.RAFT
    assert wire.decode_payload(d.kind, d.payload) == msg


@pytest.mark.parametrize("t", list(MsgType))
def test_every_message_type_has_a_wire_code(t):
    snap = Snapshot(9, 3, b"s", (1, 2, 3)) if t == MsgType.SNAP else None
    msg = Message(t, 1, 2, 3, 4, 5, (Entry(1, 6, b"x", EntryKind.NOOP),), 7, True, 8, snapshot=snap)
    assert wire.decode_message(wire.encode_message(msg)) == msg


def test_membership_codes_are_fixed():
    # the codes of the membership messages and entries (issue 12): a peer of another version
    # must read them the same
    for t, code in ((MsgType.TIMEOUT_NOW, 10), (MsgType.READ_INDEX, 11), (MsgType.READ_INDEX_RESP, 12)):
        assert wire.encode_message(Message(t, 1, 2, 3))[0] == code
    e = Entry(1, 2, b"promote 4", EntryKind.CONF_CHANGE)
    raw = wire.encode_message(Message(MsgType.APP, 1, 2, 3, entries=(e,)))
    assert raw[54 + 16] == 2
    assert wire.decode_message(raw).entries == (e,)


@given(reports())
@settings(max_examples=200)
def test_every_signed_report_round_trips_bit_for_bit(report):
    kind, payload = wire.encode_payload(report)
    d = wire.parse(datagram(kind, payload))
    back = wire.decode_payload(d.kind, d.payload)
    assert d.kind == Kind.REPORT
    assert isinstance(back, Report)
    assert back.encode() == report.encode()
    assert (back.step, back.drone, back.source, back.signature) == (
        report.step,
        report.drone,
        report.source,
        report.signature,
    )


@given(st.sampled_from(Kind), st.integers(0, U32), st.integers(0, U64), st.binary(max_size=2000))
def test_datagram_fields_round_trip(kind, sender, seq, payload):
    data = wire.frame(kind, sender, seq, payload) + SIG
    d = wire.parse(data)
    assert (d.kind, d.sender, d.seq, d.payload, d.signature) == (kind, sender, seq, payload, SIG)
    assert d.signed == data[:-64]


def test_header_is_laid_out_byte_by_byte_as_documented():
    data = wire.frame(Kind.REPORT, 0x01020304, 0x0A0B0C0D0E0F1011, b"xyz")
    assert data == (
        b"SR"  # magic
        + b"\x01"  # version
        + b"\x02"  # kind REPORT
        + bytes([4, 3, 2, 1])  # sender u32 little-endian
        + bytes([0x11, 0x10, 0x0F, 0x0E, 0x0D, 0x0C, 0x0B, 0x0A])  # seq u64
        + bytes([3, 0, 0, 0])  # payload length u32
        + b"xyz"
    )
    assert wire.HEADER_SIZE == 20


def test_raft_message_is_laid_out_as_documented():
    msg = Message(MsgType.APP, 1, 2, 3, 4, 5, (Entry(6, 7, b"ab", EntryKind.NOOP),), 8, True, 9)
    head = struct.pack("<BBIIQQQQQI", 2, 1, 1, 2, 3, 4, 5, 8, 9, 1)
    assert wire.encode_message(msg) == head + struct.pack("<QQBI", 6, 7, 1, 2) + b"ab"


def test_a_datagram_of_the_largest_size_is_accepted():
    data = datagram(Kind.RAFT, bytes(MAX_PAYLOAD))
    assert len(data) == MAX_DATAGRAM
    assert wire.parse(data).payload == bytes(MAX_PAYLOAD)


# --- malformed datagrams -------------------------------------------------------------------


def reason(fn, *args) -> str:
    with pytest.raises(WireError) as exc:
        fn(*args)
    return exc.value.reason


def test_every_truncation_of_a_datagram_is_refused():
    data = datagram(*wire.encode_payload(heartbeat()))
    for cut in range(len(data)):
        assert reason(wire.parse, data[:cut]) in ("truncated", "length_mismatch")


def test_trailing_bytes_after_the_signature_are_refused():
    assert reason(wire.parse, datagram(Kind.RAFT, b"abc") + b"\x00") == "length_mismatch"


def test_wrong_magic_version_and_kind_are_refused():
    data = bytearray(datagram(Kind.RAFT, b"abc"))
    assert reason(wire.parse, b"XX" + bytes(data[2:])) == "bad_magic"
    for version in (0, 2, 255):
        data[2] = version
        assert reason(wire.parse, bytes(data)) == "bad_version"
    data[2] = wire.VERSION
    for kind in (0, 7, 255):
        data[3] = kind
        assert reason(wire.parse, bytes(data)) == "unknown_kind"


@pytest.mark.parametrize("claimed", [0, 2, 4, 2**32 - 1])
def test_a_payload_length_that_disagrees_with_the_size_is_refused(claimed):
    data = bytearray(datagram(Kind.RAFT, b"abc"))
    data[16:20] = claimed.to_bytes(4, "little")
    assert reason(wire.parse, bytes(data)) == "length_mismatch"


def test_oversized_datagrams_are_refused_before_parsing():
    assert reason(wire.parse, b"\xff" * (MAX_DATAGRAM + 1)) == "oversized"
    assert reason(wire.frame, Kind.RAFT, 1, 1, bytes(MAX_PAYLOAD + 1)) == "oversized"


def test_a_message_too_big_for_one_datagram_is_not_encoded():
    big = Message(MsgType.APP, 1, 2, 1, entries=tuple(Entry(1, i, bytes(1400)) for i in range(64)))
    assert reason(wire.encode_message, big) == "oversized"


@pytest.mark.parametrize(
    "field,value",
    [("term", -1), ("frm", 2**32), ("commit", 2**64), ("index", 1.5), ("reject_hint", None)],
)
def test_out_of_range_fields_are_not_encoded(field, value):
    msg = heartbeat()
    setattr(msg, field, value)
    assert reason(wire.encode_message, msg) == "bad_value"


def test_negative_sender_and_sequence_are_not_framed():
    assert reason(wire.frame, Kind.RAFT, -1, 1, b"") == "bad_value"
    assert reason(wire.frame, Kind.RAFT, 1, 2**64, b"") == "bad_value"


# --- malformed payloads --------------------------------------------------------------------


def raft_payload() -> bytearray:
    msg = Message(MsgType.APP, 1, 2, 3, entries=(Entry(3, 4, b"data"), Entry(3, 5, b"")))
    return bytearray(wire.encode_message(msg))


def test_unknown_message_type_entry_kind_and_flags_are_refused():
    for code in (0, 14, 255):
        p = raft_payload()
        p[0] = code
        assert reason(wire.decode_message, bytes(p)) == "bad_value"
    p = raft_payload()
    p[1] = 0x04
    assert reason(wire.decode_message, bytes(p)) == "bad_value"
    p = raft_payload()
    p[54 + 16] = 7  # first entry's kind
    assert reason(wire.decode_message, bytes(p)) == "bad_value"


def test_an_entry_count_beyond_the_payload_is_refused_without_reading_on():
    p = raft_payload()
    p[50:54] = (2**32 - 1).to_bytes(4, "little")
    assert reason(wire.decode_message, bytes(p)) == "bad_value"


def test_an_entry_length_beyond_the_payload_is_refused():
    p = raft_payload()
    p[54 + 17 : 54 + 21] = (2**32 - 1).to_bytes(4, "little")
    assert reason(wire.decode_message, bytes(p)) == "truncated"


def test_every_truncation_of_a_raft_payload_is_refused():
    p = bytes(raft_payload())
    for cut in range(len(p)):
        assert reason(wire.decode_message, p[:cut]) in ("truncated", "bad_value")


def test_bytes_after_the_last_entry_are_refused():
    assert reason(wire.decode_message, bytes(raft_payload()) + b"\x00") == "trailing_bytes"


def test_every_truncation_and_extension_of_a_report_is_refused():
    p = wire.encode_report(a_report())
    for cut in range(len(p)):
        assert reason(wire.decode_report, p[:cut]) == "bad_report"
    assert reason(wire.decode_report, p + b"\x00") == "bad_report"


def test_report_with_an_unknown_source_or_innovation_flag_is_refused():
    p = bytearray(wire.encode_report(a_report()))
    p[8] = 2  # source
    assert reason(wire.decode_report, bytes(p)) == "bad_report"
    p = bytearray(wire.encode_report(a_report(n=4)))
    p[9] = 2  # has innovation: 2 would read 6 values, more than the report holds
    assert reason(wire.decode_report, bytes(p)) == "bad_report"


def test_report_with_an_innovation_flag_of_2_is_refused_even_when_the_sizes_add_up():
    r = a_report(n=4)
    with_innovation = Report(r.step, r.drone, r.position, r.source, r.ranges, r.position, SIG)
    p = bytearray(wire.encode_report(with_innovation))
    p[9] = 2  # 3 + 1 + 2*3 values: as many as 3 + 4 + 3, so only the flag is wrong
    p[10:12] = (1).to_bytes(2, "little")
    assert reason(wire.decode_report, bytes(p)) == "bad_report"


def test_unsigned_report_is_not_encoded():
    r = a_report()
    unsigned = Report(r.step, r.drone, r.position, r.source, r.ranges, r.innovation)
    assert reason(wire.encode_report, unsigned) == "bad_report"


@given(st.binary(max_size=400))
@settings(max_examples=500)
def test_no_bytes_make_the_decoders_raise_anything_but_wire_error(data):
    for fn in (wire.parse, wire.decode_message, wire.decode_report):
        try:
            fn(data)
        except WireError:
            pass


@given(st.sampled_from(Kind), st.binary(max_size=400))
@settings(max_examples=500)
def test_no_payload_in_a_valid_frame_makes_decoding_raise_anything_but_wire_error(kind, payload):
    d = wire.parse(datagram(kind, payload))
    try:
        wire.decode_payload(d.kind, d.payload)
    except WireError:
        pass


@given(messages, st.data())
@settings(max_examples=200)
def test_flipping_any_byte_of_a_raft_payload_decodes_or_is_a_wire_error(msg, data):
    p = bytearray(wire.encode_message(msg))
    i = data.draw(st.integers(0, len(p) - 1))
    p[i] ^= data.draw(st.integers(1, 255))
    try:
        wire.decode_message(bytes(p))
    except WireError:
        pass


@given(st.integers(0, U64), st.integers(0, U32))
def test_a_report_acknowledgement_round_trips_in_12_bytes(step, to):
    kind, payload = wire.encode_payload(wire.ReportAck(step, to))
    assert kind == Kind.REPORT_ACK and payload == struct.pack("<QI", step, to)
    assert wire.decode_payload(kind, payload) == wire.ReportAck(step, to)


def test_an_acknowledgement_of_another_length_or_out_of_range_is_refused():
    for payload in (b"", bytes(11), bytes(13)):
        with pytest.raises(WireError, match="length_mismatch"):
            wire.decode_payload(Kind.REPORT_ACK, payload)
    with pytest.raises(WireError):
        wire.encode_payload(wire.ReportAck(-1, 2))
    with pytest.raises(WireError):
        wire.encode_payload(wire.ReportAck(1, 2**32))


def test_a_snapshot_goes_with_msgsnap_only_and_a_cut_one_is_refused():
    with pytest.raises(WireError, match="MsgSnap"):
        wire.encode_message(Message(MsgType.SNAP, 1, 2, 3))
    with pytest.raises(WireError, match="MsgSnap"):
        wire.encode_message(Message(MsgType.APP, 1, 2, 3, snapshot=Snapshot(4, 3, b"s")))
    snap = Snapshot(4, 3, b"state", (1, 2), (3,))
    whole = wire.encode_message(Message(MsgType.SNAP, 1, 2, 3, snapshot=snap))
    with pytest.raises(WireError, match="truncated"):
        wire.decode_message(whole[:-1])
