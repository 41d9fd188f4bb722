"""`swarmraft status`: the request and the signed answer (`net.status`, wire kinds 3 and 4),
a drone's answers rate-limited, forged or stale answers refused, and the command against real
drone processes on 127.0.0.1 (4 drones): every drone answers with its role, term and indexes, the leader
with its followers' progress, and a killed drone shows as not answering (exit status 1)."""

import json
import os
import re
import socket
import subprocess
import sys
import time

import numpy as np
from nacl.signing import SigningKey

from swarmraft.net import wire
from swarmraft.net.auth import Signer
from swarmraft.net.launch import events
from swarmraft.net.status import REPLIES_PER_S, ReplyLimit, check_reply, encode_reply
from swarmraft.raft import Message, MsgType
from test_net_node import STARTUP_S, Swarm


def test_a_status_request_is_recognised_and_nothing_else_is():
    req = wire.status_request(2**63 - 5)
    assert len(req) == wire.HEADER_SIZE + wire.SIGNATURE_SIZE
    assert wire.status_request_nonce(req) == 2**63 - 5
    signer = Signer(1, bytes(32))
    raft = signer.seal(Message(MsgType.HEARTBEAT, frm=1, to=2, term=1))
    rng = np.random.default_rng(3)
    for other in (raft, req + b"x", req[:-1], b"", rng.bytes(84), req[:3] + b"\x04" + req[4:]):
        assert wire.status_request_nonce(other) is None
    # a request that reaches the Verifier anyway is dropped (sender 0 has no key)
    bad = bytearray(req)
    bad[4] = 1  # claims sender 1: not a request any more; unsigned
    assert wire.status_request_nonce(bytes(bad)) is None


def test_only_a_fresh_answer_signed_by_that_drone_is_taken():
    seed = bytes(range(32))
    key = SigningKey(seed).verify_key
    signer = Signer(3, seed)
    good = signer.seal_payload(wire.Kind.STATUS_REPLY, encode_reply({"nonce": 77, "role": "leader"}))
    assert check_reply(good, 77, key, 3) == {"nonce": 77, "role": "leader"}
    assert check_reply(good, 78, key, 3) == "an answer to another request"
    assert check_reply(good, 77, key, 2) == "answered as drone 3"
    other = SigningKey(bytes(32)).verify_key
    assert check_reply(good, 77, other, 3) == "bad signature"
    forged = bytearray(good)
    forged[wire.HEADER_SIZE + 3] ^= 1
    assert check_reply(bytes(forged), 77, key, 3) == "bad signature"
    not_json = signer.seal_payload(wire.Kind.STATUS_REPLY, b"\xff{")
    assert check_reply(not_json, 77, key, 3) == "an answer that is not JSON"
    raft = signer.seal(Message(MsgType.HEARTBEAT, frm=3, to=1, term=1))
    assert check_reply(raft, 77, key, 3) == "a datagram of kind 1, not a status answer"
    assert check_reply(b"junk", 77, key, 3).startswith("malformed answer")


def test_a_drone_answers_at_most_so_many_requests_a_second():
    now = [100.0]
    limit = ReplyLimit(lambda: now[0])
    assert sum(limit.allow() for _ in range(50)) == REPLIES_PER_S
    now[0] += 0.5
    assert not limit.allow()
    now[0] += 0.6
    assert sum(limit.allow() for _ in range(50)) == REPLIES_PER_S


def status_cli(path, *extra):
    return subprocess.run(
        [sys.executable, "-m", "swarmraft", "status", "--swarm", str(path), "--timeout", "3", *extra],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "120"},
    )


def test_status_of_a_running_swarm_and_of_a_killed_drone(tmp_path):
    with Swarm(tmp_path, n=4, duration_s=40) as swarm:
        swarm.wait(lambda: min(map(swarm.last_committed, (1, 2, 3, 4))) >= 5, STARTUP_S, "steps on all 4")
        done = status_cli(swarm.path, "--json")
        assert done.returncode == 0, done.stdout + done.stderr
        answers = json.loads(done.stdout)
        assert set(answers) == {"1", "2", "3", "4"}
        leaders = [a for a in answers.values() if a["role"] == "leader"]
        assert len(leaders) == 1
        (lead,) = leaders
        assert {a["term"] for a in answers.values()} == {lead["term"]}
        assert all(a["leader"] == lead["drone"] and a["quorum"] for a in answers.values())
        assert all(a["commit"] > 5 and a["last_step"] >= 5 for a in answers.values())
        # the audit is on (the default) and has refused nothing
        assert all(a["audit"]["refused_entries"] == 0 and not a["audit"]["lying"] for a in answers.values())
        assert {p for p in lead["peers"]} == {str(i) for i in (1, 2, 3, 4) if i != lead["drone"]}
        assert all(p["match"] > 0 and p["state"] in ("probe", "replicate") for p in lead["peers"].values())

        # a flood of requests: answered at most REPLIES_PER_S a second
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.settimeout(0.5)
        try:
            for k in range(60):
                sock.sendto(wire.status_request(k), swarm.swarm.drones[lead["drone"]].advertise_address)
            answered = 0
            while True:
                try:
                    sock.recvfrom(65535)
                except TimeoutError:
                    break
                answered += 1
        finally:
            sock.close()
        assert 1 <= answered <= 2 * REPLIES_PER_S

        # the wrong keys file: every drone answers, no answer is taken, and the last line says
        # so (it said "4 of 4 drones did not answer")
        from swarmraft.net.keys import write_keys

        write_keys(swarm.path.parent / "other-keys", 4)
        wrong = swarm.path.parent / "wrong-keys.toml"  # beside swarm.toml: its paths still hold
        text = swarm.path.read_text()
        assert 'public_keys = "keys/swarm-keys.toml"' in text
        wrong.write_text(text.replace('"keys/swarm-keys.toml"', '"other-keys/swarm-keys.toml"'))
        done = status_cli(wrong)
        out = " ".join(done.stdout.split())
        assert done.returncode == 1, out
        assert "bad signature" in out and "did not answer" not in out, out
        assert "4 of 4 drones answered with an answer not taken" in out, out

        follower = next(i for i in (1, 2, 3, 4) if i != lead["drone"])
        swarm.procs[follower].kill()
        time.sleep(0.5)
        done = status_cli(swarm.path)
        out = done.stdout
        assert done.returncode == 1, out
        assert f"1 of 4 drones did not answer: {follower}" in out, out
        # the killed drone's row, and the followers of whichever drone leads now (on a loaded
        # machine the leader of the first question may have been deposed since)
        assert "no answer" in out and re.search(r"Leader \d+'s followers", out), out
        swarm.stop_all()
    stop = [e for e in events(swarm.nodes_dir, lead["drone"]) if e["event"] == "stop"][-1]
    assert stop["counters"]["status_answered"] >= 1 and stop["counters"]["status_refused"] >= 1


def test_status_refuses_a_bad_swarm_file_with_one_line(tmp_path):
    done = status_cli(tmp_path / "nope.toml")
    assert done.returncode == 2
    assert (
        done.stderr.strip()
        == f"error: --swarm: {tmp_path / 'nope.toml'}: no such file (see `python -m swarmraft status --help`)"
    )
    bad = tmp_path / "swarm.toml"
    bad.write_text("version = 1\n")
    done = status_cli(bad)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
    assert done.stderr.startswith(f"error: --swarm: {bad}")


def test_status_refuses_a_keys_file_without_every_drone(tmp_path):
    """As a node does: a swarm-keys file missing a drone (status only said 'no answer')."""
    import time as _time

    from swarmraft.net.launch import prepare_swarm

    scenario = tmp_path / "s.toml"
    scenario.write_text('name = "s"\ndrones = 4\nduration_s = 2\n')
    path, swarm = prepare_swarm(tmp_path / "run", scenario, 4, _time.time())
    keys = swarm.public_keys
    keys.write_text("\n".join(ln for ln in keys.read_text().splitlines() if not ln.startswith("4 ")) + "\n")
    done = status_cli(path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"{keys}: no public key for drone 4" in " ".join(done.stderr.split())
