"""Injected bugs in the Raft core, to show that `sim.fuzz` finds the bugs that matter.

Each `Mutant` is data: a file under ``swarmraft/raft/``, an exact source snippet (one or two
lines, so it survives unrelated edits) that occurs there exactly once, and its replacement.
`MutantTree` copies the package to a temporary folder; `run_mutant` writes one mutant into
the copy and runs the fuzzer on it in a child process (``PYTHONPATH`` set to the copy, unit
tests not involved), seed after seed until the first failing one or the budget.

``python -m swarmraft.sim.mutants START COUNT [--without NAME ...]`` is that child: it runs
seeds START.. and prints one JSON line per seed, stopping at the first failure.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Mutant:
    name: str
    bug: str  # what the injected bug does
    file: str  # under swarmraft/raft/
    old: str
    new: str
    only_by: str | None = None  # the one check that catches it (shown with raft-fuzz --without)


MUTANTS: tuple[Mutant, ...] = (
    Mutant(
        "commit-back-on-heartbeat",
        "a heartbeat sets the follower's commit index, moving it backwards",
        "node.py",
        "        self.log.commit_to(min(m.commit, self.log.last_index()))",
        "        self.log.committed = min(m.commit, self.log.last_index())",
        only_by="commit-monotonic",
    ),
    Mutant(
        "commit-not-restored",
        "a restarted node starts from commit index 0 instead of its saved one",
        "node.py",
        "        self.log = RaftLog(storage, committed=hs.commit, applied=applied)",
        "        self.log = RaftLog(storage, committed=0, applied=applied)",
        only_by="commit-monotonic",
    ),
    Mutant(
        "prevote-raises-term",
        "a PreVote request raises the receiver's term",
        "node.py",
        "            if m.type == MsgType.PRE_VOTE or (m.type == MsgType.PRE_VOTE_RESP and not m.reject):",
        "            if m.type == MsgType.PRE_VOTE_RESP and not m.reject:",
        only_by="liveness",
    ),
    Mutant(
        "heartbeat-keeps-timer",
        "a follower's election timer is not reset by heartbeats",
        "node.py",
        "        elif m.type == MsgType.HEARTBEAT:\n            self.election_elapsed = 0\n",
        "        elif m.type == MsgType.HEARTBEAT:\n            pass\n",
        only_by="liveness",
    ),
    Mutant(
        "ack-whole-log",
        "a follower acknowledges its whole log instead of what the append just gave it",
        "node.py",
        "m.frm, self.term, index=last))",
        "m.frm, self.term, index=self.log.last_index()))",
    ),
    Mutant(
        "follower-commits-own-last",
        "a follower commits up to its own last entry, not the last one the append matched",
        "log.py",
        "        self.commit_to(min(commit, last_new))",
        "        self.commit_to(min(commit, self.last_index()))",
    ),
    Mutant(
        "heartbeat-commit-unclamped",
        "a heartbeat carries the leader's commit index whatever the follower holds",
        "node.py",
        "                        index=self._read_round,\n"
        "                        commit=min(pr.match, self.log.committed),",
        "                        index=self._read_round,\n                        commit=self.log.committed,",
    ),
    Mutant(
        "figure8-old-term-commit",
        "a leader commits an entry of an earlier term by counting replicas (Raft paper, Figure 8)",
        "node.py",
        "        if n > self.log.committed and self.log.term(n) == self.term:",
        "        if n > self.log.committed:",
    ),
    Mutant(
        "vote-not-persisted",
        "a restarted node has forgotten its vote, as if it were never saved",
        "node.py",
        "        self.vote = hs.vote",
        "        self.vote = None",
    ),
    Mutant(
        "vote-saved-late",
        "a Ready's messages leave before its term and vote are saved (they are saved by the next Ready)",
        "node.py",
        "            hard_state=hs if hs != self._persisted_hs else None,",
        "            hard_state=hs if hs != self._persisted_hs and not self.msgs else None,",
    ),
    Mutant(
        "term-not-restored",
        "a restarted node starts from term 0 instead of its saved term",
        "node.py",
        "        self.term = hs.term",
        "        self.term = 0",
    ),
    Mutant(
        "no-vote-restriction",
        "a node votes for a candidate whose log is behind its own",
        "node.py",
        "        if can_vote and self.log.is_up_to_date(m.index, m.log_term):",
        "        if can_vote:",
    ),
    Mutant(
        "up-to-date-by-length",
        "the vote restriction compares log lengths only, not last terms",
        "log.py",
        "        return last_term > mine or (last_term == mine and last_index >= self.last_index())",
        "        return last_index >= self.last_index()",
    ),
    Mutant(
        "two-votes-per-term",
        "a node grants its vote to every candidate that asks",
        "node.py",
        "self.vote == m.frm or (self.vote is None and self.lead is None)",
        "True",
    ),
    Mutant(
        "quorum-of-half",
        "a quorum is half the members, not a majority",
        "node.py",
        "        return len(self.conf_state.voters) // 2 + 1",
        "        return len(self.conf_state.voters) // 2",
    ),
    Mutant(
        "no-prev-term-check",
        "a follower accepts an append whose previous entry it holds with another term",
        "log.py",
        "        if not self.match_term(prev_index, prev_term):",
        "        if prev_index > self.last_index():",
    ),
    Mutant(
        "truncate-on-every-append",
        "a follower truncates its log after every append, even one it already holds (a late duplicate)",
        "log.py",
        "            if not self.match_term(e.index, e.term):",
        "            if e.index > 0:",
    ),
    # membership, leader transfer and reads
    Mutant(
        "learner-in-quorum",
        "a learner's acknowledgement counts towards the commit quorum",
        "node.py",
        "        matches = [pr.match for p, pr in self.prs.items() if p in voters]",
        "        matches = [pr.match for p, pr in self.prs.items()]",
    ),
    Mutant(
        "two-changes-pending",
        "a leader accepts a configuration change while another one is uncommitted",
        "node.py",
        "        if self.confs.last_index > self.log.committed:",
        "        if False:",
    ),
    Mutant(
        "change-before-term-commit",
        "a new leader proposes a configuration change before committing an entry of its term",
        "node.py",
        "        if self.log.committed < self._term_start:\n            raise ConfChangeRefused(",
        "        if False:\n            raise ConfChangeRefused(",
    ),
    Mutant(
        "timeout-now-behind",
        "a leader sends MsgTimeoutNow at once, to a transfer target whose log is behind",
        "node.py",
        "        if pr.match == self.log.last_index():\n            self._send_timeout_now(to)",
        "        if True:\n            self._send_timeout_now(to)",
        only_by="transfer-caught-up",
    ),
    Mutant(
        "learner-campaigns",
        "a learner or a removed node campaigns like a voter when its election timeout ends",
        "node.py",
        "        if self.role == Role.LEADER or self.id not in self.conf_state.voters:",
        "        if self.role == Role.LEADER:",
    ),
    Mutant(
        "read-before-quorum",
        "a leader answers a read at once, without a heartbeat round to a quorum",
        "node.py",
        "        if self._read_confirmed(r):  # a single voter",
        "        if True:",
        only_by="read-linearizable",
    ),
    Mutant(
        "conf-kept-on-truncate",
        "a follower keeps a configuration whose entry its log lost to a new leader's entries",
        "node.py",
        "            self.confs.truncate(self.log.term, self.log.first_index())",
        "            pass",
    ),
    Mutant(
        "removed-leader-stays",
        "a leader that removed itself keeps leading after the change commits",
        "node.py",
        "        if self.id not in self.conf_state.voters and self.log.committed >= self.confs.last_index:",
        "        if False:",
    ),
    Mutant(
        "snapshot-over-newer-log",
        "a follower installs a leader's snapshot older than its commit index, over its newer log",
        "node.py",
        "        if snap.index <= self.log.committed:\n            pass  # older than what we have committed",
        "        if False:\n            pass  # older than what we have committed",
    ),
    Mutant(
        "compacted-entries-sent",
        "a leader appends from its compaction point (an entry it no longer holds) instead of snapshotting",
        "node.py",
        "        if pr.next < self.log.first_index():",
        "        if pr.next < self.log.first_index() - 1:",
    ),
    Mutant(
        "snapshot-past-applied",
        "a host labels its snapshot one entry past the index its state machine applied",
        "snapshots.py",
        "        return applied, compact_to if compact_to >= first_index else None",
        "        return applied + 1, compact_to if compact_to >= first_index else None",
    ),
    Mutant(
        "restart-reapplies-snapshot",
        "a restarted node applies the entries its snapshot already holds",
        "log.py",
        "        self.applied = max(applied, storage.snapshot().index)",
        "        self.applied = applied",
    ),
    Mutant(
        "snapshot-wrong-term",
        "a snapshot records the term after the one of its last entry",
        "storage.py",
        "        self._snap = _snapshot(index, self._b.term(index), data, conf)",
        "        self._snap = _snapshot(index, self._b.term(index) + 1, data, conf)",
    ),
    Mutant(
        "timeout-not-randomised",
        "every election timeout is the same, election_tick ticks",
        "node.py",
        "        return et + self.rng.randrange(et)  # uniform in [election_tick, 2 election_tick)",
        "        return et",
    ),
)


def by_name(names: Iterable[str]) -> list[Mutant]:
    """The mutants named, in the order of `MUTANTS`; an unknown name is a ValueError."""
    want = set(names)
    known = {m.name for m in MUTANTS}
    if unknown := want - known:
        raise ValueError(f"no mutant {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}")
    return [m for m in MUTANTS if m.name in want]


def package_dir() -> Path:
    """The folder of the ``swarmraft`` package that is running."""
    import swarmraft

    return Path(swarmraft.__file__).parent


def occurrences(mutant: Mutant, package: Path | None = None) -> int:
    """How often the mutant's snippet occurs in its file (it applies only when exactly once)."""
    return (package or package_dir()).joinpath("raft", mutant.file).read_text().count(mutant.old)


@dataclass(frozen=True)
class SeedOutcome:
    seed: int
    ok: bool
    invariant: str | None
    error: str | None


class MutantTree:
    """A copy of the package in a temporary folder, where one mutant at a time is written."""

    def __init__(self, package: Path | None = None) -> None:
        self._tmp = tempfile.TemporaryDirectory(prefix="swarmraft-mutants-")
        self.root = Path(self._tmp.name)
        shutil.copytree(
            package or package_dir(), self.root / "swarmraft", ignore=shutil.ignore_patterns("__pycache__")
        )

    def close(self) -> None:
        self._tmp.cleanup()

    def __enter__(self) -> MutantTree:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def run(
        self, mutant: Mutant | None, seeds: int, seed_start: int = 0, without: Iterable[str] = ()
    ) -> Iterator[SeedOutcome]:
        """Run the fuzzer on the copy with ``mutant`` written into it (None: the unmodified
        core) in a child process, yielding each seed's outcome; it stops after the first
        failing seed. The copy is restored afterwards."""
        target = self.root / "swarmraft" / "raft" / mutant.file if mutant else None
        original = target.read_text() if target else ""
        if mutant and target:
            if original.count(mutant.old) != 1:
                raise ValueError(
                    f"mutant {mutant.name}: its snippet occurs {original.count(mutant.old)} times in "
                    f"raft/{mutant.file}, not once"
                )
            target.write_text(original.replace(mutant.old, mutant.new))
        env = {**os.environ, "PYTHONPATH": str(self.root), "PYTHONDONTWRITEBYTECODE": "1"}
        cmd = [sys.executable, "-m", "swarmraft.sim.mutants", str(seed_start), str(seeds)]
        for name in without:
            cmd += ["--without", name]
        try:
            with subprocess.Popen(
                cmd, cwd=self.root, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            ) as proc:
                assert proc.stdout is not None
                try:
                    for line in proc.stdout:
                        d = json.loads(line)
                        yield SeedOutcome(d["seed"], d["ok"], d["invariant"], d["error"])
                finally:
                    proc.kill()
                    err = proc.stderr.read() if proc.stderr else ""
                if proc.wait() not in (0, -9) and err:
                    raise RuntimeError(f"the fuzzer's child process failed: {err.strip().splitlines()[-1]}")
        finally:
            if target:
                target.write_text(original)


def _child(argv: list[str]) -> None:
    import swarmraft
    from swarmraft.sim.fuzz import FuzzConfig, run_seeds

    start, count = int(argv[0]), int(argv[1])
    without = frozenset(argv[i + 1] for i, a in enumerate(argv) if a == "--without")
    here = Path(os.environ.get("PYTHONPATH", "")).resolve()
    if here not in Path(swarmraft.__file__).resolve().parents:
        raise SystemExit(f"the child imported {swarmraft.__file__}, not the copy under {here}")
    for r in run_seeds(start, count, FuzzConfig(without=without), stop_at_first=True):
        print(
            json.dumps({"seed": r.seed, "ok": r.ok, "invariant": r.invariant, "error": r.error}), flush=True
        )


if __name__ == "__main__":
    _child(sys.argv[1:])
