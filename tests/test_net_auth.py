"""Datagram authentication: a Verifier accepts a datagram only from a known sender, with a
valid signature over its exact bytes, a sequence number it has not seen (sliding window) and a
payload that speaks for that sender; everything else is dropped, counted and never raised."""

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from nacl.signing import SigningKey, VerifyKey

from swarmraft.net import wire
from swarmraft.net.auth import (
    Accepted,
    Dropped,
    RateLimitedLog,
    ReplayWindow,
    Signer,
    Verifier,
    public_key,
)
from swarmraft.protocol.records import Report
from swarmraft.protocol.signing import Keyring
from swarmraft.raft.types import Entry, Message, MsgType

SEEDS = {i: bytes([i]) * 32 for i in range(1, 6)}  # drones 1..5
PUBLIC = {i: public_key(s) for i, s in SEEDS.items()}
OUTSIDER = bytes([99]) * 32


def verifier(**kw) -> Verifier:
    return Verifier(PUBLIC, **kw)


def msg(frm: int = 3, to: int = 1, term: int = 2) -> Message:
    return Message(MsgType.APP, frm, to, term, 1, 4, (Entry(2, 5, b"record"),), 4)


def report(drone: int = 2) -> Report:
    """A report of drone index ``drone`` (Raft id drone + 1), signed as protocol.signing does."""
    keys = Keyring.generate(5, np.random.default_rng(0))
    r = Report(9, drone, np.array([1.0, 2.0, 3.0]), "gnss", np.arange(5.0), None)
    return keys.sign(r)


def dropped(result, reason: str) -> None:
    assert isinstance(result, Dropped), result
    assert result.reason == reason, result


# --- what is accepted ----------------------------------------------------------------------


def test_a_signed_raft_message_is_accepted_and_decoded():
    v = verifier(own_id=1)
    got = v.check(Signer(3, SEEDS[3]).seal(msg()))
    assert got == Accepted(sender=3, seq=1, kind=wire.Kind.RAFT, message=msg())
    assert v.counters["accepted"] == 1
    assert sum(v.counters.values()) == 1


def test_a_signed_report_is_accepted_from_the_drone_it_is_about():
    r = report(drone=2)
    got = verifier().check(Signer(3, SEEDS[3]).seal(r))
    assert isinstance(got, Accepted)
    assert got.message.encode() == r.encode()


def test_sequence_numbers_increase_from_the_first():
    s = Signer(2, SEEDS[2], first_seq=41)
    seqs = [wire.parse(s.seal(msg(frm=2))).seq for _ in range(3)]
    assert seqs == [41, 42, 43]
    assert s.next_seq == 44


def test_each_sender_has_its_own_sequence_space():
    v = verifier(own_id=1)
    for sender in (2, 3, 4):
        assert isinstance(v.check(Signer(sender, SEEDS[sender]).seal(msg(frm=sender))), Accepted)
    assert v.counters["accepted"] == 3


def test_a_drones_report_key_and_datagram_key_are_one_key():
    """protocol.signing signs reports, net.auth datagrams: one 32-byte seed serves both."""
    keys = Keyring.generate(5, np.random.default_rng(0))
    seed = np.random.default_rng(0).bytes(32)  # drone 0's seed, as Keyring.generate draws it
    assert bytes(keys.public[0]) == bytes(SigningKey(seed).verify_key)
    r = keys.sign(Report(9, 0, np.array([1.0, 2.0, 3.0]), "gnss", np.arange(5.0), None))
    VerifyKey(bytes(keys.public[0])).verify(r.body(), r.signature)  # raises if it does not hold


# --- what is dropped -----------------------------------------------------------------------


def test_random_bytes_are_dropped_as_malformed():
    v = verifier()
    rng = np.random.default_rng(1)
    for size in (0, 1, 20, 83, 84, 85, 500, 1400):
        dropped(v.check(rng.bytes(size)), "malformed")
    assert v.counters["malformed"] == 8
    assert v.counters["accepted"] == 0


def test_every_truncation_is_dropped_as_malformed():
    data = Signer(3, SEEDS[3]).seal(msg())
    v = verifier()
    for cut in range(len(data)):
        dropped(v.check(data[:cut]), "malformed")
    assert v.counters["malformed"] == len(data)


def test_an_oversized_datagram_is_dropped_before_parsing():
    v = verifier()
    dropped(v.check(b"SR" + bytes(wire.MAX_DATAGRAM)), "oversized")
    assert v.counters["oversized"] == 1


def test_another_version_is_dropped_and_counted_apart():
    data = bytearray(Signer(3, SEEDS[3]).seal(msg()))
    data[2] = 2
    v = verifier()
    dropped(v.check(bytes(data)), "wrong_version")


def test_a_sender_without_a_public_key_is_dropped():
    v = verifier()
    dropped(v.check(Signer(6, OUTSIDER).seal(msg(frm=6))), "unknown_sender")
    assert v.counters["unknown_sender"] == 1


def test_a_forged_signature_is_dropped():
    data = bytearray(Signer(3, SEEDS[3]).seal(msg()))
    data[-1] ^= 0x01
    v = verifier()
    dropped(v.check(bytes(data)), "bad_signature")


@pytest.mark.parametrize("where", ["header", "payload"])
def test_a_changed_byte_under_the_signature_is_dropped(where):
    data = bytearray(Signer(3, SEEDS[3]).seal(msg()))
    data[8 if where == "header" else 40] ^= 0x01  # the sequence number, or the term
    dropped(verifier().check(bytes(data)), "bad_signature")


def test_a_drone_cannot_sign_for_another_drone():
    """A compromised drone 3 claims to be drone 5 in the header: its own key does not verify
    as drone 5's."""
    forged = Signer(5, SEEDS[3]).seal(msg(frm=5))
    v = verifier()
    dropped(v.check(forged), "bad_signature")
    assert v.counters["accepted"] == 0


def test_a_drone_cannot_put_another_drones_raft_message_in_its_own_datagram():
    v = verifier(own_id=1)
    dropped(v.check(Signer(3, SEEDS[3]).seal(msg(frm=5))), "sender_mismatch")


def test_a_drone_cannot_forward_another_drones_report_in_its_own_datagram():
    v = verifier()
    dropped(v.check(Signer(3, SEEDS[3]).seal(report(drone=4))), "sender_mismatch")


def test_a_raft_message_for_another_node_is_dropped():
    v = verifier(own_id=2)
    dropped(v.check(Signer(3, SEEDS[3]).seal(msg(to=1))), "wrong_recipient")


def test_a_malformed_payload_under_a_valid_signature_is_dropped():
    s = Signer(3, SEEDS[3])
    v = verifier()
    dropped(v.check(s.seal_payload(wire.Kind.RAFT, b"\x02garbage")), "malformed")
    dropped(v.check(s.seal_payload(wire.Kind.REPORT, b"\x00" * 40)), "malformed")


# --- replays -------------------------------------------------------------------------------


def test_a_valid_datagram_replayed_is_dropped():
    data = Signer(3, SEEDS[3]).seal(msg())
    v = verifier()
    assert isinstance(v.check(data), Accepted)
    for _ in range(3):
        dropped(v.check(data), "replayed")
    assert v.counters["replayed"] == 3
    assert v.counters["accepted"] == 1


def sealed_at(seq: int, sender: int = 3) -> bytes:
    return Signer(sender, SEEDS[sender], first_seq=seq).seal(msg(frm=sender))


def test_a_sequence_far_behind_the_window_is_dropped():
    v = verifier()
    assert isinstance(v.check(sealed_at(5000)), Accepted)
    dropped(v.check(sealed_at(1)), "too_old")
    assert v.counters["too_old"] == 1


def test_late_datagrams_within_the_window_are_accepted_once():
    v = verifier()
    for seq in (10, 7, 9, 8):
        assert isinstance(v.check(sealed_at(seq)), Accepted), seq
    for seq in (7, 8, 9, 10):
        dropped(v.check(sealed_at(seq)), "replayed")


def test_window_edges():
    v = verifier(window=1024)
    assert isinstance(v.check(sealed_at(2000)), Accepted)
    assert isinstance(v.check(sealed_at(2000 - 1023)), Accepted)  # the oldest the window holds
    dropped(v.check(sealed_at(2000 - 1023)), "replayed")
    dropped(v.check(sealed_at(2000 - 1024)), "too_old")  # just out of it
    assert isinstance(v.check(sealed_at(2001)), Accepted)
    dropped(v.check(sealed_at(2000 - 1023)), "too_old")  # slid out


def test_a_jump_of_more_than_the_window_forgets_everything_before():
    v = verifier(window=64)
    for seq in (1, 2, 3):
        v.check(sealed_at(seq))
    assert isinstance(v.check(sealed_at(3 + 64)), Accepted)
    dropped(v.check(sealed_at(3)), "too_old")
    assert isinstance(v.check(sealed_at(4)), Accepted)  # top - 63: still inside, never seen
    dropped(v.check(sealed_at(3 + 64)), "replayed")


def test_a_datagram_with_a_bad_signature_does_not_move_the_window():
    forged = bytearray(sealed_at(10**6))
    forged[-1] ^= 0x01
    v = verifier()
    dropped(v.check(bytes(forged)), "bad_signature")
    assert isinstance(v.check(sealed_at(1)), Accepted)


def test_a_replayed_datagram_costs_no_signature_check():
    data = sealed_at(7)
    v = verifier()
    v.check(data)
    forged = bytearray(data)
    forged[-1] ^= 0x01  # a bad signature, but the sequence number was seen already
    dropped(v.check(bytes(forged)), "replayed")


@pytest.mark.parametrize("width", [1, 64, 1024])
def test_replay_window_matches_a_set_of_everything_seen(width):
    rng = np.random.default_rng(width)
    w = ReplayWindow(width)
    seen: set[int] = set()
    for seq in rng.integers(0, 3 * width + 10, size=2000):
        seq = int(seq)
        top = max(seen, default=None)
        expect = "replayed" if seq in seen else None
        if top is not None and seq <= top - width:
            expect = "too_old"
        assert w.check(seq) == expect, (seq, top)
        if expect is None:
            w.mark(seq)
            seen.add(seq)


# --- never raises, logs within limits ------------------------------------------------------


@given(st.binary(max_size=300))
@settings(max_examples=500)
def test_no_bytes_make_the_verifier_raise_or_accept(data):
    v = verifier()
    assert isinstance(v.check(data), Dropped)
    assert v.counters["internal_error"] == 0


@given(st.data())
@settings(max_examples=300)
def test_no_change_to_a_valid_datagram_is_accepted(data):
    good = Signer(3, SEEDS[3], first_seq=data.draw(st.integers(1, 2**64 - 1))).seal(msg())
    b = bytearray(good)
    i = data.draw(st.integers(0, len(b) - 1))
    b[i] ^= data.draw(st.integers(1, 255))
    v = verifier()
    assert isinstance(v.check(bytes(b)), Dropped)
    assert v.counters["internal_error"] == 0


def test_every_drop_reason_is_counted_from_zero():
    v = verifier()
    assert all(v.counters[r] == 0 for r in Verifier.REASONS)
    assert "accepted" in v.counters


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_rate_limited_log_writes_k_lines_per_reason_per_second_and_counts_the_rest(caplog):
    clock = FakeClock()
    log = RateLimitedLog(logging.getLogger("test.ratelimit"), per_second=3, clock=clock)
    with caplog.at_level(logging.INFO, logger="test.ratelimit"):
        for i in range(10):
            log.warning("bad_signature", f"drop {i}")
        log.warning("replayed", "other reason")
        assert [r.getMessage() for r in caplog.records] == ["drop 0", "drop 1", "drop 2", "other reason"]
        assert log.suppressed["bad_signature"] == 7
        clock.t += 1.0
        caplog.clear()
        log.warning("bad_signature", "drop 10")
    assert [r.getMessage() for r in caplog.records] == [
        "bad_signature: 7 more lines suppressed",
        "drop 10",
    ]


def test_a_flood_of_bad_datagrams_logs_a_bounded_number_of_lines(caplog):
    clock = FakeClock()
    v = verifier(log=RateLimitedLog(logging.getLogger("test.flood"), per_second=5, clock=clock))
    with caplog.at_level(logging.DEBUG, logger="test.flood"):
        for _ in range(1000):
            v.check(b"junk")
    assert len(caplog.records) == 5
    assert v.counters["malformed"] == 1000


def test_a_report_acknowledgement_is_accepted_only_by_the_drone_it_names():
    ack = wire.ReportAck(step=41, to=2)
    got = verifier(own_id=2).check(Signer(1, SEEDS[1]).seal(ack))
    assert got == Accepted(sender=1, seq=1, kind=wire.Kind.REPORT_ACK, message=ack)
    dropped(verifier(own_id=3).check(Signer(1, SEEDS[1]).seal(ack)), "wrong_recipient")
