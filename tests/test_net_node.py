"""Real drone processes (`swarmraft node`) on 127.0.0.1: they elect a leader, commit steps and
end with identical records; a SIGKILLed leader is replaced within about a second and steps go
on; the old leader restarted on its SQLite file rejoins with its log and catches up; hostile
datagrams are dropped and counted while the drones keep stepping; SIGTERM stops a drone
cleanly. Every wait is bounded; each test takes well under a minute on a busy 2-core machine
(the processes need several seconds to start there, so the scenarios are long and each test
ends them with SIGTERM once it has seen what it checks)."""

import asyncio
import logging
import os
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from swarmraft.net.auth import Signer
from swarmraft.net.keys import load_private_key
from swarmraft.net.launch import NodeProcess, current_leader, events, gather_steps, prepare_swarm, read_jsonl
from swarmraft.net.node import DroneHost
from swarmraft.net.swarmfile import load_swarm
from swarmraft.protocol import Keyring, Report
from swarmraft.raft import Message, MsgType

STARTUP_S = 40.0  # the longest a swarm may take to elect its first leader and commit
SCENARIO = """
name = "net-test"
seed = 5
drones = {n}
duration_s = {duration}

[protocol]
detector = "joint"
"""


class Swarm:
    """n drones on loopback, processes for ``running`` of them; every process is ended on exit."""

    def __init__(self, tmp_path, n: int, duration_s: float, running=None):
        scenario = tmp_path / "scenario-src.toml"
        scenario.write_text(SCENARIO.format(n=n, duration=duration_s))
        self.path, self.swarm = prepare_swarm(tmp_path / "run", scenario, n, time.time() + 1.0)
        self.nodes_dir = tmp_path / "run" / "nodes"
        self.n, self.duration_s = n, duration_s
        self.procs = {
            i: NodeProcess(i, self.path, self.nodes_dir / f"drone-{i}.log")
            for i in (running or range(1, n + 1))
        }

    def __enter__(self):
        for p in self.procs.values():
            p.start()
        return self

    def __exit__(self, *exc):
        for p in self.procs.values():
            p.kill()

    def alive(self):
        return [i for i, p in self.procs.items() if p.alive]

    def steps(self, i):
        """Drone i's step rows by step."""
        return {r["step"]: r for r in read_jsonl(self.nodes_dir / f"drone-{i}.steps.jsonl")}

    def last_committed(self, i):
        return max((k for k, r in self.steps(i).items() if r["committed"]), default=-1)

    def wait(self, predicate, timeout_s, what):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if predicate():
                return
            for i, p in self.procs.items():
                if p.proc is not None and p.proc.poll() not in (None, -signal.SIGKILL):
                    log = (self.nodes_dir / f"drone-{i}.log").read_text()[-2000:]
                    pytest.fail(f"drone {i} exited with {p.proc.returncode} while waiting for {what}:\n{log}")
            time.sleep(0.05)
        pytest.fail(f"timed out after {timeout_s} s waiting for {what}")

    def steps_go_on(self, drones, more, timeout_s, what):
        """Wait until every one of ``drones`` committed ``more`` steps past the furthest now."""
        now = max(self.last_committed(i) for i in drones)
        self.wait(lambda: min(self.last_committed(i) for i in drones) >= now + more, timeout_s, what)

    def stop_all(self, timeout_s=15.0):
        """SIGTERM every process; their exit statuses."""
        for p in self.procs.values():
            p.terminate()
        return {i: p.wait(timeout_s) for i, p in self.procs.items()}


def assert_identical_records(swarm: Swarm, drones):
    """Every step each of ``drones`` applied has the same record (hash) on all of them."""
    per = {i: swarm.steps(i) for i in drones}
    common = set.intersection(*(set(s) for s in per.values()))
    assert common
    for k in common:
        assert len({per[i][k].get("record") for i in drones}) == 1, f"step {k} differs"
    return per


def test_five_drone_processes_commit_identical_records_and_survive_the_leader_killed(tmp_path):
    with Swarm(tmp_path, n=5, duration_s=40) as swarm:
        swarm.wait(
            lambda: sum(swarm.last_committed(i) >= 0 for i in range(1, 6)) == 5, STARTUP_S, "steps on all 5"
        )
        first = max(swarm.last_committed(i) for i in range(1, 6))
        swarm.wait(
            lambda: min(swarm.last_committed(i) for i in range(1, 6)) >= first + 10, 10, "10 more steps"
        )
        lead = current_leader(swarm.nodes_dir, swarm.alive())
        assert lead is not None
        old, old_term = lead
        killed_at = time.time()
        swarm.procs[old].kill()
        step_at_kill = swarm.last_committed(old)
        others = [i for i in range(1, 6) if i != old]

        # a new leader within about a second, and steps go on
        def new_leader():
            return current_leader(swarm.nodes_dir, others)

        swarm.wait(lambda: new_leader() is not None and new_leader()[1] > old_term, 5, "a new leader")
        elected = min(
            e["t"]
            for i in others
            for e in events(swarm.nodes_dir, i)
            if e["event"] == "role" and e["role"] == "leader" and e["term"] > old_term
        )
        assert elected - killed_at <= 1.0, f"new leader after {elected - killed_at:.2f} s"
        swarm.wait(
            lambda: min(swarm.last_committed(i) for i in others) >= step_at_kill + 15,
            10,
            "steps after the crash",
        )

        # the old leader restarts on its SQLite file with its log intact, and catches up
        db = sqlite3.connect(swarm.nodes_dir / f"drone-{old}.sqlite")
        (entries_before,) = db.execute("SELECT COUNT(*) FROM entries").fetchone()
        (commit_before,) = db.execute("SELECT commit_index FROM hard_state").fetchone()
        db.close()
        assert entries_before > 10
        swarm.procs[old].start()
        swarm.wait(
            lambda: len([e for e in events(swarm.nodes_dir, old) if e["event"] == "start"]) == 2,
            20,
            "restart",
        )
        restart = [e for e in events(swarm.nodes_dir, old) if e["event"] == "start"][-1]
        assert restart["last_index"] == entries_before and restart["commit"] == commit_before
        target = max(swarm.last_committed(i) for i in others) + 10
        swarm.wait(lambda: swarm.last_committed(old) >= target, 20, "the restarted drone to catch up")
        statuses = swarm.stop_all()

    assert all(s == 0 for s in statuses.values()), statuses
    per = assert_identical_records(swarm, range(1, 6))
    # the restarted drone holds the steps of the time it was down too, from the log
    down = [k for k in range(step_at_kill + 1, step_at_kill + 15) if per[others[0]][k]["committed"]]
    assert down and all(per[old][k]["committed"] for k in down)
    for i in range(1, 6):
        stop = [e for e in events(swarm.nodes_dir, i) if e["event"] == "stop"][-1]
        assert stop["reason"] == "SIGTERM"
        assert stop["counters"].get("replayed_record_differs", 0) == 0
        assert stop["counters"].get("internal_error", 0) == 0
        assert stop["verifier"].get("internal_error", 0) == 0
        # the restarted drone's sequence numbers went on above its first run's: nothing refused
        assert stop["verifier"].get("too_old", 0) == 0 and stop["verifier"].get("replayed", 0) == 0
        # the audit (on by default) refused nothing of honest leaders, found no censorship,
        # also on the restarted drone that re-checked its log at apply (docs/audit.md)
        audit = stop["audit"]
        assert audit["refused_entries"] == audit["refused_applies"] == audit["censorship_findings"] == 0
        found = [e for e in events(swarm.nodes_dir, i) if e["event"].startswith(("audit", "censorship"))]
        assert not found, found[:3]
        # the restarted drone re-checked its log at apply in its audit thread (not on its loop)
        assert (stop["counters"].get("audited_at_apply", 0) > 10) == (i == old), (i, stop["counters"])
    g = gather_steps(swarm.nodes_dir, 5, 400, 0.1)
    assert g.all_identical and g.committed > 30


def test_hostile_datagrams_are_dropped_and_counted_while_drones_keep_stepping(tmp_path):
    # 4 drones in the swarm, 3 processes; the test speaks as drone 4 (it holds its key)
    with Swarm(tmp_path, n=4, duration_s=40, running=[1, 2, 3]) as swarm:
        swarm.wait(lambda: min(swarm.last_committed(i) for i in (1, 2, 3)) >= 0, STARTUP_S, "steps on all 3")
        seed4 = load_private_key(swarm.swarm.drones[4].key)
        signer = Signer(4, seed4, first_seq=time.time_ns() // 1000)
        rng = np.random.default_rng(0)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for i in (1, 2, 3):
                addr = swarm.swarm.drones[i].advertise_address
                stale = signer.seal(Message(MsgType.HEARTBEAT_RESP, frm=4, to=i, term=0))
                sock.sendto(stale, addr)
                sock.sendto(stale, addr)  # replayed
                forged = bytearray(signer.seal(Message(MsgType.HEARTBEAT_RESP, frm=4, to=i, term=0)))
                forged[-1] ^= 0xFF
                sock.sendto(bytes(forged), addr)  # bad signature
                keys = Keyring.generate(4, rng)
                other = keys.sign(Report(0, 0, np.zeros(3), "gnss", np.zeros(4), None))
                sock.sendto(signer.seal(other), addr)  # drone 4 speaking for drone 1
                sock.sendto(rng.bytes(61_000), addr)  # oversized
                for _ in range(50):
                    sock.sendto(rng.bytes(int(rng.integers(0, 300))), addr)  # garbage
                sock.sendto(b"SR" + bytes(200), addr)  # our magic, nonsense after it
        finally:
            sock.close()
        swarm.steps_go_on((1, 2, 3), 10, 10, "steps after the attack")
        statuses = swarm.stop_all()
    assert statuses == {1: 0, 2: 0, 3: 0}
    assert_identical_records(swarm, (1, 2, 3))
    for i in (1, 2, 3):
        stop = [e for e in events(swarm.nodes_dir, i) if e["event"] == "stop"][-1]
        v = stop["verifier"]
        assert v.get("replayed", 0) >= 1 and v.get("bad_signature", 0) >= 1
        assert v.get("sender_mismatch", 0) >= 1 and v.get("oversized", 0) >= 1
        assert v.get("malformed", 0) >= 50
        assert v.get("internal_error", 0) == 0 and stop["counters"].get("internal_error", 0) == 0
        # the sockets and files are closed: the port can be bound again
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(swarm.swarm.drones[i].bind_address)
        s.close()


def test_no_message_leaves_before_the_state_it_depends_on_is_persisted(tmp_path, monkeypatch):
    """Three drone hosts in this process (of a 4-drone swarm): every Raft message, when it is
    handed to the transport, finds what it depends on already in the sender's SQLite storage:
    its term, the vote it grants, the entries it acknowledges or sends. Each host pins BLAS
    to one thread as it starts (`blas.pin_one_blas_thread`: its verify and audit threads
    cannot set it themselves); spied, so this process's BLAS is left as it was."""
    import swarmraft.net.node as node_module

    pinned = []
    monkeypatch.setattr(node_module, "pin_one_blas_thread", lambda: pinned.append(1))
    scenario = tmp_path / "scenario-src.toml"
    scenario.write_text(SCENARIO.format(n=4, duration=4))
    path, _ = prepare_swarm(tmp_path / "run", scenario, 4, time.time() + 0.5)
    hosts = [DroneHost(load_swarm(path), i) for i in (1, 2, 3)]
    checked, violations = Counter(), []

    def guarded(host, send):
        def send_raft(m):
            hs, last = host.storage.initial_state(), host.storage.last_index()
            needs_term = m.type not in (MsgType.PRE_VOTE, MsgType.PRE_VOTE_RESP, MsgType.PROP)
            if needs_term and hs.term < m.term:
                violations.append(f"{m.type} of term {m.term} sent with term {hs.term} on disk")
            if m.type == MsgType.VOTE_RESP and not m.reject and hs.vote != m.to:
                violations.append(f"vote for {m.to} sent with vote {hs.vote} on disk")
            if m.type == MsgType.APP_RESP and not m.reject and last < m.index:
                violations.append(f"MsgAppResp for index {m.index} sent with {last} entries on disk")
            if m.type == MsgType.APP and m.entries and last < m.entries[-1].index:
                violations.append(f"MsgApp up to {m.entries[-1].index} sent with {last} entries on disk")
            checked[m.type] += 1
            send(m)

        return send_raft

    for h in hosts:
        h._send_raft = guarded(h, h._send_raft)

    async def main():
        await asyncio.wait_for(asyncio.gather(*(h.run() for h in hosts)), 30)

    asyncio.run(main())
    assert len(pinned) == len(hosts)
    assert not violations, violations[:5]
    assert checked[MsgType.VOTE_RESP] and checked[MsgType.APP_RESP] and checked[MsgType.APP] > 20
    assert all(h.drone.state.records for h in hosts)


def run_cli(*args, timeout=30):
    return subprocess.run(
        [sys.executable, "-m", "swarmraft", *args], capture_output=True, text=True, timeout=timeout
    )


def test_a_node_that_cannot_bind_or_is_misconfigured_exits_with_one_line(tmp_path):
    scenario = tmp_path / "scenario-src.toml"
    # long enough not to have ended by the last check (a node refuses an ended scenario)
    scenario.write_text(SCENARIO.format(n=4, duration=600))
    path, swarm = prepare_swarm(tmp_path / "run", scenario, 4, time.time())
    taken = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    taken.bind(swarm.drones[1].bind_address)
    try:
        done = run_cli("node", "--id", "1", "--swarm", str(path))
    finally:
        taken.close()
    host, port = swarm.drones[1].bind_address
    assert done.returncode == 2
    assert done.stderr.strip() == f"error: cannot bind UDP {host}:{port}: Address already in use"
    done = run_cli("node", "--id", "9", "--swarm", str(path))
    assert done.returncode == 2
    assert done.stderr.strip() == "error: --id: no drone 9 in the swarm file (ids 1..4)"
    (tmp_path / "run" / "keys" / "drone-2.key").chmod(0o644)
    done = run_cli("node", "--id", "2", "--swarm", str(path))
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
    assert "chmod 600" in done.stderr
    # a damaged Raft database, and an out that is a file: one line each, not a traceback
    db = Path(swarm.out) / "drone-3.sqlite"
    db.parent.mkdir(parents=True, exist_ok=True)
    db.write_bytes(b"not a database at all" * 100)
    done = run_cli("node", "--id", "3", "--swarm", str(path), timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == f"error: {db}: not a drone's Raft database (file is not a database)"
    text = path.read_text()
    (tmp_path / "afile").write_text("x")
    path.write_text(re.sub(r'(?m)^out = ".*"$', f'out = "{tmp_path / "afile"}"', text))
    assert str(tmp_path / "afile") in path.read_text()
    done = run_cli("node", "--id", "4", "--swarm", str(path), timeout=60)
    assert done.returncode == 2, done.stderr
    said = f"error: out: {tmp_path / 'afile'} is a file, not a folder (the swarm file's out)"
    assert done.stderr.strip() == said
    path.write_text(re.sub(r'(?m)^out = ".*"$', 'out = "/proc/nope"', text))
    done = run_cli("node", "--id", "4", "--swarm", str(path), timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().startswith("error: out: cannot create /proc/nope (")
    assert done.stderr.strip().endswith("the swarm file's out)")


def test_a_node_with_no_step_to_fly_says_so_in_one_line(tmp_path):
    """A start time whose scenario has ended exited 0 in silence; a step of 1 ms, shorter
    than the Raft tick, sent reports for 12 s and applied nothing. (A step shorter than the
    leader's 60 ms wait for reports is not refused: 20 Hz works.)"""
    scenario = tmp_path / "scenario-src.toml"
    scenario.write_text(SCENARIO.format(n=4, duration=4))
    path, _ = prepare_swarm(tmp_path / "old", scenario, 4, time.time() - 100)
    done = run_cli("node", "--id", "1", "--swarm", str(path), timeout=60)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "start_unix_s: step 0 was at" in done.stderr and "nothing left to fly" in done.stderr
    from swarmraft.net.node import step_too_short

    assert step_too_short(0.05, 10.0) is None  # 20 Hz on the 10 ms tick
    path, _ = prepare_swarm(tmp_path / "fast", scenario, 4, time.time() + 60)
    path.write_text(re.sub(r"(?m)^start_unix_s", "step_s = 0.001\nstart_unix_s", path.read_text()))
    done = run_cli("node", "--id", "1", "--swarm", str(path), timeout=60)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "step_s: a step of 1 ms is shorter than the Raft tick (10 ms): give at least 0.01 s" in done.stderr
    # a start time in milliseconds: the node waits, and says how long
    path, _ = prepare_swarm(tmp_path / "ms", scenario, 4, time.time() * 1000)
    cmd = [sys.executable, "-m", "swarmraft", "node", "--id", "1", "--swarm", str(path)]
    node = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = node.stderr.readline()  # blocks until the node says something
    finally:
        node.terminate()
        node.communicate(timeout=30)
    assert "drone 1: step 0 is" in line and "days from now" in line and "not milliseconds" in line


@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_or_sigterm_stops_launch_and_every_drone_process(tmp_path, sig, status):
    """Ctrl-C, or a SIGTERM to launch alone (`kill`, `timeout`, a CI runner): every drone is
    stopped and the results are written; before SIGTERM was handled the drones outlived it."""
    scenario = tmp_path / "long.toml"
    scenario.write_text(SCENARIO.format(n=4, duration=60))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "swarmraft", "launch", "--scenario", str(scenario), "--out", str(out)]
    launch = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        nodes = out / "nodes"
        end = time.monotonic() + STARTUP_S
        while time.monotonic() < end and not all(
            any(r["committed"] for r in read_jsonl(nodes / f"drone-{i}.steps.jsonl")) for i in range(1, 5)
        ):
            time.sleep(0.1)
        launch.send_signal(sig)
        stdout, stderr = launch.communicate(timeout=30)
    finally:
        launch.kill()
    assert launch.returncode == status, stdout + stderr
    assert f"interrupted ({sig.name})" in stderr and "steps committed" in stdout
    # summarised over the steps it reached, not the 601 of the scenario (those after the
    # interrupt were counted as skipped)
    reached = (out / "records.csv").read_text().count("\n") - 1
    assert 0 < reached < 601
    assert f"of {reached} steps committed" in " ".join(stdout.split())
    for i in range(1, 5):
        pid = [e for e in events(nodes, i) if e["event"] == "start"][-1]["pid"]
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
        assert [e for e in events(nodes, i) if e["event"] == "stop"][-1]["reason"] == "SIGTERM"
    assert (out / "steps.csv").exists()


def test_launch_refuses_bad_input_with_one_line(tmp_path):
    done = run_cli("launch", "--scenario", "no-such-scenario", "--out", str(tmp_path / "a"))
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
    assert "--scenario: no file no-such-scenario and no shipped scenario" in done.stderr
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "swarm.toml").write_text("")
    done = run_cli("launch", "--scenario", "demo", "--out", str(tmp_path / "b"))
    assert done.returncode == 2
    assert done.stderr.strip().startswith(f"error: --out: {tmp_path / 'b'} holds a swarm already")
    # an earlier run's keys or drone files without its swarm.toml: new drones would reopen its
    # SQLite logs and report its records as theirs (and keys/ ended in a traceback)
    for part in ("keys", "nodes"):
        (tmp_path / part / part).mkdir(parents=True)
        done = run_cli("launch", "--scenario", "demo", "--out", str(tmp_path / part))
        assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert f"holds a swarm already ({part})" in done.stderr
    for bad in ("inf", "nan"):
        done = run_cli("launch", "--scenario", "demo", "--out", str(tmp_path / "c"), "--start-delay", bad)
        assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert "--start-delay" in done.stderr and "finite" in done.stderr
    assert not (tmp_path / "c").exists()  # nothing written


def test_a_drone_warms_up_its_detector_on_a_flagged_step_as_well():
    # the first step with a flagged drone loads the rival search and the re-inclusion (20 ms
    # more than the next such step): a drone process pays that before its first step, not
    # inside it at a spoof's onset
    from swarmraft.net.node import warm_up_detector
    from swarmraft.sim.scenario import Scenario
    from swarmraft.sim.sensing import ScenarioWorld

    records = warm_up_detector(ScenarioWorld.build(Scenario(drones=9, duration_s=1, seed=3)))
    assert [r.step for r in records] == [0, 1]
    assert not records[0].faulty.any()
    assert records[1].faulty[4]  # the report moved by 40 m


def test_a_report_read_after_its_half_deadline_is_not_held_for_the_censorship_check(tmp_path):
    """A voter holds a fanned-out report for the censorship check only while its step's half
    deadline has not passed by the clock, whether or not its `_retry` timer has fired yet (a
    loaded process's timers fire late): nine processes on 2 loaded cores found their honest
    leader censoring reports that reached the voters late. A report of a step still to come is
    held."""
    from nacl.signing import SigningKey

    from swarmraft.protocol import SwarmDrone

    scenario = tmp_path / "scenario-src.toml"
    scenario.write_text(SCENARIO.format(n=4, duration=600))
    # step 0 began 10 s ago: the half deadlines of steps 0 to 99 have passed, not step 500's
    path, swarm = prepare_swarm(tmp_path / "run", scenario, 4, time.time() - 10.0)
    host = DroneHost(load_swarm(path), 1)
    sender = SwarmDrone(
        1,
        host.world.protocol,
        Keyring({1: SigningKey(load_private_key(swarm.drones[2].key))}, host.drone.keys.public),
    )

    def report(step: int) -> Report:
        return sender.make_report(step, np.zeros(3), "gnss", np.full(4, 20.0), None)

    late, due = report(50), report(500)
    assert not host._note_for_censorship(late)
    assert 1 not in host.drone.audit.timely.get(50, set())
    assert host._note_for_censorship(due)
    assert host.drone.audit.timely[500] == {1}


WARM_CHECK = """
import numba
from swarmraft.estimation import joint, gnc
from swarmraft.net.node import warm_up_detector
from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario
from swarmraft.sim.sensing import ScenarioWorld

import tomllib
from swarmraft.sim.scenario import find_scenario
data = tomllib.loads(find_scenario("leader-crash-under-attack").read_text())
data.update(duration_s=13, fault=[], protocol={"detector": "paper"})  # the spoofs from 10 s
sc = Scenario(**data)
kernels = [joint.levenberg_marquardt_kernel, gnc._gnc_kernel]
warm_up_detector(ScenarioWorld.build(sc))
before = [set(map(str, k.signatures)) for k in kernels]
log = run_mission(sc)
new = [sorted(set(map(str, k.signatures)) - b) for k, b in zip(kernels, before)]
print("flagged", int(log.faulty.sum()), "new", sum(map(len, new)))
"""


def test_warm_up_loads_what_a_paper_mission_step_compiles():
    """A node's warm-up loads every compiled kernel its steps use, whatever the detector: under
    `paper` a record's re-estimate with a decided trusted set (a spoofed drone gated) loaded
    Levenberg-Marquardt's kernel in the first such step, and on a cold cache compiled it: 43 s
    inside a step, the swarm stalled behind one drone. A fresh process, so that nothing
    loaded by other tests hides it."""
    r = subprocess.run([sys.executable, "-c", WARM_CHECK], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    flagged, new = (int(w) for w in r.stdout.split()[1::2])
    assert flagged > 0, r.stdout  # drones were gated: the path ran
    assert new == 0, r.stdout


class _JumpingClock:
    """The time module, but its wall clock (``time()``) jumps ``by`` s forward once the real
    one passes ``at``: what a machine paused while its wall clock ran on (a busy virtual
    machine), or a stepped clock, looks like to a drone."""

    def __init__(self, at: float, by: float) -> None:
        self.at, self.by = at, by

    def time(self) -> float:
        now = time.time()
        return now + (self.by if now > self.at else 0.0)

    def __getattr__(self, name):  # noqa: ANN001, ANN204
        return getattr(time, name)


def test_a_wall_clock_jump_reschedules_the_steps(tmp_path, monkeypatch):
    """Three drone hosts in this process (of a 4-drone swarm, 8 s); 2 s into it the wall
    clock jumps 2 s forward. The drones schedule their steps again from the wall clock and go
    on committing; before, every later step's timer fired at a moment the wall clock called
    over, and nothing more was committed (a 30 s launch committed nothing after 9 s)."""
    import swarmraft.net.node as node_module

    scenario = tmp_path / "scenario-src.toml"
    scenario.write_text(SCENARIO.format(n=4, duration=8))
    start = time.time() + 1.0
    path, _ = prepare_swarm(tmp_path / "run", scenario, 4, start)
    hosts = [DroneHost(load_swarm(path), i) for i in (1, 2, 3)]
    monkeypatch.setattr(node_module, "time", _JumpingClock(start + 2.0, 2.0))

    async def main():
        await asyncio.wait_for(asyncio.gather(*(h.run() for h in hosts)), 40)

    asyncio.run(main())
    applied = [int(k) for h in hosts for k, rec in h._written.items() if rec]
    assert max(applied) >= 60, max(applied)  # the steps after the jump (2 s = 20 steps skipped)
    assert sum(k > 45 for k in applied) >= 20
    assert all(h.counters["clock_resyncs"] >= 1 for h in hosts)


def test_a_role_change_is_logged_for_node_v(caplog):
    """`node -v` logs role changes (its help says so); they went to the event file only."""
    from types import SimpleNamespace

    from swarmraft.net.node import DroneHost

    seen = []
    host = SimpleNamespace(
        id=3,
        node=SimpleNamespace(role="leader", term=4, lead=3),
        _role=("follower", 3),
        _event=lambda kind, **fields: seen.append((kind, fields)),
    )
    with caplog.at_level(logging.INFO, logger="swarmraft.net.node"):
        DroneHost._note_role(host)
        DroneHost._note_role(host)  # no change: nothing more
    assert seen == [("role", {"role": "leader", "term": 4, "leader": 3})]
    assert [r.getMessage() for r in caplog.records] == ["drone 3 is leader in term 4, leader 3"]


def test_launch_stopped_before_step_0_writes_no_results(tmp_path):
    """A launch interrupted while its drones wait for step 0 flew nothing: it says so and
    writes no summary (it summarised a skipped step 0)."""
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO.format(n=4, duration=20))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "swarmraft", "launch", "--scenario", str(scenario), "--out", str(out)]
    launch = subprocess.Popen(
        [*cmd, "--start-delay", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        end = time.monotonic() + 60
        while time.monotonic() < end and not (out / "swarm.toml").exists():
            time.sleep(0.1)
        time.sleep(1.0)
        launch.send_signal(signal.SIGTERM)
        stdout, stderr = launch.communicate(timeout=60)
    finally:
        launch.kill()
    assert launch.returncode == 143, stdout + stderr
    said = " ".join(stderr.split())  # wrapped to the terminal's width
    assert "interrupted (SIGTERM) before step 0: nothing flown, no results written (" in said
    assert "holds the swarm's keys and files: give another --out to launch again)" in said
    assert not (out / "summary.json").exists() and not (out / "steps.csv").exists()


def test_a_node_refuses_a_swarm_file_written_for_other_code(tmp_path):
    """Every drone must run the same code: a voter re-runs its leader's verification, and
    another version's honest records would be refused as lies, the swarm electing leader
    after leader with every refusal blaming one. `launch` writes the code it runs into the
    swarm file; a node with other code refuses to start, in one line; without the line,
    nothing is checked (hand-written files)."""
    from swarmraft.net.node import NodeConfigError
    from swarmraft.provenance import source_sha256

    scenario = tmp_path / "scenario-src.toml"
    scenario.write_text(SCENARIO.format(n=4, duration=4))
    path, swarm = prepare_swarm(tmp_path / "run", scenario, 4, time.time() + 60)
    assert swarm.code_sha256 == source_sha256()
    DroneHost(load_swarm(path), 1)  # this code: accepted
    text = path.read_text()
    path.write_text(text.replace(source_sha256(), "0" * 64))
    with pytest.raises(NodeConfigError, match="names swarmraft code 000000000000, this program is"):
        DroneHost(load_swarm(path), 1)
    path.write_text(re.sub(r"(?m)^code_sha256 = .*\n", "", text))
    assert load_swarm(path).code_sha256 is None
    DroneHost(load_swarm(path), 1)


def test_the_warm_up_runs_on_a_scenario_of_exact_data():
    """`launch --scenario paper-recovery-6-2` (exact GNSS and ranges, sigma 0) stopped at
    'error: Singular matrix': the warm-up's joint estimate inverted a zero covariance (found
    by a new-user review)."""
    from swarmraft.experiments.mission import load_scenario
    from swarmraft.net.node import warm_up_detector
    from swarmraft.sim.scenario import find_scenario
    from swarmraft.sim.sensing import ScenarioWorld

    sc = load_scenario(find_scenario("paper-recovery-6-2"))
    assert sc.gnss.sigma_h == 0
    records = warm_up_detector(ScenarioWorld.build(sc))
    assert len(records) == 2
