"""The fuzzer tested by injected bugs: the mutation suite of `swarmraft raft-fuzz --mutants`,
the new invariants (commit monotonic, liveness) and the crash points of the simulator."""

import re

import pytest
from click.testing import CliRunner

from swarmraft.cli import main
from swarmraft.sim import Cluster, InvariantViolation
from swarmraft.sim.mutants import MUTANTS, by_name, occurrences

# each kind of bug the issue names has its mutant
ISSUE_KINDS = {
    "commit-back-on-heartbeat",
    "prevote-raises-term",
    "ack-whole-log",
    "follower-commits-own-last",
    "figure8-old-term-commit",
    "vote-not-persisted",
    "vote-saved-late",
}


def test_every_mutant_snippet_occurs_exactly_once_in_the_current_core():
    # a core refactor that moves a snippet fails here, instead of testing nothing
    assert {m.name: occurrences(m) for m in MUTANTS} == {m.name: 1 for m in MUTANTS}


def test_the_suite_has_at_least_12_mutants_with_every_kind_the_issue_names():
    names = [m.name for m in MUTANTS]
    assert len(names) >= 12 and len(set(names)) == len(names)
    assert ISSUE_KINDS <= set(names)
    with pytest.raises(ValueError, match="no mutant nonsense"):
        by_name(["nonsense"])


def suite(*args: str):
    return CliRunner().invoke(main, ["raft-fuzz", "--mutants", *args])


def test_cheap_mutants_are_caught_by_the_fuzzer_alone_and_the_unmodified_core_passes():
    cheap = [m.name for m in MUTANTS if m.only_by] + [
        "quorum-of-half",
        "vote-not-persisted",
        "snapshot-wrong-term",
        "restart-reapplies-snapshot",
    ]
    r = suite("--seeds", "150", *(a for m in cheap for a in ("--mutant", m)))
    assert r.exit_code == 0, r.output
    assert f"{len(cheap)} of {len(cheap)} mutants caught" in r.output
    assert re.search(r"\(unmodified core\) +passes +- +- +150", r.output), r.output
    for m in by_name(cheap):
        row = re.search(rf"{m.name} +yes +\d+ +(\S+)", r.output)
        assert row, r.output
        if m.only_by:
            assert row.group(1) == m.only_by


@pytest.mark.parametrize("check", ["commit-monotonic", "liveness"])
def test_without_its_check_a_mutant_only_that_check_catches_survives(check):
    only = [m.name for m in MUTANTS if m.only_by == check]
    assert only
    blind = suite("--seeds", "20", *(a for m in only for a in ("--mutant", m)), "--without", check)
    assert blind.exit_code == 1 and f"0 of {len(only)} mutants caught" in blind.output, blind.output


def test_commit_index_going_back_is_a_violation():
    c = Cluster(3, seed=5)
    assert c.run_until(lambda: c.leader() is not None, 2000)
    c.propose(b"x")
    c.run(200)
    f = next(i for i in c.ids if i != c.leader())
    node = c.nodes[f]
    node.log.committed -= 1  # behind Raft's back
    with pytest.raises(InvariantViolation, match="commit-monotonic: node .* went back") as exc:
        c.run(200)
    assert exc.value.invariant == "commit-monotonic"


@pytest.mark.parametrize("point", ["persisted", "sent"])
def test_crash_in_ready_stops_the_node_between_saving_and_sending(point):
    c = Cluster(3, seed=6, raft_options={"max_entries_per_msg": 2})
    assert all(cfg.max_entries_per_msg == 2 for cfg in c.configs.values())
    assert c.run_until(lambda: c.leader() is not None, 2000)
    lead = c.leader()
    c.run(100)  # the leader's no-op is everywhere
    f, other = (i for i in c.ids if i != lead)
    c.crash(other)
    c.crash_in_ready(f, point, on={"MsgAppResp"}, restart_ms=5.0)
    acks = c.messages["MsgAppResp"]
    assert c.propose_batch([b"a", b"b", b"c"])
    c.run(4)
    assert not c.alive(f)
    assert [e.data for e in c.storage[f].entries(2, 4)] == [b"a", b"b"]  # saved: the first append
    assert c.messages["MsgAppResp"] == acks + (point == "sent")
    c.run(500)
    assert c.alive(f) and c.applied(f) == [b"a", b"b", b"c"]
