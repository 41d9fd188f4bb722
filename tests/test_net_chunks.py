"""A Raft message larger than one datagram (a MsgSnap carrying a large drone state) travels in
signed pieces (`wire.Chunk`) and is put together by the receiver's Verifier: whole, in any
order, once; a missing, forged or stale piece never yields a message; memory stays bounded."""

import random

import pytest

from raftnet import make_node
from swarmraft.net import wire
from swarmraft.net.auth import Accepted, Dropped, Partial, Signer, Verifier, public_key
from swarmraft.net.chunks import Reassembler
from swarmraft.raft import Role
from swarmraft.raft.types import Message, MsgType, Snapshot

SEEDS = {i: bytes([i]) * 32 for i in range(1, 4)}
PUBLIC = {i: public_key(s) for i, s in SEEDS.items()}


def snap_msg(size: int, frm: int = 1, to: int = 2, seed: int = 0) -> Message:
    data = random.Random(seed).randbytes(size)
    return Message(MsgType.SNAP, frm, to, 3, snapshot=Snapshot(1200, 3, data, (1, 2, 3), (4,)))


def test_a_small_message_is_one_ordinary_datagram():
    m = Message(MsgType.SNAP, 1, 2, 3, snapshot=Snapshot(10, 3, b"small", (1, 2, 3)))
    (only,) = Signer(1, SEEDS[1]).seal_all(m)
    assert wire.parse(only).kind == wire.Kind.RAFT
    assert Verifier(PUBLIC, own_id=2).check(only).message == m


@pytest.mark.parametrize("size", [wire.MAX_PAYLOAD, 3 * wire.CHUNK_DATA, 200_000])
def test_a_large_snapshot_arrives_whole_in_any_order(size):
    m = snap_msg(size)
    datagrams = Signer(1, SEEDS[1]).seal_all(m)
    assert len(datagrams) == -(-len(wire.encode_message(m, limit=wire.MAX_MESSAGE)) // wire.CHUNK_DATA) >= 2
    assert all(len(d) <= wire.MAX_DATAGRAM and wire.parse(d).kind == wire.Kind.CHUNK for d in datagrams)
    random.Random(size).shuffle(datagrams)
    v = Verifier(PUBLIC, own_id=2)
    got = [v.check(d) for d in datagrams]
    assert all(isinstance(g, Partial) for g in got[:-1])
    assert isinstance(got[-1], Accepted) and got[-1].kind == wire.Kind.RAFT
    assert got[-1].message == m
    assert v.counters["pieces"] == len(datagrams) - 1 and v.counters["accepted"] == 1
    assert v.pieces.held_bytes() == 0


def test_a_missing_piece_yields_nothing_and_a_duplicate_is_a_replay():
    datagrams = Signer(1, SEEDS[1]).seal_all(snap_msg(150_000))
    v = Verifier(PUBLIC, own_id=2)
    for d in datagrams[:-1]:
        assert isinstance(v.check(d), Partial)
    assert isinstance(v.check(datagrams[0]), Dropped)  # replayed
    assert v.counters["accepted"] == 0


def test_a_forged_piece_is_dropped_and_the_message_never_assembles():
    datagrams = Signer(1, SEEDS[1]).seal_all(snap_msg(150_000))
    bad = bytearray(datagrams[1])
    bad[wire.HEADER_SIZE + 40] ^= 1
    v = Verifier(PUBLIC, own_id=2)
    results = [v.check(datagrams[0]), v.check(bytes(bad)), *(v.check(d) for d in datagrams[2:])]
    assert isinstance(results[1], Dropped) and results[1].reason == "bad_signature"
    assert not any(isinstance(r, Accepted) for r in results)


def test_a_message_in_pieces_for_another_drone_is_dropped_when_whole():
    v = Verifier(PUBLIC, own_id=3)
    results = [v.check(d) for d in Signer(1, SEEDS[1]).seal_all(snap_msg(150_000, to=2))]
    assert isinstance(results[-1], Dropped) and results[-1].reason == "wrong_recipient"


def test_pieces_of_a_newer_message_replace_an_unfinished_older_one():
    signer = Signer(1, SEEDS[1])
    old, new = snap_msg(150_000, seed=1), snap_msg(150_000, seed=2)
    first, second = signer.seal_all(old), signer.seal_all(new)
    v = Verifier(PUBLIC, own_id=2)
    v.check(first[0])
    for d in second[:-1]:
        v.check(d)
    assert v.pieces.held_bytes() == sum(len(wire.parse(d).payload) - 16 for d in second[:-1])
    for d in first[1:]:  # the rest of the older message: ignored, never completes
        assert isinstance(v.check(d), Partial)
    assert v.check(second[-1]).message == new


def test_the_reassembler_holds_at_most_one_message_per_sender():
    r = Reassembler()
    for message in range(1, 50):
        for i in range(3):
            r.add(7, wire.Chunk(message, i, 4, 3 * wire.CHUNK_DATA + 5, bytes(wire.CHUNK_DATA)))
    assert r.held_bytes() == 3 * wire.CHUNK_DATA


def test_a_piece_disagreeing_with_its_message_is_ignored():
    r = Reassembler()
    length = 2 * wire.CHUNK_DATA + 1
    assert r.add(1, wire.Chunk(5, 0, 3, length, bytes(wire.CHUNK_DATA))) is None
    assert r.add(1, wire.Chunk(5, 1, 4, 3 * wire.CHUNK_DATA + 1, bytes(wire.CHUNK_DATA))) is None
    assert r.add(1, wire.Chunk(5, 2, 3, length, b"x")) is None
    assert r.add(1, wire.Chunk(5, 1, 3, length, bytes(wire.CHUNK_DATA))) == bytes(2 * wire.CHUNK_DATA) + b"x"


L3 = 2 * wire.CHUNK_DATA + 1  # a message in 3 pieces


@pytest.mark.parametrize(
    "chunk, reason",
    [
        (wire.Chunk(1, 0, 1, wire.MAX_PAYLOAD, bytes(wire.MAX_PAYLOAD - 16)), "bad_value"),  # fits one
        (wire.Chunk(1, 3, 3, L3, b"x"), "bad_value"),  # piece beyond the count
        (wire.Chunk(1, 0, 4, L3, bytes(wire.CHUNK_DATA)), "bad_value"),  # wrong count
        (wire.Chunk(1, 2, 3, L3, b"xy"), "length_mismatch"),  # last piece too long
        (wire.Chunk(1, 0, 3, L3, b"x"), "length_mismatch"),  # a short middle piece
        (wire.Chunk(1, 0, 300, wire.MAX_MESSAGE + 1, b""), "bad_value"),  # past the message limit
    ],
)
def test_a_piece_that_contradicts_its_own_header_is_refused(chunk, reason):
    payload = wire.encode_chunk(chunk)
    with pytest.raises(wire.WireError) as exc:
        wire.decode_chunk(payload)
    assert exc.value.reason == reason


def test_a_message_past_the_limit_is_not_sent():
    with pytest.raises(wire.WireError, match="oversized"):
        Signer(1, SEEDS[1]).seal_all(snap_msg(wire.MAX_MESSAGE))


def test_a_follower_catches_up_by_a_large_snapshot_sent_in_pieces_over_a_lossy_link():
    """Three Raft cores joined by the runtime's own datagram path (`Signer.seal_all`, then
    loss and reordering, then `Verifier.check`, as `net.node` sends and receives): a follower
    cut off while the leader compacts its log catches up by installing a 150 KB snapshot
    that travels in 3 pieces (sent again while pieces are lost), at 20 % loss per datagram."""
    rng = random.Random(5)
    ids = (1, 2, 3)
    nodes = {i: make_node(i, ids, seed=i) for i in ids}
    signers = {i: Signer(i, SEEDS[i]) for i in ids}
    verifiers = {i: Verifier(PUBLIC, own_id=i) for i in ids}
    applied: dict[int, list[bytes]] = {i: [] for i in ids}
    state = {i: b"" for i in ids}  # the state machine: the last entry applied, 150 KB of it
    cut = {3}
    in_flight: list[tuple[int, bytes]] = []
    pieces_sent = 0

    def handle(i: int) -> None:
        nonlocal pieces_sent
        node = nodes[i]
        while (rd := node.ready()) is not None:
            node.log.storage.save(rd.hard_state, rd.entries, rd.snapshot)
            for m in rd.messages:
                datagrams = signers[i].seal_all(m)
                assert len(datagrams) == 1 or m.type == MsgType.SNAP
                pieces_sent += len(datagrams) > 1
                in_flight.extend((m.to, d) for d in datagrams if m.to not in cut and i not in cut)
            if rd.snapshot is not None:
                state[i] = rd.snapshot.data
                applied[i] = [b"snapshot"]
            for e in rd.committed:
                if e.data:
                    state[i] = e.data * 18_750  # 150 KB
                    applied[i].append(e.data)
            node.advance(rd)

    def run(ticks: int) -> None:
        for _ in range(ticks):
            for i in ids:
                nodes[i].tick()
                handle(i)
            rng.shuffle(in_flight)
            batch, in_flight[:] = list(in_flight), []
            for to, d in batch:
                if rng.random() < 0.2:
                    continue
                got = verifiers[to].check(d)
                if isinstance(got, Accepted):
                    nodes[to].step(got.message)
                    handle(to)

    run(60)
    lead = next(i for i in ids if nodes[i].role == Role.LEADER)
    assert lead != 3  # cut off from the start
    for k in range(6):
        while nodes[lead].propose(b"%08d" % k) is None:
            run(5)
        run(20)
    storage = nodes[lead].log.storage
    top = nodes[lead].status.applied
    storage.create_snapshot(top, state[lead], compact_to=top, conf=nodes[lead].conf_state_at(top))
    cut.clear()
    run(300)
    assert pieces_sent > 0
    assert nodes[3].log.storage.snapshot().index == top
    assert state[3] == state[lead] == b"%08d" % 5 * 18_750
    assert sum(v.counters["pieces"] for v in verifiers.values()) > 0
