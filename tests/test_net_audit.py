"""The audit in the networked runtime (docs/audit.md): five drone hosts in this process over
real UDP on 127.0.0.1. While the leader is honest no record is refused; once it is told to
lie (`DroneHost.compromise`, what SIGUSR1 does: the scenario's lying-leader fault), the honest
drones refuse its records, never apply one, and another drone leads. Every wait is bounded
and generous (the machine may be loaded); the test stops the hosts once it has seen what it
checks."""

import asyncio
import time

from swarmraft.net.launch import events, prepare_swarm, read_jsonl
from swarmraft.net.node import DroneHost
from swarmraft.net.results import audit_summary
from swarmraft.net.swarmfile import drone_file, load_swarm
from swarmraft.raft import Role

SCENARIO = """
name = "net-audit"
seed = 3
drones = 5
duration_s = 300

[protocol]
detector = "paper"

[[fault]]
kind = "lying-leader"
at_s = 10  # not read here: the test tells the leader when to lie
mode = "{mode}"
drone = 2
"""
N = 5
HONEST_RECORDS = 20  # committed on every drone before the leader is told to lie
AFTER_RECORDS = 10  # committed by honest leaders on every honest drone after the lie
PHASE_S = 120.0  # the longest each phase may take


def committed(host: DroneHost) -> int:
    return sum(1 for rec in host._written.values() if rec)


def leader(hosts: list[DroneHost]) -> DroneHost | None:
    leads = [h for h in hosts if hasattr(h, "node") and h.node.role == Role.LEADER]
    return max(leads, key=lambda h: h.node.term, default=None)


async def until(predicate, what: str) -> None:
    end = time.monotonic() + PHASE_S
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f"not within {PHASE_S:g} s: {what}")
        await asyncio.sleep(0.05)


def swarm_of_hosts(tmp_path, mode: str, watch):
    """Five hosts of SCENARIO (lying ``mode``), run until ``await watch(hosts, seen)``
    returns, then stopped; the hosts, what ``watch`` put in ``seen``, and the swarm file."""
    scenario = tmp_path / "scenario-src.toml"
    scenario.write_text(SCENARIO.format(mode=mode))
    path, swarm = prepare_swarm(tmp_path / "run", scenario, N, time.time() + 3.0)
    hosts = [DroneHost(load_swarm(path), i) for i in range(1, N + 1)]
    seen: dict = {}

    async def main():
        runs = [asyncio.create_task(h.run()) for h in hosts]
        try:
            await watch(hosts, seen)
        finally:
            for h in hosts:
                if hasattr(h, "_stopped"):
                    h.stop("test over")
            await asyncio.wait_for(asyncio.gather(*runs, return_exceptions=True), 60)

    asyncio.run(main())
    return hosts, seen, swarm


def run_swarm(tmp_path, mode: str, after_lie):
    """Five hosts; once every one committed HONEST_RECORDS, their audit counts are taken and
    the leader is told to lie; ``after_lie(hosts, liar, term)`` says when to stop."""

    async def watch(hosts, seen):
        await until(
            lambda: all(hasattr(h, "node") and committed(h) >= HONEST_RECORDS for h in hosts),
            "honest records",
        )
        seen["honest"] = [h.audit_counts() for h in hosts]
        await until(lambda: leader(hosts) is not None, "a leader")
        liar = leader(hosts)
        seen["liar"], seen["term"] = liar.id, liar.node.term
        liar.compromise()
        await until(lambda: after_lie(hosts, liar, seen["term"]), "the liar replaced")

    return swarm_of_hosts(tmp_path, mode, watch)


def replaced(hosts, liar, term, mode="move") -> bool:
    """The liar lied (``move``: proposed a falsified record; ``censor``: an honest drone found
    it out), another drone leads in a later term, and every honest drone committed
    AFTER_RECORDS records of later terms."""
    honest = [h for h in hosts if h is not liar]
    lied = (
        liar.counters["falsified_proposed"] > 0
        if mode == "move"
        else any(h.counters["censorship_findings"] > 0 for h in honest)
    )
    return (
        lied
        and any(h.node.role == Role.LEADER and h.node.term > term for h in honest)
        and all(
            sum(r["term"] > term for r in read_jsonl(h.steps_path) if r["committed"]) >= AFTER_RECORDS
            for h in honest
        )
    )


def test_a_lying_leader_is_refused_by_every_honest_drone_and_replaced(tmp_path):
    hosts, seen, swarm = run_swarm(tmp_path, "move", replaced)
    # the honest swarm: nothing refused, no censorship found, in HONEST_RECORDS steps and more
    for counts in seen["honest"]:
        assert counts["refused_entries"] == counts["refused_applies"] == 0, counts
        assert counts["censorship_findings"] == 0, counts
    liar = seen["liar"]
    nodes = tmp_path / "run" / "nodes"
    proposed = [e["record"] for e in events(nodes, liar) if e["event"] == "falsified"]
    lies = set(proposed)
    assert lies
    for h in hosts:
        if h.id != liar:
            applied = {
                r["record"] for r in read_jsonl(drone_file(nodes, h.id, "steps.jsonl")) if r["committed"]
            }
            assert not applied & lies, f"drone {h.id} applied a falsified record"
    # the honest drones refused the lie (its positions are not the re-run's) at append
    refusals = [
        e for h in hosts if h.id != liar for e in events(nodes, h.id) if e["event"] == "audit_refused"
    ]
    assert refusals and all(e["reason"] == "positions differ from the re-run" for e in refusals)
    summary = audit_summary(nodes, N, swarm.start_unix_s)
    assert summary["liar"] == liar and summary["falsified_applied"] == 0
    assert summary["falsified_proposed"] == len(proposed) and summary["refused_entries"] == len(refusals)
    # replaced: another drone led after the first lie (in the simulator within 0.3 s; a loaded
    # machine's elections take longer)
    assert summary["other_leader_s"] is not None
    assert summary["other_leader_s"] - summary["first_lie_s"] < 10.0, summary


def test_a_censoring_leader_is_found_and_replaced(tmp_path):
    hosts, seen, swarm = run_swarm(
        tmp_path, "censor", lambda h, liar, term: replaced(h, liar, term, "censor")
    )
    summary = audit_summary(tmp_path / "run" / "nodes", N, swarm.start_unix_s)
    assert summary["liar"] == seen["liar"] and summary["falsified_proposed"] == 0
    # every honest voter held drone 2's reports (the fan-out) and saw them left out
    assert summary["censorship_findings"] > 0 and summary["refused_entries"] == 0, summary
    assert summary["other_leader_s"] is not None, summary


def test_a_leader_keeps_its_quorum_while_its_voters_audit_slowly(tmp_path, monkeypatch):
    """Every record's re-run made to take 0.3 s (twice the 150 ms election timeout): the
    voters audit beside their Raft nodes (`DroneHost._preaudit`) and answer their leader's
    heartbeats meanwhile, so the first leader keeps its term while records commit. When the
    node waited for its audit (the append stepped in the audit thread), nine voters' 276-308
    ms audits of a searched step on 2 cores cost their leader its quorum (docs/audit.md); this
    swarm's term then rose with every record."""
    from swarmraft.protocol.audit import Auditor

    real = Auditor._evidence_uncached

    def slow(self, rec, body):
        time.sleep(0.3)
        return real(self, rec, body)

    monkeypatch.setattr(Auditor, "_evidence_uncached", slow)

    async def watch(hosts, seen):
        await until(lambda: leader(hosts) is not None and committed(leader(hosts)) >= 1, "a record")
        seen["first"] = leader(hosts).node.term
        await until(lambda: all(hasattr(h, "node") and committed(h) >= 8 for h in hosts), "8 records")
        seen["terms"] = [h.node.term for h in hosts]
        seen["audits"] = [h.counters["audit_count"] for h in hosts]

    _, seen, _ = swarm_of_hosts(tmp_path, "move", watch)
    assert seen["terms"] == [seen["first"]] * N, seen
    assert sum(a > 0 for a in seen["audits"]) >= N - 1  # the voters did audit, slowly


def test_appends_the_node_drops_unread_are_not_audited(tmp_path):
    """A liar sends its next records while its first lie is audited; once deposed, its held
    appends (and a stale term's) are stepped unaudited, the node dropping them
    (`RaftNode.ignores`): each audit is a full re-run, and on a loaded machine those of a
    liar's queued records delayed the next leader's appends behind them."""
    import random

    from swarmraft.raft import Entry, EntryKind, MemoryStorage, Message, MsgType, RaftConfig, RaftNode

    scenario = tmp_path / "scenario-src.toml"
    scenario.write_text(SCENARIO.format(mode="move"))
    path, _ = prepare_swarm(tmp_path / "run", scenario, N, time.time() + 60)
    host = DroneHost(load_swarm(path), 3)
    host.node = RaftNode(RaftConfig(3, (1, 2, 4, 5)), MemoryStorage(), random.Random(0))
    host.node.step(Message(MsgType.HEARTBEAT, 2, 3, 1))
    host.node.advance(host.node.ready())
    host.node.depose(2)  # its lie was refused
    stepped, audited = [], []
    host._push = stepped.append

    class Loop:  # records what is sent to the audit thread; the audit never finishes here
        def run_in_executor(self, pool, fn, *args):  # noqa: ANN001, ANN202
            audited.append(args)
            return type("Pending", (), {"add_done_callback": lambda self, cb: None})()

    host._loop = Loop()
    host._audit_pool = None  # the loop above is asked to run the audit, never a pool
    record = Entry(1, 1, b"a record not checked yet", EntryKind.NORMAL)
    from_liar = Message(MsgType.APP, 2, 3, 1, log_term=0, index=0, entries=(record,), commit=0)
    host._held_apps.append(from_liar)
    host._preaudit()
    assert len(stepped) == 1 and not audited and not host._held_apps
    from_next = Message(MsgType.APP, 4, 3, 2, log_term=0, index=0, entries=(record,), commit=0)
    host._held_apps.append(from_next)
    host._preaudit()
    assert len(audited) == 1 and len(stepped) == 1  # the next leader's append: audited first
