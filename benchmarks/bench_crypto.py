"""Benchmark of Ed25519 signing and verification for the networked runtime's datagrams.

Prints, per library and message size (200 bytes: a Raft heartbeat or vote; 1,400 bytes: a
report or an append that fills one Ethernet-sized datagram), the per-operation time in
microseconds, best and median of several runs, against the target:

  verify <= 150 us per datagram. At n = 33 drones and 10 Hz steps the leader receives about
  4 (n - 1) = 128 datagrams per 100 ms step (a report, an append response and two heartbeat
  responses from each follower), about 1,300 a second; at 150 us each that is 19 ms of every
  100 ms, under a fifth of one core, which leaves the rest for verification of the step.
  Signing is done once per datagram sent, about as many, so sign <= 150 us as well.

Then the whole path of one datagram with the library chosen: `Signer.seal` (encode, frame,
sign) and `Verifier.check` (parse, replay window, verify, decode, sender checks), for a
heartbeat and an append of one 1,400-byte entry, against the same 150 us.

Libraries: PyNaCl (libsodium, the dependency) and `cryptography` (OpenSSL underneath), measured
only if it is importable (``.venv/bin/pip install cryptography``).

Decision (five runs on the shared 2-core machine while another job kept both cores busy,
numbers in docs/net.md): `cryptography`'s verify run medians are 136-192 us, over the target in
8 of 10; PyNaCl's 73-114 us, never over, and it signs about as fast or faster. So PyNaCl
signs both the datagrams (`swarmraft.net.auth`) and the reports (`protocol.signing`), and
`cryptography` is no longer a dependency. Both are RFC 8032 Ed25519 (deterministic: the same
32-byte seed and message give the same signature bytes in either library).

Run: .venv/bin/python benchmarks/bench_crypto.py [--ops 2000] [--runs 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

from nacl.signing import SigningKey

from swarmraft.net.auth import Signer, Verifier, public_key
from swarmraft.raft.types import Entry, Message, MsgType
from timing import per_op_us

TARGET_US = 150.0
SIZES = (200, 1400)


def cryptography_ops(msg: bytes) -> tuple[Callable[[], object], Callable[[], object]] | None:
    try:
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    except ImportError:
        return None
    key = Ed25519PrivateKey.from_private_bytes(os.urandom(32))
    pub = key.public_key()
    sig = key.sign(msg)
    return (lambda: key.sign(msg)), (lambda: pub.verify(sig, msg))


def pynacl_ops(msg: bytes) -> tuple[Callable[[], object], Callable[[], object]]:
    key = SigningKey(os.urandom(32))
    pub = key.verify_key
    sig = key.sign(msg).signature
    return (lambda: key.sign(msg)), (lambda: pub.verify(msg, sig))


def datagram_path_us(msg: Message, ops: int, runs: int) -> tuple[float, float, float, float]:
    """Best and median of `Signer.seal` and of `Verifier.check` on fresh datagrams, in us."""
    seed = os.urandom(32)
    signer = Signer(msg.frm, seed)
    seal = per_op_us(lambda: signer.seal(msg), ops, runs)
    check_times = []
    for _ in range(runs):
        datagrams = [signer.seal(msg) for _ in range(ops)]
        verifier = Verifier({msg.frm: public_key(seed)}, own_id=msg.to)
        t0 = time.perf_counter()
        for d in datagrams:
            verifier.check(d)
        check_times.append((time.perf_counter() - t0) / ops * 1e6)
        assert verifier.counters["accepted"] == ops
    return (*seal, min(check_times), statistics.median(check_times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ops", type=int, default=2000, help="operations per run")
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()

    print(f"Ed25519, per operation in us: best / median of {args.runs} runs of {args.ops} ops")
    print(f"target: sign and verify <= {TARGET_US:.0f} us")
    head = f"{'library':<14}{'bytes':>7}{'sign best':>11}{'median':>9}{'verify best':>13}{'median':>9}"
    print(head + "  target")
    for name, make in (("pynacl", pynacl_ops), ("cryptography", cryptography_ops)):
        for size in SIZES:
            ops = make(os.urandom(size))
            if ops is None:
                print(f"{name:<14}{size:>7}  not installed")
                break
            sign, verify = ops
            s_best, s_med = per_op_us(sign, args.ops, args.runs)
            v_best, v_med = per_op_us(verify, args.ops, args.runs)
            ok = "met" if max(s_best, v_best) <= TARGET_US else "MISSED"
            print(f"{name:<14}{size:>7}{s_best:>11.1f}{s_med:>9.1f}{v_best:>13.1f}{v_med:>9.1f}  {ok}")

    print("\nswarmraft.net, one datagram: Signer.seal and Verifier.check, per datagram in us")
    print(f"{'message':<17}{'bytes':>7}{'seal best':>11}{'median':>9}{'check best':>12}{'median':>9}  target")
    heartbeat = Message(MsgType.HEARTBEAT, 1, 2, 7, commit=40)
    append = Message(MsgType.APP, 1, 2, 7, 7, 40, (Entry(7, 41, os.urandom(1400)),), 40)
    for label, msg in (("heartbeat", heartbeat), ("append 1x1400 B", append)):
        size = len(Signer(1, bytes(32)).seal(msg))
        s_best, s_med, c_best, c_med = datagram_path_us(msg, args.ops, args.runs)
        ok = "met" if max(s_best, c_best) <= TARGET_US else "MISSED"
        print(f"{label:<17}{size:>7}{s_best:>11.1f}{s_med:>9.1f}{c_best:>12.1f}{c_med:>9.1f}  {ok}")


if __name__ == "__main__":
    main()
