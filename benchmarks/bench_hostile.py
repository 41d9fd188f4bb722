"""Benchmark of a running swarm under a flood of hostile datagrams (issue 10's acceptance: "10,000
hostile datagrams ... at a running node: zero accepted, zero crashes, its step rate unchanged
within noise").

n drones on 127.0.0.1 (n - 1 processes: the attacker holds drone n's key, a compromised drone);
after ``--warmup`` seconds of steps, ``--rounds`` rounds of: a quiet stretch, then ``--count``
hostile datagrams of every kind (`swarmraft.net.hostile`: random bytes, truncated, oversized,
forged signatures, a valid datagram replayed, another sender claimed) at ``--rate`` per second
at the leader, both stretches equally long (count / rate seconds). Per round, from the drones'
step files: committed steps per second and commit latency p50 / p99 (step start to the leader's
apply) in the quiet stretch and under the flood, and their ratios (flood / quiet; one run, so
the machine's drift between minutes cancels). At the end, from the target's stop event: how
many of the flood its Verifier dropped, under which reasons, against the labels; how many the
kernel dropped before the node saw them (its socket's receive buffer full; Linux
/proc/net/udp); how many were accepted (must be 0); every drone's exit status on SIGTERM (must
be 0) and whether the records are identical.

Targets: zero accepted, zero crashes, the step rate under the flood within noise of the quiet
one (here: a ratio >= 0.95, and no step skipped that the quiet stretch did not skip too).

Run: .venv/bin/python benchmarks/bench_hostile.py [--n 5] [--count 10000] [--rate 1000] [--rounds 3]
"""

from __future__ import annotations

import argparse
import math
import socket
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from netrun import LoopbackSwarm, machine, window_stats
from swarmraft.net.hostile import HostileFlood, PacedSender, udp_socket_queue
from swarmraft.net.keys import load_private_key
from swarmraft.net.launch import current_leader

RATE_TARGET = 0.95


def flood(swarm: LoopbackSwarm, target: int, count: int, rate: float, rng: np.random.Generator) -> tuple:
    """Send ``count`` hostile datagrams at drone ``target``: ``rate`` a second, or (rate 0) each
    once its socket has room (`PacedSender`); (labels sent, the kernel's drops at the target's
    socket meanwhile or None, start and end unix times, this sender's CPU seconds: it shares
    the machine's cores with the swarm)."""
    attacker = swarm.n
    addr = swarm.swarm.drones[target].advertise_address
    hostile = HostileFlood(
        count,
        rng,
        attacker=attacker,
        seed=load_private_key(swarm.swarm.drones[attacker].key),
        target=target,
        n=swarm.n,
        first_seq=time.time_ns() // 1000,
    )
    before = udp_socket_queue(addr[1], addr[0])
    sent: Counter[str] = Counter()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    t0, cpu0 = time.time(), time.process_time()
    paced = PacedSender(sock, addr)
    try:
        paced.send(hostile.primer)
        for i, h in enumerate(hostile):
            if rate <= 0:
                paced.send(h.data)
            else:
                if (wait := t0 + i / rate - time.time()) > 0:
                    time.sleep(wait)
                sock.sendto(h.data, addr)
            sent[h.reason] += 1
    finally:
        sock.close()
    t1, cpu = time.time(), time.process_time() - cpu0
    time.sleep(0.2)  # let the node read what is queued
    after = udp_socket_queue(addr[1], addr[0])
    kernel = after[1] - before[1] if before and after else None
    return sent, kernel, t0, t1, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5, help="drones in the swarm (n - 1 processes)")
    ap.add_argument("--count", type=int, default=10_000, help="hostile datagrams per round")
    ap.add_argument(
        "--rate",
        type=float,
        default=0.0,
        help="hostile datagrams per second; 0: as fast as the node reads them",
    )
    ap.add_argument("--quiet", type=float, default=10.0, help="seconds of steps without the flood, per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--warmup", type=float, default=5.0, help="seconds of steps before the first round")
    ap.add_argument("--seed", type=int, default=1, help="the scenario's and the flood's seed")
    ap.add_argument("--out", type=Path, default=None, help="keep the run's files here (default: removed)")
    args = ap.parse_args()
    step_s = 0.1
    most_flood_s = args.count / args.rate if args.rate > 0 else args.count / 200  # paced: 200/s at worst
    duration_s = args.warmup + args.rounds * (args.quiet + most_flood_s + 2.0) + 3.0
    rng = np.random.default_rng(args.seed)

    print(f"hostile flood at a running swarm's leader; {machine()}")
    print(
        f"{args.n} drones, {args.n - 1} processes; {args.rounds} rounds of {args.quiet:g} s quiet, then "
        f"{args.count:,} hostile datagrams at the leader, "
        + (f"{args.rate:g}/s" if args.rate > 0 else "each once its socket has room (no kernel drops)")
    )
    print(
        f"target: none accepted, no crash, steps/s under the flood >= {RATE_TARGET:.2f} x quiet, "
        "no step skipped beyond the quiet stretch's"
    )
    print()
    print(
        f"{'round':>5}{'flood dg/s':>11}{'its CPU':>8}{'quiet/s':>9}{'flood/s':>9}{'ratio':>7}"
        f"{'p50 q':>8}{'p50 f':>8}{'p99 q':>8}{'p99 f':>8}  target"
    )
    with tempfile.TemporaryDirectory(prefix="bench-hostile-") as tmp:
        out = args.out or Path(tmp)
        running = list(range(1, args.n))
        sent, kernel_drops, targets, rows, missed = Counter(), 0, set(), [], []
        with LoopbackSwarm(out, args.n, duration_s, seed=args.seed, running=running) as swarm:
            t = swarm.step_start(round(args.warmup / step_s))
            for r in range(1, args.rounds + 1):
                swarm.sleep_until(t + args.quiet)
                quiet = (t, t + args.quiet)
                lead = current_leader(swarm.nodes_dir, running)
                target = lead[0] if lead else 1
                targets.add(target)
                s, k, f0, f1, cpu = flood(swarm, target, args.count, args.rate, rng)
                sent += s
                kernel_drops += k or 0
                rows.append((r, quiet, (f0, f1), cpu))
                t = time.time() + 1.0
                swarm.sleep_until(t)
            swarm.sleep_until(time.time() + 1.0)
            statuses = swarm.stop()

        def steps_within(a: float, b: float) -> tuple[int, int]:
            """The steps that start between unix times a and b."""
            t0 = swarm.step_start(0)
            return math.ceil((a - t0) / step_s), math.floor((b - t0) / step_s)

        for r, quiet, flooded, cpu in rows:
            q, f = window_stats(swarm, *steps_within(*quiet)), window_stats(swarm, *steps_within(*flooded))
            ratio = f.rate_per_s / q.rate_per_s if q.rate_per_s else float("nan")
            ok = ratio >= RATE_TARGET and f.skipped <= q.skipped
            print(
                f"{r:>5}{args.count / (flooded[1] - flooded[0]):>11,.0f}"
                f"{cpu / (flooded[1] - flooded[0]):>8.0%}"
                f"{q.rate_per_s:>9.2f}{f.rate_per_s:>9.2f}{ratio:>7.2f}{q.latency_ms(50):>8.1f}"
                f"{f.latency_ms(50):>8.1f}{q.latency_ms(99):>8.1f}{f.latency_ms(99):>8.1f}"
                f"  {'met' if ok else 'MISSED'}"
            )
            if not ok:
                missed.append(
                    f"round {r}: {f.rate_per_s:.2f} steps/s under the flood ({f.skipped} skipped), "
                    f"{q.rate_per_s:.2f} quiet ({q.skipped} skipped)"
                )
        print(
            "columns: hostile datagrams per second sent; the sender's CPU (s per s); committed steps/s "
            "quiet and under the flood, their ratio; commit latency p50, p99 (ms) quiet and under the flood"
        )
        total = sum(sent.values())
        dropped, other_drops = Counter(), Counter()
        for i in running:
            stop = swarm.last_event(i, "stop") or {}
            v = {r: c for r, c in stop.get("verifier", {}).items() if r != "accepted"}
            (dropped if i in targets else other_drops).update(v)
        # with no kernel drop, every hostile datagram reached the Verifier: what it did not drop, it accepted
        accepted = total - sum(dropped.values()) if kernel_drops == 0 else None
        print()
        print(f"flood: {total:,} hostile datagrams at drone(s) {sorted(targets)}; labels {dict(sent)}")
        print(f"dropped by the kernel (socket buffer full, /proc/net/udp): {kernel_drops:,}")
        print(f"dropped by the Verifier: {sum(dropped.values()):,} {dict(dropped)}")
        if accepted is not None:
            print(f"accepted: {accepted:,} (sent - Verifier drops; the kernel dropped none)")
        else:
            print(
                "accepted: not counted exactly (the kernel dropped datagrams at that socket, the flood's "
                "and the drones' own alike); the Verifier's drops per reason are within the labels: "
                + ("yes" if all(dropped[r] <= sent[r] for r in dropped) else "NO")
            )
        print(
            f"exit statuses on SIGTERM: {statuses}; drops at the other drones: {dict(other_drops) or 'none'}"
        )
        g = window_stats(swarm, 0, round(duration_s / step_s))
        print(f"records identical on every drone: {'yes' if g.identical else 'NO'}; {machine()}")
        if accepted:
            missed.append(f"{accepted} hostile datagrams accepted (target: 0)")
        if accepted is None and not all(dropped[r] <= sent[r] for r in dropped):
            missed.append("the Verifier dropped more under some reason than the flood carried")
        if any(s != 0 for s in statuses.values()):
            missed.append(f"exit statuses {statuses} (target: all 0)")
        if not g.identical:
            missed.append("records differ between drones")
        if kernel_drops == 0 and dropped != sent:
            missed.append("the Verifier's drop reasons differ from the labels")
        for line in missed:
            print("MISSED: " + line)
        if not missed:
            print("every target met")


if __name__ == "__main__":
    main()
