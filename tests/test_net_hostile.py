"""Hostile datagrams at running drones (issue 10's acceptance): 10,000 of every kind
(`swarmraft.net.hostile`: random bytes, truncated, oversized, forged signatures, a valid
datagram replayed, another sender claimed) at a running drone are all dropped, each under the
reason it must get, none accepted; no drone crashes (exit 0 on SIGTERM), the records stay
identical and the steps go on. The step rate under the flood is measured by
benchmarks/bench_hostile.py, not here (no timing in tests)."""

import os
import socket
import time
from collections import Counter

import numpy as np

from swarmraft.net.auth import Verifier, public_key
from swarmraft.net.hostile import KINDS, HostileFlood, PacedSender, udp_socket_queue
from swarmraft.net.keys import load_private_key
from swarmraft.net.launch import current_leader, events
from test_net_node import STARTUP_S, Swarm, assert_identical_records

FLOOD = 10_000


def test_a_flood_labels_every_kind_with_the_reason_a_verifier_drops_it_for():
    seeds = {i: os.urandom(32) for i in range(1, 5)}
    verifier = Verifier({i: public_key(s) for i, s in seeds.items()}, own_id=1)
    flood = HostileFlood(600, np.random.default_rng(3), attacker=4, seed=seeds[4], target=1, n=4)
    assert verifier.check(flood.primer).sender == 4  # accepted: the replays have something to replay
    got, labels = Counter(), Counter()
    for h in flood:
        got[getattr(verifier.check(h.data), "reason", "accepted")] += 1
        labels[h.reason] += 1
    assert got == labels and "accepted" not in got
    assert Counter(flood.kinds) == dict.fromkeys(KINDS, 100)
    assert set(labels) == {
        "malformed",
        "oversized",
        "bad_signature",
        "replayed",
        "sender_mismatch",
        "unknown_sender",
    }


def test_ten_thousand_hostile_datagrams_at_the_leader_are_all_dropped_and_the_swarm_steps_on(tmp_path):
    # 4 drones in the swarm, 3 processes; the attacker holds drone 4's key (a compromised drone)
    with Swarm(tmp_path, n=4, duration_s=120, running=[1, 2, 3]) as swarm:
        swarm.wait(lambda: min(swarm.last_committed(i) for i in (1, 2, 3)) >= 0, STARTUP_S, "steps on all 3")
        lead = current_leader(swarm.nodes_dir, [1, 2, 3])
        target = lead[0] if lead else 1
        addr = swarm.swarm.drones[target].advertise_address
        flood = HostileFlood(
            FLOOD,
            np.random.default_rng(10),
            attacker=4,
            seed=load_private_key(swarm.swarm.drones[4].key),
            target=target,
            n=4,
            first_seq=time.time_ns() // 1000,
        )
        kernel_before = udp_socket_queue(addr[1], addr[0])
        assert kernel_before is not None, "no /proc/net/udp entry for the target's socket"
        sent, flood_bytes = Counter(), len(flood.primer)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        paced = PacedSender(sock, addr)
        try:
            paced.send(flood.primer)
            for h in flood:
                paced.send(h.data)
                sent[h.reason] += 1
                flood_bytes += len(h.data)
            swarm.wait(lambda: udp_socket_queue(addr[1], addr[0])[0] == 0, 10, "the target to read the flood")
        finally:
            sock.close()
        kernel_after = udp_socket_queue(addr[1], addr[0])
        swarm.steps_go_on((1, 2, 3), 10, 20, "steps after the flood")
        statuses = swarm.stop_all()

    assert statuses == {1: 0, 2: 0, 3: 0}  # no crash: each stopped cleanly on SIGTERM
    assert sum(sent.values()) == FLOOD
    assert kernel_after[1] == kernel_before[1], "the kernel dropped datagrams: the counts cannot add up"
    assert_identical_records(swarm, (1, 2, 3))
    for i in (1, 2, 3):
        stop = [e for e in events(swarm.nodes_dir, i) if e["event"] == "stop"][-1]
        dropped = {r: n for r, n in stop["verifier"].items() if r != "accepted"}
        if i == target:
            # every one dropped under its own reason and nothing else dropped: none accepted
            assert dropped == dict(sent)
            received = stop["transport"]["bytes_received"] - stop["at_step_0"]["transport"]["bytes_received"]
            assert received >= flood_bytes
        else:
            assert dropped == {}
        assert stop["counters"].get("internal_error", 0) == 0
        assert stop["cpu_s"] > stop["at_step_0"]["cpu_s"] > 0
