"""Storage: memory and SQLite behave alike; SQLite survives SIGKILL."""

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from swarmraft.raft import Entry, EntryKind, HardState, MemoryStorage, SQLiteStorage


@pytest.fixture(params=["memory", "sqlite"])
def storage(request, tmp_path):
    if request.param == "memory":
        yield MemoryStorage()
    else:
        s = SQLiteStorage(tmp_path / "raft.db")
        yield s
        s.close()


def test_save_truncates_from_first_new_entry(storage):
    storage.save(HardState(2, 1, 0), [Entry(1, 1, b"a"), Entry(1, 2, b"b"), Entry(2, 3, b"c")])
    assert storage.last_index() == 3 and storage.term(3) == 2
    storage.save(None, [Entry(3, 2, b"x", EntryKind.NOOP)])
    assert storage.last_index() == 2
    assert storage.entries(1, 3) == [Entry(1, 1, b"a"), Entry(3, 2, b"x", EntryKind.NOOP)]
    assert storage.initial_state() == HardState(2, 1, 0)
    assert storage.term(0) == 0


def test_rejects_gaps_and_bad_ranges(storage):
    with pytest.raises(ValueError, match="start at 3"):
        storage.save(None, [Entry(1, 3, b"x")])
    with pytest.raises(IndexError):
        storage.term(5)
    with pytest.raises(IndexError):
        storage.entries(1, 9)


def test_sqlite_reopens_with_state(tmp_path):
    path = tmp_path / "r.db"
    s = SQLiteStorage(path)
    s.save(HardState(5, 3, 2), [Entry(5, 1, b"p"), Entry(5, 2, b"q")])
    s.close()
    again = SQLiteStorage(path)
    assert again.initial_state() == HardState(5, 3, 2)
    assert [e.data for e in again.entries(1, 3)] == [b"p", b"q"]
    again.close()


def test_sqlite_survives_sigkill(tmp_path):
    path = tmp_path / "k.db"
    child = textwrap.dedent(f"""
        import sys, time
        from swarmraft.raft import Entry, HardState, SQLiteStorage
        s = SQLiteStorage({str(path)!r})
        for k in range(1, 201):
            s.save(HardState(term=k, vote=k % 5 + 1, commit=k - 1), [Entry(k, k, b"x%d" % k)])
            if k == 200:
                print("saved", flush=True)
        time.sleep(60)
    """)
    p = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "saved"
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    s = SQLiteStorage(path)
    assert s.initial_state() == HardState(term=200, vote=1, commit=199)
    assert s.last_index() == 200 and s.entries(200, 201)[0].data == b"x200"
    s.close()


def test_node_on_sqlite_keeps_its_vote_across_restart(tmp_path):
    import random

    from swarmraft.raft import Message, MsgType, RaftConfig, RaftNode

    cfg = RaftConfig(id=1, peers=(2, 3))
    s = SQLiteStorage(tmp_path / "n.db")
    n = RaftNode(cfg, s, random.Random(0))
    n.step(Message(MsgType.VOTE, 2, 1, term=3))
    rd = n.ready()
    s.save(rd.hard_state, rd.entries)
    n.advance(rd)
    s.close()
    again = RaftNode(cfg, SQLiteStorage(tmp_path / "n.db"), random.Random(1))
    assert (again.term, again.vote) == (3, 2)
    again.step(Message(MsgType.VOTE, 3, 1, term=3))
    assert [m.reject for m in again.ready().messages] == [True]
