"""Benchmark of the Raft message encodings considered for the datagram payload: `struct` (what
`swarmraft.net.wire` uses) against msgpack (measured only if importable; it is not a
dependency of swarmraft, it arrives with the test extra's dask).

Prints, per message (a heartbeat, a vote response, an append of one 1,400-byte entry, an
append of 8 such entries), the encoded size in bytes and the time to encode and to decode
(back to a `raft.types.Message`), best and median of several runs, in microseconds, against
the target: encode + decode <= 20 us for a message without entries, a small share of the
Ed25519 verification every datagram costs anyway (about 70-160 us, bench_crypto.py).

The msgpack decoder here only rebuilds the Message; it does not check types or ranges, which
`wire.decode_message` does (and a real msgpack path would have to), so it flatters msgpack.

Decision (numbers in docs/net.md): both codecs meet the target by a factor of 3 or more and
cost a few microseconds against about 100 us of signature checking per datagram. msgpack is
about 1 us faster on small messages and writes 27-35 fewer bytes (out of 100-140 with the
84-byte header and signature), and about 2x faster on large appends without any checking;
that is no measured reason to add a dependency and a second layer of type checks, so
`swarmraft.net.wire` uses `struct`.

Run: .venv/bin/python benchmarks/bench_wire.py [--ops 20000] [--runs 7]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

from swarmraft.net import wire
from swarmraft.raft.types import Entry, EntryKind, Message, MsgType
from timing import per_op_us

TARGET_US = 20.0
_TYPES = list(MsgType)
_KINDS = list(EntryKind)


def msgpack_codec() -> tuple[Callable[[Message], bytes], Callable[[bytes], Message]] | None:
    try:
        import msgpack
    except ImportError:
        return None

    def encode(m: Message) -> bytes:
        entries = [(e.term, e.index, _KINDS.index(e.kind), e.data) for e in m.entries]
        fields = (_TYPES.index(m.type), m.frm, m.to, m.term, m.log_term, m.index, m.commit)
        return msgpack.packb((*fields, m.reject, m.reject_hint, entries))

    def decode(data: bytes) -> Message:
        t, frm, to, term, log_term, index, commit, reject, hint, entries = msgpack.unpackb(data)
        es = tuple(Entry(a, b, d, _KINDS[k]) for a, b, k, d in entries)
        return Message(_TYPES[t], frm, to, term, log_term, index, es, commit, reject, hint)

    return encode, decode


def cases() -> dict[str, Message]:
    big = 2**40  # terms and indexes of a long-lived cluster
    entry = Entry(big, big, bytes(1400))
    return {
        "heartbeat": Message(MsgType.HEARTBEAT, 1, 2, big, commit=big),
        "vote response": Message(MsgType.VOTE_RESP, 2, 1, big, reject=True),
        "append 1x1400 B": Message(MsgType.APP, 1, 2, big, big, big, (entry,), big),
        "append 8x1400 B": Message(MsgType.APP, 1, 2, big, big, big, (entry,) * 8, big),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ops", type=int, default=20000, help="operations per run")
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()

    codecs = {"struct": (wire.encode_message, wire.decode_message)}
    if (mp := msgpack_codec()) is not None:
        codecs["msgpack"] = mp
    else:
        print("msgpack: not installed")
    print(f"Raft message codecs, per operation in us: best / median of {args.runs} runs of {args.ops} ops")
    print(f"target: encode + decode <= {TARGET_US:.0f} us for a message without entries")
    print(f"{'message':<17}{'codec':<9}{'bytes':>7}{'encode':>8}{'median':>8}{'decode':>8}{'median':>8}")
    for label, msg in cases().items():
        for name, (encode, decode) in codecs.items():
            data = encode(msg)
            assert decode(data) == msg
            e_best, e_med = per_op_us(lambda m=msg, f=encode: f(m), args.ops, args.runs)
            d_best, d_med = per_op_us(lambda b=data, f=decode: f(b), args.ops, args.runs)
            note = ""
            if not msg.entries:
                note = "  met" if e_best + d_best <= TARGET_US else "  MISSED"
            times = f"{e_best:>8.2f}{e_med:>8.2f}{d_best:>8.2f}{d_med:>8.2f}"
            print(f"{label:<17}{name:<9}{len(data):>7}{times}{note}")


if __name__ == "__main__":
    main()
