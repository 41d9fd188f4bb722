"""Snapshots and log compaction: storage (memory and SQLite, SIGKILL), InstallSnapshot for a
follower behind the leader's log, restart from the snapshot and the tail, the drone's state
encoding."""

import os
import random
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from swarmraft.protocol.drone import Applied
from swarmraft.protocol.records import StepRecord
from swarmraft.raft import (
    Compacted,
    ConfChange,
    ConfChangeType,
    Entry,
    EntryKind,
    HardState,
    MemoryStorage,
    Message,
    MsgType,
    RaftConfig,
    RaftNode,
    Snapshot,
    SnapshotPolicy,
    SQLiteStorage,
    pack_entries,
    unpack_entries,
)
from swarmraft.sim import Cluster


@pytest.fixture(params=["memory", "sqlite"])
def storage(request, tmp_path):
    if request.param == "memory":
        yield MemoryStorage()
    else:
        s = SQLiteStorage(tmp_path / "raft.db")
        yield s
        s.close()


def fill(storage, n, term=1):
    storage.save(HardState(term, 1, n), [Entry(term, i, b"e%d" % i) for i in range(1, n + 1)])


def test_create_snapshot_and_compact_keep_the_tail_and_the_compaction_point_term(storage):
    fill(storage, 10)
    storage.save(None, [Entry(2, 11, b"e11")])
    snap = storage.create_snapshot(8, b"state@8", compact_to=5)
    assert snap == Snapshot(8, 1, b"state@8") == storage.snapshot()
    assert (storage.first_index(), storage.last_index()) == (6, 11)
    assert storage.term(5) == 1  # the compaction point still answers for appends after it
    with pytest.raises(Compacted):
        storage.term(4)
    with pytest.raises(Compacted):
        storage.entries(5, 7)
    assert [e.index for e in storage.entries(6, 12)] == list(range(6, 12))
    storage.compact(8)
    assert storage.first_index() == 9 and storage.term(8) == 1
    with pytest.raises(ValueError, match="older"):
        storage.create_snapshot(7, b"old")


def test_installing_a_leaders_snapshot_replaces_the_whole_log(storage):
    fill(storage, 6)
    storage.save(HardState(3, 2, 20), [], Snapshot(20, 3, b"leader"))
    assert (storage.first_index(), storage.last_index(), storage.term(20)) == (21, 20, 3)
    storage.save(None, [Entry(3, 21, b"x")])
    assert storage.entries(21, 22) == [Entry(3, 21, b"x")]
    with pytest.raises(ValueError, match="not newer"):
        storage.save(None, [], Snapshot(20, 3, b"again"))


def test_sqlite_restart_loads_the_snapshot_and_the_tail_only(tmp_path):
    s = SQLiteStorage(tmp_path / "r.db")
    fill(s, 1000)
    s.create_snapshot(990, b"S" * 100, compact_to=980)
    s.close()
    again = SQLiteStorage(tmp_path / "r.db")
    assert again.snapshot() == Snapshot(990, 1, b"S" * 100)
    assert (again.first_index(), again.last_index()) == (981, 1000)
    assert len(again._b.terms) == 20  # memory holds the tail's terms, not the history's
    n = again._db.execute("SELECT COUNT(*), MIN(idx) FROM entries").fetchone()
    assert n == (20, 981)
    again.close()


def test_sqlite_snapshot_and_compaction_survive_sigkill_consistently(tmp_path):
    path = tmp_path / "k.db"
    child = textwrap.dedent(f"""
        from swarmraft.raft import Entry, HardState, SQLiteStorage
        s = SQLiteStorage({str(path)!r})
        for k in range(1, 100_000):
            s.save(HardState(1, 1, k), [Entry(1, k, b"x%d" % k)])
            if k % 7 == 0:
                s.create_snapshot(k, b"state@%d" % k, compact_to=k - 3)
            if k == 300:
                print("running", flush=True)
    """)
    p = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "running"
    os.kill(p.pid, signal.SIGKILL)  # somewhere in the loop: perhaps mid-transaction
    p.wait()
    s = SQLiteStorage(path)
    snap, first, last = s.snapshot(), s.first_index(), s.last_index()
    assert snap.index % 7 == 0 and snap.data == b"state@%d" % snap.index
    assert first == snap.index - 3 + 1 and last >= snap.index
    assert [e.index for e in s.entries(first, last + 1)] == list(range(first, last + 1))
    assert s.initial_state().commit == last
    s.close()


def test_entries_codec_round_trips_and_rejects_garbage():
    es = [Entry(1, 1, b"a"), Entry(2, 2, b"", kind="noop"), Entry(2, 3, b"\x00" * 5)]
    assert unpack_entries(pack_entries(es)) == es
    with pytest.raises(ValueError, match="unpack_entries"):
        unpack_entries(pack_entries(es)[:-3])
    with pytest.raises(ValueError, match="after the last"):
        unpack_entries(pack_entries(es) + b"z")


def test_snapshot_policy_plans_every_k_entries_with_a_margin():
    p = SnapshotPolicy(every=100, keep=30)
    assert p.plan(99, 0, 1) is None
    assert p.plan(100, 0, 1) == (100, 70)
    assert p.plan(250, 150, 121) == (250, 220)
    assert SnapshotPolicy(every=10, keep=50).plan(20, 0, 1) == (20, None)  # not enough log to compact
    with pytest.raises(ValueError, match="every"):
        SnapshotPolicy(every=-1)


def elected(c, timeout=3000):
    assert c.run_until(lambda: c.leader() is not None, timeout)
    return c.leader()


def test_a_follower_behind_the_leaders_first_index_catches_up_by_install_snapshot():
    c = Cluster(3, seed=1, snapshots=SnapshotPolicy(every=10, keep=3))
    lead = elected(c)
    f = next(i for i in c.ids if i != lead)
    c.crash(f)
    for k in range(60):
        c.propose(b"p%d" % k)
        c.run(20)
    assert c.storage[lead].first_index() > 2  # the leader no longer holds what f lacks
    c.restart(f)
    c.run(1500)
    assert c.snapshots_installed >= 1
    assert c.applied(f) == c.applied(lead) == [b"p%d" % k for k in range(60)]
    assert c.storage[f].snapshot().index > 1


def test_a_restarted_node_restores_its_snapshot_and_applies_the_tail_only():
    applied: list[tuple[int, int]] = []
    c = Cluster(
        3,
        seed=2,
        snapshots=SnapshotPolicy(every=10, keep=2),
        on_apply=lambda i, e: applied.append((i, e.index)),
    )
    lead = elected(c)
    for k in range(35):
        c.propose(b"q%d" % k)
        c.run(20)
    c.run(200)
    f = next(i for i in c.ids if i != lead)
    snap = c.storage[f].snapshot().index
    assert snap >= 30
    applied.clear()
    c.crash(f)
    c.restart(f)
    c.run(300)
    assert [x for i, x in applied if i == f] == list(range(snap + 1, c.status(f).last_index + 1))
    assert c.applied(f) == c.applied(lead)


def test_a_follower_ignores_a_snapshot_it_already_holds_and_acks_its_commit():
    node = RaftNode(RaftConfig(id=2, peers=(1, 3)), MemoryStorage(), random.Random(0))
    node.step(Message(MsgType.APP, 1, 2, 1, entries=tuple(Entry(1, i, b"x") for i in range(1, 6)), commit=5))
    rd = node.ready()
    node.log.storage.save(rd.hard_state, rd.entries)
    node.advance(rd)
    node.step(Message(MsgType.SNAP, 1, 2, 1, snapshot=Snapshot(3, 1, b"old")))
    rd = node.ready()
    assert rd.snapshot is None and [(m.type, m.index) for m in rd.messages] == [(MsgType.APP_RESP, 5)]
    node.advance(rd)
    node.step(Message(MsgType.SNAP, 1, 2, 1, snapshot=Snapshot(9, 1, b"new")))
    rd = node.ready()
    assert rd.snapshot == Snapshot(9, 1, b"new") and rd.committed == ()
    assert rd.hard_state.commit == 9 and [m.index for m in rd.messages] == [9]


def record(step, n=4):
    return StepRecord(
        step,
        2,
        np.arange(3 * n, dtype=float).reshape(n, 3) + step,
        np.zeros(n, bool),
        np.zeros(n, bool),
        "ok",
        "paper",
        "d" * 32,
        np.ones(n),
        np.full(n, np.nan),
    )


def test_drone_state_encodes_deterministically_and_round_trips():
    st = Applied({k: record(k) for k in (5, 7, 8)}, skipped=[6], last_step=8, ignored=2)
    data = st.encode()
    assert data == Applied({k: record(k) for k in (5, 7, 8)}, [6], 8, 2).encode()
    back = Applied.decode(data)
    assert (list(back.records), back.skipped, back.last_step, back.ignored) == ([5, 7, 8], [6], 8, 2)
    assert back.records[7].encode() == record(7).encode()
    with pytest.raises(ValueError, match="drone state"):
        Applied.decode(b"XXXX" + data[4:])
    with pytest.raises(ValueError, match="drone state"):
        Applied.decode(data[:-1])


def test_a_snapshot_carries_the_configuration_to_a_new_member_and_across_a_restart():
    """A node that joins after the change that added it was compacted away learns the
    configuration from the snapshot alone; a node restarted after compaction rebuilds it from
    its own snapshot (not the bootstrap voters)."""
    c = Cluster(3, seed=3, snapshots=SnapshotPolicy(every=5, keep=0))
    lead = elected(c)
    c.run(200)  # the leader's no-op commits: changes may start
    new = c.add_node()
    c.propose_conf_change(ConfChange(ConfChangeType.ADD_LEARNER, new))
    c.run(200)
    c.propose_conf_change(ConfChange(ConfChangeType.PROMOTE, new))
    c.run(200)
    f = next(i for i in (1, 2, 3) if i != lead)
    c.propose_conf_change(ConfChange(ConfChangeType.REMOVE, f))
    c.run(200)
    for k in range(30):  # the changes end up in snapshots; the logs no longer hold them
        c.propose(b"r%d" % k)
        c.run(20)
    c.run(300)
    want = c.conf_state(lead)
    assert new in want.voters and f not in want.members
    snap = c.storage[lead].snapshot()
    assert (snap.voters, snap.learners) == (want.voters, want.learners)
    assert not any(e.kind == EntryKind.CONF_CHANGE for e in c.log(lead))  # compacted away
    late = c.add_node()  # knows only the bootstrap voters
    c.propose_conf_change(ConfChange(ConfChangeType.ADD_LEARNER, late))
    for k in range(30):
        c.propose(b"s%d" % k)
        c.run(20)
    c.run(500)
    assert c.snapshots_installed >= 1
    assert c.conf_state(late) == c.conf_state(lead) and late in c.conf_state(late).learners
    other = next(i for i in want.voters if i != lead)
    c.crash(other)
    c.restart(other)
    c.run(300)
    assert c.conf_state(other) == c.conf_state(lead)
