"""The audit of a leader's records (docs/audit.md): before a voter persists and acknowledges
a record, it checks that the record follows from the evidence the record carries, so a
lying leader's record never reaches a quorum while honest voters are a majority.

A record passes when

- the leader's signature over the record verifies, and every carried report is for the
  record's step, from a distinct drone, with a signature that verifies;
- the detector and its parameters are the swarm's (this drone's configuration), the report
  digest and the missing flags match the carried reports, and the record's term is its log
  entry's;
- the record's step is at most FUTURE_STEPS ahead of this drone's clock (`at_step`);
- the prior is a record this drone holds for that step (audited, proposed, applied, or read
  back from its own log after a restart: `remember`), settled, at most PRIOR_STEPS before.
  Raft's log matching puts every honest prior in the voter's log (its entry comes before the
  record's), so a prior this drone does not hold is one the leader made up;
- re-running the verification (`compute_record`) on the carried reports and prior gives the
  same flags, missing drones and status exactly, and positions and protection levels within
  ``POSITION_TOL_M`` (floating point differs between machines; a record is never trusted to
  more than that).

Censorship: a drone also receives every drone's report directly (the report fan-out). A
record that leaves out a report this drone held by the step's deadline is an omission of that
drone's report; a drone whose reports are omitted in more than k of the last m records of the
same leader term makes this drone treat the leader as faulty (`take_suspicion`), as a refused
record does. The windows restart with every new term.

Signatures are verified once: a report whose signature verified when it arrived directly
(`note_report`) is not verified again when a record carries it, by the drone's `Keyring`,
which remembers each check by (drone, signature, digest of the signed bytes); a carried
report that differs in any byte from the one received is verified in full.

Pure logic: the host feeds reports (`note_report`), closes steps at their deadline
(`close_step`) and deposes the leader (`RaftNode.depose`) on a censorship finding.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import TYPE_CHECKING

import numpy as np

from swarmraft.protocol.drone import PRIOR_STEPS, Prior, memo_compute
from swarmraft.protocol.memo import record_digest
from swarmraft.protocol.records import (
    Report,
    StepRecord,
    canonical_params,
    carried_positions,
    settled,
    well_formed,
)
from swarmraft.raft import Entry, EntryKind, Snapshot

if TYPE_CHECKING:
    from swarmraft.protocol.drone import SwarmDrone

#: m: how far a re-run position (and protection level) may be from the record's. Covers
#: floating-point differences between machines: last-bit differences in BLAS, libm and the
#: compiled kernels, amplified by the estimators' conditioning and the solver's stopping rule
#: (the iteration a Levenberg-Marquardt run stops at can differ). Re-run on an AVX2 CPU, the
#: records of every shipped scenario (seeds 1-3) differ from this machine's (AVX-512) by up to
#: 3.7e-5 m (`benchmarks/cross_cpu_audit.py`); 1 mm leaves 27 times that and is far below any
#: error that matters (the position sigma is 0.1-3 m).
POSITION_TOL_M = 1e-3
#: (k, m): a leader is faulty when one drone's reports are omitted in more than k of the
#: last m records of its term (chosen by `benchmarks/bench_censor.py`, docs/audit.md)
CENSOR = (10, 20)
#: steps of reports, records and omissions kept
KEEP_STEPS = 64
_MISSING = object()  # a memo's miss (its values include None: a passing record)
#: steps a record may be ahead of the auditing drone's own clock (`Auditor.at_step`): the
#: clock difference allowed between a leader and its voters (0.3 s at 10 Hz). A record for a
#: step far ahead, carrying only the liar's own signed report for that step, passed every
#: other check, and every drone then ignored each later record and report for good.
FUTURE_STEPS = 3


def _close(a: np.ndarray | None, b: np.ndarray | None, tol: float) -> bool:
    """Same shape, same nan and inf pattern, finite values within ``tol`` (absolute)."""
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape != b.shape:
        return False
    if tol >= 0 and a.tobytes() == b.tobytes():  # the same bits (a re-run on the leader's kind of machine)
        return True
    fa, fb = np.isfinite(a), np.isfinite(b)
    if not np.array_equal(fa, fb):
        return False
    same_special = np.array_equal(a[~fa], b[~fb], equal_nan=True)
    return bool(same_special and np.all(np.abs(a[fa] - b[fb]) <= tol))


def rerun_differs(again: StepRecord, rec: StepRecord, tol: float = POSITION_TOL_M) -> str | None:
    """Why the record ``rec`` is not what re-running its verification gave (``again``), or
    None: the same report digest, missing drones, flags and status exactly, positions and
    protection levels within ``tol`` m with the same nan and inf pattern."""
    if again.digest != rec.digest:  # the re-run digests the carried reports once
        return "report digest"
    if not np.array_equal(again.missing, rec.missing):
        return "missing drones differ from the reports"
    if not np.array_equal(again.faulty, rec.faulty):
        bad = np.flatnonzero(again.faulty != rec.faulty) + 1
        return f"flags differ from the re-run (drones {bad.tolist()})"
    if again.status != rec.status:
        return f"status {rec.status}, the re-run gives {again.status}"
    if not _close(again.positions, rec.positions, tol):
        return "positions differ from the re-run"
    if not (_close(again.hpl, rec.hpl, tol) and _close(again.vpl, rec.vpl, tol)):
        return "protection levels differ from the re-run"
    return None


class Auditor:
    """One drone's audit: `validate` is its Raft node's validator; `check` the full check of
    one record (reason None when it passes). ``cache`` (optional, the simulator's): a memo
    shared by drones of the evidence checks, which depend only on the record's bytes and the
    swarm's configuration and keys (the same on every drone); each drone still checks the
    term, the prior and censorship itself."""

    def __init__(
        self, drone: SwarmDrone, cache: dict | None = None, censor: tuple[int, int] = CENSOR
    ) -> None:
        self.drone = drone
        self.cache = cache
        self.k, self.m = censor
        if not 0 <= self.k < self.m:
            raise ValueError(f"censor: need 0 <= k < m, got k={self.k}, m={self.m}")
        self.tolerance = POSITION_TOL_M
        self._passed: OrderedDict[bytes, int] = OrderedDict()  # digest -> the record's term
        self.seen: dict[int, list[StepRecord]] = {}  # step -> records held for it
        self.refused: list[tuple[int, str]] = []  # (step, reason)
        self.clock: int | None = None  # the step this drone's clock has reached (`at_step`)
        # censorship
        self.timely: dict[int, set[int]] = {}  # step -> drones whose report this drone held
        self.closed: set[int] = set()
        self.omissions: dict[int, list[int]] = {}  # drone -> steps its report was left out
        self.omission_term = -1
        self._unjudged: dict[int, list[tuple[int, set[int]]]] = {}  # step -> [(term, carried)]
        self.suspicion: str | None = None

    def at_step(self, k: int) -> None:
        """This drone's clock has reached step k (its host calls this as each step begins, and
        a networked host from the wall clock as messages come; and it moves on by itself to a
        step whose signed reports it holds from a majority of the swarm, `note_report`, so
        that a drone whose clock lags the others' does not refuse their leader's records): a
        record more than FUTURE_STEPS ahead of it is refused. Until a host calls it nothing
        is ahead."""
        self.clock = k if self.clock is None else max(self.clock, k)

    # -- the records this drone holds --------------------------------------------------------
    def passed(self, data: bytes) -> bool:
        """Whether this drone already checked ``data`` and it passed."""
        return record_digest(data) in self._passed

    def _hold(self, data: bytes, rec: StepRecord) -> None:
        self._passed[record_digest(data)] = rec.term
        while len(self._passed) > 4 * KEEP_STEPS:
            self._passed.popitem(last=False)
        self._see(rec)

    def _see(self, rec: StepRecord) -> None:
        """``rec`` held for its step (a prior of later records); steps long past forgotten."""
        self.seen.setdefault(rec.step, []).append(rec)
        for old in [s for s in self.seen if s < rec.step - KEEP_STEPS]:
            del self.seen[old]

    def remember(self, data: bytes) -> None:
        """A record of this drone's own Raft log, read back after a restart: held as a prior
        of later records (what `seen` held before the restart). Every entry of a log was
        validated before it was persisted (or proposed by this drone), so it is not checked
        again here; one committed is checked at its apply as any record not passed. Bytes
        that do not decode are left out."""
        try:
            rec = self.drone.decode(data)
        except Exception:  # noqa: BLE001 - any undecodable entry is simply not a prior
            return
        self._see(rec)

    def proposed(self, data: bytes, rec: StepRecord) -> None:
        """This drone proposed ``rec`` as leader: it holds it (a prior of later records)."""
        self._hold(data, rec)

    # -- checks ------------------------------------------------------------------------------
    def evidence_ahead(self, data: bytes) -> None:
        """Computes the checks of ``data`` that depend only on its bytes (the signatures and
        the re-run: nearly all the audit's time) into ``cache``, so that `validate` finds them
        there. They read nothing that changes, so a host may run this beside its Raft node, in
        a thread of its own, before it steps the append (`net.node`). Needs ``cache``."""
        if self.cache is None:
            raise ValueError("evidence_ahead: the auditor has no cache")
        if self.passed(data) or record_digest(data) in self.cache:
            return
        try:
            rec = self.drone.decode(data)
        except Exception:  # undecodable: `check` says why when the node steps it
            return
        self._evidence(data, rec)

    def validate(self, entry: Entry) -> bool:
        """The Raft node's validator: whether ``entry`` may enter this drone's log."""
        if entry.kind != EntryKind.NORMAL:
            return True
        held = self._passed.get(record_digest(entry.data))
        if held is not None:
            if held == entry.term:
                return True
            # bytes audited before, now in an entry of another term: the term check, which
            # the shortcut skipped
            self._refuse(-1, f"a record of term {held} in an entry of term {entry.term}")
            return False
        rec, reason = self.check(entry.data, entry.term)
        if reason is None and rec is not None:
            self._censorship(rec)
        return reason is None

    def validate_snapshot(self, snap: Snapshot) -> bool:
        """The Raft node's validator of a leader's snapshot, before it is installed: the
        replicated state it carries (`Applied`) must be one that applying audited records
        makes. A snapshot holds the records the log entries it replaces made; a liar that
        could send any (a record moved 500 m, not even signed, a last step a million ahead)
        got round the audit of entries. Refused (False, the reason in ``refused``) unless
        it decodes; its last step is its newest record's (-1 with none), ahead of no skipped
        step, and at most FUTURE_STEPS ahead of this drone's clock; and each record passes
        `check` in step order (signatures, the re-run, the clock; a record's prior inside
        the snapshot must be its record for that step). A prior before the snapshot's
        oldest record is checked where this drone holds a record for that step: a drone
        that needs a snapshot is behind, and may hold none."""
        n_refused = len(self.refused)
        reason = self._state_problem(snap.data)
        del self.refused[n_refused:]  # a record's own refusal: said once, in the snapshot's
        if reason is not None:
            self._refuse(-1, f"snapshot at index {snap.index}: {reason}")
        return reason is None

    def _state_problem(self, data: bytes) -> str | None:
        from swarmraft.protocol.drone import Applied  # the drone module imports this one

        try:
            state = Applied.decode(data)
        except Exception as exc:  # noqa: BLE001 - anything a liar's bytes make it raise
            return f"undecodable ({type(exc).__name__})"
        steps = sorted(state.records)
        if state.last_step != (steps[-1] if steps else -1):
            return f"last step {state.last_step} is not its newest record's"
        if any(k >= state.last_step for k in state.skipped):
            return "a skipped step at or after its last step"
        if self.clock is not None and state.last_step > self.clock + FUTURE_STEPS:
            return f"last step {state.last_step} is ahead of this drone's clock (step {self.clock})"
        for k in steps:
            rec = state.records[k]
            # a prior before the oldest record kept is not in the snapshot (a record's prior is
            # often not the record before it: that one an alarm, or not yet applied when this
            # step was verified); one inside it must be the record held for that step
            _, why = self.check(rec.encode(), prior_unknown_ok=rec.prior_step < steps[0])
            if why is not None:
                return f"its record of step {k}: {why}"
        return None

    def check(
        self, data: bytes, term: int | None = None, prior_unknown_ok: bool = False
    ) -> tuple[StepRecord | None, str | None]:
        """The record in ``data`` and why it fails (None: it passes; it is then held).
        ``prior_unknown_ok``: a prior this drone holds no record for is not refused (a
        snapshot's record whose prior is before the snapshot's oldest record)."""
        try:
            rec = self.drone.decode(data)
        except (ValueError, TypeError, IndexError) as exc:
            return self._refuse(-1, f"undecodable: {exc}")
        except Exception as exc:  # struct.error, json errors: malformed bytes from a liar
            return self._refuse(-1, f"undecodable: {type(exc).__name__}")
        if term is not None and rec.term != term:
            return self._refuse(rec.step, f"term {rec.term} in an entry of term {term}")
        if self.clock is not None and rec.step > self.clock + FUTURE_STEPS:
            ahead = f"step {rec.step} is ahead of this drone's clock (step {self.clock})"
            return self._refuse(rec.step, ahead)
        reason = self._evidence(data, rec)
        if reason is None:
            reason = self._prior(rec, prior_unknown_ok)
        if reason is not None:
            return self._refuse(rec.step, reason)
        self._hold(data, rec)
        return rec, None

    def _refuse(self, step: int, reason: str) -> tuple[None, str]:
        self.refused.append((step, reason))
        return None, reason

    def _evidence(self, data: bytes, rec: StepRecord) -> str | None:
        """The checks that depend only on the bytes (memoised in ``cache``)."""
        key = record_digest(data)
        # one read (`get`), not `in` then `[]`: the audit thread may forget the item between
        if self.cache is not None and (hit := self.cache.get(key, _MISSING)) is not _MISSING:
            return hit
        reason = self._evidence_uncached(rec, data[: len(data) - len(rec.signature)])
        if self.cache is not None:
            self.cache[key] = reason
        return reason

    def _evidence_uncached(self, rec: StepRecord, body: bytes) -> str | None:
        """``body``: the signed bytes as received (what the signature covers)."""
        c, keys = self.drone.config, self.drone.keys
        if len(rec.faulty) != c.n:
            return f"{len(rec.faulty)} drones, the swarm has {c.n}"
        if not keys.verify_bytes(rec.leader, body, rec.signature):
            return f"leader signature (drone {rec.leader + 1})"
        if rec.detector != c.detector or rec.params != canonical_params(c.detector_params):
            return "detector or parameters are not the swarm's"
        if not rec.reports:
            return "no reports"
        drones = [r.drone for r in rec.reports]
        if drones != sorted(set(drones)) or not 0 <= drones[0] <= drones[-1] < c.n:
            return "reports out of order, repeated or out of range"
        formed = well_formed(rec.reports, c.n)  # all at once; one by one only for the reason
        for r in rec.reports:
            if r.step != rec.step:
                return f"drone {r.drone + 1}'s report is for step {r.step}"
            if not formed and (why := r.malformed(c.n)) is not None:  # an honest leader keeps none such
                return f"drone {r.drone + 1}'s report: {why}"
            if not keys.verify(r):
                return f"drone {r.drone + 1}'s report signature"
        prior = None
        if rec.prior_step >= 0:
            if rec.prior_positions is None or rec.prior_faulty is None:
                return "prior without positions"
            prior = Prior(rec.prior_step, rec.prior_positions, rec.prior_faulty)
        reports = {r.drone: r for r in rec.reports}
        try:
            again = memo_compute(self.drone.record_memo, rec.step, rec.term, reports, prior, c)
        except Exception as exc:  # noqa: BLE001 - whatever the leader signed made it raise
            # a leader signs the prior it likes: one of 1e300 or inf made the solver raise,
            # and the exception left the validator through the Raft node (no refusal, no
            # election: the voter followed the liar for good). A record the verification
            # cannot re-run does not follow from its evidence.
            return f"re-run failed: {type(exc).__name__}: {str(exc)[:120]}"
        return rerun_differs(again, rec, self.tolerance)

    def _prior(self, rec: StepRecord, unknown_ok: bool = False) -> str | None:
        """The prior is a settled record this drone holds, within PRIOR_STEPS (``unknown_ok``:
        or one it holds no record for)."""
        if rec.prior_step < 0:
            return None
        if not rec.step - PRIOR_STEPS <= rec.prior_step < rec.step:
            return f"prior step {rec.prior_step} outside {PRIOR_STEPS} steps"
        held = list(self.seen.get(rec.prior_step, []))
        applied = self.drone.state.records.get(rec.prior_step)
        if applied is not None:
            held.append(applied)
        if not held:
            return None if unknown_ok else f"prior step {rec.prior_step}: this drone holds no record for it"
        for h in held:
            if (
                settled(h)
                and np.array_equal(carried_positions(h), rec.prior_positions, equal_nan=True)
                and np.array_equal(h.faulty, rec.prior_faulty)
            ):
                return None
        return f"prior step {rec.prior_step} is not a settled record held for it"

    # -- censorship --------------------------------------------------------------------------
    def note_report(self, report: Report, data: bytes | None = None) -> bool:
        """A report received directly (the fan-out): held for its step if its signature
        verifies and the step's deadline has not passed here. ``data``: its bytes, the key
        of the shared memo (``cache``) of the signature check."""
        return self._note(report.step, report.drone, data, lambda: report)

    def note_report_bytes(self, data: bytes) -> bool:
        """`note_report` of an encoded report, decoded only where its signature must be
        checked: a copy for a step already closed or already held, or whose check the memo
        holds, needs only its step and drone (in a 17-drone mission each report reaches 15
        voters, and decoding every copy was a tenth of the simulator's time)."""
        step, drone = Report.head(data)
        return self._note(step, drone, data, lambda: Report.decode(data))

    def _note(self, step: int, drone: int, data: bytes | None, report) -> bool:  # noqa: ANN001
        if step in self.closed or drone in self.timely.get(step, ()):
            return False

        def good(r: Report) -> bool:  # as the leader keeps it (`SwarmDrone.receive`)
            return r.malformed(self.drone.config.n) is None and self.drone.keys.verify(r)

        if self.cache is not None and data is not None:
            key = b"report" + record_digest(data)  # one bytes object per fanned-out report
            ok = self.cache.get(key)  # one read: another thread may forget it meanwhile
            if ok is None:
                ok = self.cache[key] = good(report())
        else:
            ok = good(report())
        if not ok:
            return False
        held = self.timely.setdefault(step, set())
        held.add(drone)
        if 2 * (len(held) + 1) > self.drone.config.n:
            # a majority of the swarm (this drone with them) has reached this step: a clock
            # that lags theirs (the networked drone's wall clock) catches up, so that their
            # leader's records are not refused as ahead
            self.at_step(step)
        return True

    def close_step(self, step: int) -> None:
        """Step ``step``'s deadline passed here: reports arriving later are not timely. A
        record of that step validated before now is judged for omissions now (its host then
        asks `take_suspicion`), against the reports held by this moment."""
        self.at_step(step)
        self.closed.add(step)
        # the newest leader's first: an earlier term's record for the step is then not judged
        for term, carried in sorted(self._unjudged.pop(step, []), key=lambda p: -p[0]):
            self._judge(step, term, carried)
        for old in [s for s in self.closed if s < step - KEEP_STEPS]:
            self.closed.discard(old)
            self.timely.pop(old, None)
        for old in [s for s in self.timely if s < step - KEEP_STEPS]:
            del self.timely[old]
        for old in [s for s in self._unjudged if s < step - KEEP_STEPS]:
            del self._unjudged[old]

    def _censorship(self, rec: StepRecord) -> None:
        """A record's omissions, judged once its step has closed here (at once if it has):
        judged when the record came, a leader that proposed before the fan-out's copies
        arrived was never found leaving anyone out (even a record carrying its own report
        alone)."""
        carried = {r.drone for r in rec.reports}
        if rec.step in self.closed:
            self._judge(rec.step, rec.term, carried)
        else:
            self._unjudged.setdefault(rec.step, []).append((rec.term, carried))

    def _judge(self, step: int, term: int, carried: set[int]) -> None:
        if term < self.omission_term:
            return  # an earlier leader's record, judged after a later one's: not its tally
        if term > self.omission_term:
            self.omissions.clear()  # a new leader starts with a clean slate
            self.omission_term = term
        for d in self.timely.get(step, set()) - carried:
            steps = self.omissions.setdefault(d, [])
            steps.append(step)
            recent = [s for s in steps if s > step - self.m]
            self.omissions[d] = recent
            if len(recent) > self.k and self.suspicion is None:
                left = f"left out of {len(recent)} of the last {self.m} steps"
                self.suspicion = f"drone {d + 1}'s reports {left}"

    def take_suspicion(self) -> str | None:
        """Why this drone now treats its leader as faulty (once), or None."""
        why, self.suspicion = self.suspicion, None
        if why is not None:
            self.omissions.clear()
        return why
