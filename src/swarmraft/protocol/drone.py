"""The SwarmRaft drone: reports, the leader's verification, and the replicated state machine.

Pure logic (no clock, no network): the host (the simulator, or a real runtime) calls

- `make_report` every step and sends the report to the Raft leader;
- `receive` on the leader for each report that arrives (signatures are checked);
- `verify_step` on the leader at the step's deadline, and proposes the returned record's
  bytes to Raft;
- `apply` on every drone, in log order, for each committed entry.

Exactly one record per step: `apply` takes records in step order and ignores a record for a
step that already has one (a new leader may propose a step again) or for a step behind the
last applied one; steps passed over are *skipped*. Every drone applies the same log, so every
drone holds the same records.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from swarmraft.estimation import SnapshotBatch, get_detector, verify_batch
from swarmraft.estimation.bounds import gnss_covariance
from swarmraft.estimation.joint import anchor_counts, trusted_estimate
from swarmraft.protocol.drift import DriftModel, DriftVerdict, record_drift
from swarmraft.protocol.memo import BoundedMemo, record_digest
from swarmraft.protocol.records import (
    Report,
    StepRecord,
    canonical_params,
    carried_positions,
    reports_digest,
    settled,
)
from swarmraft.protocol.signing import Keyring

MIN_SIGMA = 1e-3  # m: floor for exact (noise-free) scenarios, as the detectors use
#: how far back the leader looks for a record to carry on (steps)
PRIOR_STEPS = 3


@dataclass(frozen=True)
class ProtocolConfig:
    """Leader-side settings. ``innovation_gate``: flag a drone whose whitened GNSS-minus-INS
    innovation (squared, 3 dof) exceeds it (None: off); ``innovation_sigma``: the 1-sigma
    (horizontal, vertical) per axis of an honest drone's innovation (GNSS change plus INS
    drift over the window). A drone flagged in the last record stays flagged while its report
    disagrees (beyond the same gate) with where the trusted drones put it. ``drift``: the
    drag-off test over the reports' window innovations (`swarmraft.protocol.drift`; None: off)."""

    n: int
    detector: str = "paper"
    detector_params: dict[str, Any] = field(default_factory=dict)
    gnss_sigma: tuple[float, float] = (1.5, 3.0)
    range_sigma: float = 0.1
    innovation_gate: float | None = 25.9  # chi-square 3 dof at 1e-5
    innovation_sigma: tuple[float, float] = (0.5, 0.9)
    prior_sigma: float = 3.0  # m: the last record's position, one step (up to ~1 m of motion) old
    drift: DriftModel | None = None


#: records a drone keeps (the newest): the protocol reads only the last one (the next step's
#: prior); a host that wants every record takes each as it is applied (the simulator's mission
#: log, the networked drone's records file). Keeping all of them grew by 16.5 MB a minute in
#: a 17-drone mission.
RECORDS_KEPT = 32
#: skipped steps a drone keeps (the newest): the protocol reads none of them; they tell a
#: host or a snapshot's reader which recent steps were passed over. Unbounded, a swarm that
#: loses its leader for good grew the list (and every snapshot) by 10 steps a second.
SKIPPED_KEPT = 256


@dataclass
class Applied:
    """A drone's replicated state: the newest RECORDS_KEPT records by step, and the newest
    SKIPPED_KEPT steps passed over."""

    records: dict[int, StepRecord] = field(default_factory=dict)
    skipped: list[int] = field(default_factory=list)
    last_step: int = -1
    ignored: int = 0  # records for a step already decided (re-proposals) or behind

    def encode(self) -> bytes:
        """The state as bytes, for a Raft snapshot (docs/protocol.md, Snapshots): a header
        (magic b"SRAP", version 1, last_step i64, ignored u64, number of skipped steps u32),
        the skipped steps (i64 each), the number of records (u32), then each record's length
        (u32) and its `StepRecord.encode` bytes, oldest first. Little-endian; the same state
        gives the same bytes."""
        recs = [self.records[k].encode() for k in sorted(self.records)]
        return b"".join(
            [
                _STATE_HEAD.pack(
                    _STATE_MAGIC, _STATE_VERSION, self.last_step, self.ignored, len(self.skipped)
                ),
                struct.pack(f"<{len(self.skipped)}q", *self.skipped),
                _U32.pack(len(recs)),
                *(_U32.pack(len(r)) + r for r in recs),
            ]
        )

    @classmethod
    def decode(cls, data: bytes) -> Applied:
        """The inverse of `encode`; ValueError naming what is wrong if ``data`` is not such bytes."""
        try:
            magic, version, last_step, ignored, n_skipped = _STATE_HEAD.unpack_from(data)
            if magic != _STATE_MAGIC or version != _STATE_VERSION:
                raise ValueError(f"drone state: magic {magic!r} version {version}, not {_STATE_MAGIC!r} 1")
            off = _STATE_HEAD.size
            skipped = list(struct.unpack_from(f"<{n_skipped}q", data, off))
            off += 8 * n_skipped
            (n_records,) = _U32.unpack_from(data, off)
            off += _U32.size
            records: dict[int, StepRecord] = {}
            for _ in range(n_records):
                (size,) = _U32.unpack_from(data, off)
                off += _U32.size
                if off + size > len(data):
                    raise ValueError("drone state: a record runs past the end")
                rec = StepRecord.decode(bytes(data[off : off + size]))
                records[rec.step] = rec
                off += size
        except struct.error as exc:
            raise ValueError(f"drone state: truncated ({exc})") from exc
        except (TypeError, IndexError, KeyError, UnicodeDecodeError) as exc:  # a record's parts
            raise ValueError(f"drone state: a record does not decode ({type(exc).__name__}: {exc})") from exc
        if off != len(data):
            raise ValueError(f"drone state: {len(data) - off} bytes after the last record")
        return cls(records, skipped, last_step, ignored)


_STATE_MAGIC = b"SRAP"
_STATE_VERSION = 1
_STATE_HEAD = struct.Struct("<4sBqQI")
_U32 = struct.Struct("<I")


class SwarmDrone:
    """One drone's protocol state. With ``audit`` (docs/audit.md) the drone checks every record
    before it applies it (a learner's check; a voter's comes earlier, at append: `audit`'s
    `Auditor.validate` is the Raft node's validator) and refuses a record that does not
    follow from its evidence; ``recompute_cache`` is the simulator's shared memo of the
    evidence checks (`Auditor`) and ``record_memo`` its shared `RecordMemo` (the leader's
    verification and every auditor's re-run of it are then computed once)."""

    def __init__(
        self,
        index: int,
        config: ProtocolConfig,
        keys: Keyring,
        audit: bool = False,
        recompute_cache: dict | None = None,
        censor: tuple[int, int] | None = None,
        record_memo: RecordMemo | None = None,
    ) -> None:
        self.index = index
        self.record_memo = record_memo
        self.config = config
        self.keys = keys
        self.state = Applied()
        self.inbox: dict[int, dict[int, Report]] = {}
        self.last_seen: dict[int, int] = {}  # drone -> last step it reported
        self.gone: set[int] = set()  # drones that left the swarm and have not reported since
        self.decided: set[int] = set()  # steps this drone verified as leader, not yet applied
        self.rejected = 0
        self.refused_applies = 0  # committed records this drone's audit refused to apply
        get_detector(config.detector)
        self.audit = None
        if audit:
            from swarmraft.protocol.audit import CENSOR, Auditor

            self.audit = Auditor(self, recompute_cache, censor or CENSOR)

    # -- every drone ------------------------------------------------------------------------
    def snapshot(self) -> bytes:
        """The replicated state (`Applied`) as bytes, for a Raft snapshot."""
        return self.state.encode()

    def restore(self, data: bytes) -> None:
        """Take the replicated state from a snapshot (the drone's own on restart, or the
        leader's); what the drone holds as leader (reports waiting) is not replicated and stays."""
        self.state = Applied.decode(data)

    def decode(self, data: bytes) -> StepRecord:
        """A record's bytes decoded (through the shared ``record_memo``, if any)."""
        return StepRecord.decode(data) if self.record_memo is None else self.record_memo.decode(data)

    def make_report(
        self,
        step: int,
        position: np.ndarray,
        source: str,
        ranges: np.ndarray,
        innovation: np.ndarray | None,
        drift: np.ndarray | None = None,
        ins: np.ndarray | None = None,
    ) -> Report:
        """The signed report; ``drift`` (M, 3) and ``ins`` (3,) as `Report` describes them."""
        return self.keys.sign(
            Report(
                step,
                self.index,
                np.asarray(position, float),
                source,
                np.asarray(ranges, float),
                innovation,
                drift=None if drift is None else np.asarray(drift, float),
                ins=None if ins is None else np.asarray(ins, float),
            )
        )

    def apply(self, data: bytes) -> StepRecord | None:
        """Apply one committed entry; returns the record if it took effect. An auditing drone
        first checks a record it has not already checked (a learner, or a voter replaying its
        log after a restart) and does not apply one that fails (counted in
        ``refused_applies``)."""
        if self.audit is not None and not self.audit.passed(data):
            rec, reason = self.audit.check(data)
            if reason is not None:
                self.refused_applies += 1
                return None
        else:
            rec = self.decode(data)
        st = self.state
        if rec.step <= st.last_step:
            st.ignored += 1
            return None
        st.skipped.extend(range(max(st.last_step + 1, rec.step - SKIPPED_KEPT), rec.step))
        if len(st.skipped) > SKIPPED_KEPT:
            del st.skipped[: len(st.skipped) - SKIPPED_KEPT]
        st.records[rec.step] = rec
        st.last_step = rec.step
        while len(st.records) > RECORDS_KEPT:
            del st.records[next(iter(st.records))]  # steps arrive in order: the first is the oldest
        return rec

    # -- leader -----------------------------------------------------------------------------
    def receive(self, report: Report) -> bool:
        """Keep a report for its step if its signature verifies and the step is still open
        (not applied). One that comes after the step was verified is kept only until the next
        verification: it is acknowledged (a resend cannot help) and tells `has_all` that its
        drone is alive, but the step is not verified again (`verify_step`)."""
        if report.drone in self.inbox.get(report.step, {}):
            return True  # a resend of a report already verified and kept
        if (
            report.step <= self.state.last_step
            or report.malformed(self.config.n) is not None
            or not self.keys.verify(report)
        ):
            self.rejected += report.step > self.state.last_step
            return False
        self.inbox.setdefault(report.step, {})[report.drone] = report
        self.last_seen[report.drone] = max(self.last_seen.get(report.drone, -1), report.step)
        self.gone.discard(report.drone)
        return True

    def forget(self, drone: int) -> None:
        """Drone ``drone`` (index) left the swarm: `has_all` no longer waits for its reports
        (until it reports again)."""
        self.last_seen.pop(drone, None)
        self.gone.add(drone)

    def has_all(self, step: int, recent: int = 10) -> bool:
        """Whether every drone known to be alive has reported for ``step``, so the leader
        need not wait for the step's deadline: every drone heard from in the last ``recent``
        steps and every drone that reported in the newest applied record, if that record is
        at most ``recent`` steps old (a silent drone does not hold the step up beyond its
        first deadlines). Without such a record the drone does not know who is alive (a new
        leader has heard only from itself: it closed its first step on its own report, the
        others' arriving a millisecond later), and only all n reports close the step early."""
        got = self.inbox.get(step, {})
        if len(got) == self.config.n:
            return True
        last = self.state.records.get(self.state.last_step)
        if last is None or last.step < step - recent:
            return False
        expected = {d for d, k in self.last_seen.items() if k >= step - recent}
        expected |= {int(d) for d in np.flatnonzero(~np.asarray(last.missing, bool))} - self.gone
        return expected <= got.keys()

    def trusted_record(self, step: int) -> StepRecord | None:
        """The newest record at most PRIOR_STEPS before ``step`` whose verdict can be carried
        on (`records.settled`), or None."""
        for k in range(step - 1, max(step - 1 - PRIOR_STEPS, -1), -1):
            rec = self.state.records.get(k)
            if rec is not None and settled(rec):
                return rec
        return None

    def verify_step(self, step: int, term: int) -> StepRecord | None:
        """The leader's verdict for a step from the reports it holds (None if it has none,
        or the step is already decided: applied, or verified here before), with its evidence
        (unsigned: see `seal`). A step is verified once: a report arriving after that (which
        `receive` holds until the next verification) makes no second record of the step."""
        reports = self.inbox.pop(step, {})
        for old in [k for k in self.inbox if k < step]:
            del self.inbox[old]
        if not reports or step <= self.state.last_step or step in self.decided:
            return None
        self.decided = {k for k in self.decided if k > self.state.last_step}
        self.decided.add(step)
        # The last record's positions are a prior (0.1 s old): they resolve the mirror of three
        # anchors, and stand in for a flagged drone whose geometry is insufficient. A record
        # whose verdict is alarm or unidentifiable is not a prior: its flags and positions are
        # what the data could not settle, and carrying them on locks the wrong partition in.
        last = self.trusted_record(step)
        prior = None if last is None else Prior(last.step, carried_positions(last), last.faulty)
        return memo_compute(self.record_memo, step, term, reports, prior, self.config)

    def seal(self, rec: StepRecord) -> bytes:
        """The record signed by this drone as leader, encoded for the log."""
        rec = replace(rec, leader=self.index, signature=b"")
        data = rec.body()
        data += self.keys.sign_bytes(self.index, data)
        if self.audit is not None:
            self.audit.proposed(data, self.decode(data))
        return data


class RecordMemo:
    """The newest ``size`` results of `compute_record`, by a digest of all of its inputs (the
    step, the term, every signed report's bytes, the prior, the configuration). The simulator
    shares one among its drones: `compute_record` is a pure function, so a leader's
    verification and each auditor's re-run of the same inputs are one computation and no
    result changes. A record from the memo is shared: callers must not modify it (a lying
    leader's record is a modified copy, `sim.mission`)."""

    def __init__(self, size: int = 64) -> None:
        self._held: BoundedMemo = BoundedMemo(size)
        self.hits = 0

    def get(self, key: bytes) -> StepRecord | None:
        rec = self._held.get(key)
        self.hits += rec is not None
        return rec

    def decode(self, data: bytes) -> StepRecord:
        """``StepRecord.decode(data)``, one object for the same bytes: in the simulator every
        drone decodes every committed record, and each keeps the newest (`Applied`, the
        audit's priors); shared, 64 drones hold one copy of each record and its n reports
        instead of 64 (385 MB of a 5 s mission of 64 drones were such copies)."""
        key = b"bytes" + record_digest(data)
        rec = self._held.get(key)
        if rec is None:
            rec = StepRecord.decode(data)
            self.put(key, rec)
        return rec

    def put(self, key: bytes, rec: StepRecord) -> None:
        self._held[key] = rec


def record_inputs_key(
    step: int, term: int, reports: dict[int, Report], last: Prior | None, c: ProtocolConfig
) -> bytes:
    """A digest of everything `compute_record` reads."""
    h = hashlib.sha256(struct.pack("<qq", step, term))
    for i in sorted(reports):
        body = reports[i].encode()
        h.update(struct.pack("<qI", i, len(body)) + body)
    if last is None:
        h.update(b"no prior")
    else:
        pos, flags = np.ascontiguousarray(last.positions, "<f8"), np.ascontiguousarray(last.faulty, bool)
        h.update(struct.pack("<q", last.step) + pos.tobytes() + flags.tobytes() + repr(pos.shape).encode())
    h.update(repr(c).encode())
    return h.digest()


def memo_compute(
    memo: RecordMemo | None,
    step: int,
    term: int,
    reports: dict[int, Report],
    last: Prior | None,
    c: ProtocolConfig,
) -> StepRecord:
    """`compute_record`, through ``memo`` when there is one."""
    if memo is None:
        return compute_record(step, term, reports, last, c)
    key = record_inputs_key(step, term, reports, last, c)
    rec = memo.get(key)
    if rec is None:
        rec = compute_record(step, term, reports, last, c)
        memo.put(key, rec)
    return rec


class Prior(NamedTuple):
    """The record a verification carries on: its step, positions and flags."""

    step: int
    positions: np.ndarray
    faulty: np.ndarray


def ins_fallback(
    reports: dict[int, Report],
    present: np.ndarray,
    faulty: np.ndarray,
    positions: np.ndarray,
    before: np.ndarray,
    drift: DriftVerdict,
) -> np.ndarray | None:
    """Never worse than raw GNSS: a verdict whose trusted set disagrees both with the previous committed
    one (``before``) and with the INS tracks (a drone it flags anew that the drag-off test
    neither finds dragged nor suspect, or one it trusts anew that the test does) is not
    committed as it stands: the record is an alarm whose positions (n, 3) are, for each drone
    the previous record trusted, its INS track (its dead reckoning from its last alignment,
    `drift.realigns`, which no spoof moves), and for a drone it flagged the verdict's
    ``positions`` (its track has not been aligned since it was flagged: 45 s of drone-grade
    INS put one 47 m off in the demo mission). None when the verdict stands (or a drone that
    would need it sent no INS track)."""
    changed = present & (faulty != before)
    against = changed & (faulty != (drift.suspect | drift.dragged))
    if not against.any():
        return None
    ins = np.full((len(present), 3), np.nan)
    for i, r in reports.items():
        if r.ins is not None:
            ins[i] = r.ins
    tracked = present & ~before
    if not np.isfinite(ins[tracked]).all():
        return None
    return np.where(tracked[:, None], ins, positions)


def _detect(reported: np.ndarray, ranges: np.ndarray, prior: np.ndarray, idx: np.ndarray, c: ProtocolConfig):  # noqa: ANN202
    """The configured detector's verdict on the drones ``idx``."""
    sub = SnapshotBatch(
        reported[idx][None],
        ranges[np.ix_(idx, idx)][None],
        c.gnss_sigma,
        c.range_sigma,
        prior[idx][None],
        c.prior_sigma,
    )
    return verify_batch(sub, c.detector, check=False, **c.detector_params)


def _off_report(positions: np.ndarray, flagged: np.ndarray, reported: np.ndarray, prior: np.ndarray) -> None:
    """A flagged drone still at its report (nobody placed it) takes its prior, or nan
    without one, in place in ``positions`` (n, 3): a flagged drone is never committed at
    its report."""
    still = flagged & (positions == reported).all(axis=1)
    positions[still] = prior[still]


def compute_record(
    step: int, term: int, reports: dict[int, Report], last: Prior | None, c: ProtocolConfig
) -> StepRecord:
    """The verification of one step: a pure function of the signed reports, the prior and
    the configuration (the leader computes it; every auditor re-runs it on the evidence the
    record carries, `swarmraft.protocol.audit`)."""
    n = c.n
    present = np.zeros(n, dtype=bool)
    present[list(reports)] = True
    reported = np.full((n, 3), np.nan)
    ranges = np.full((n, n), np.nan)
    for i, r in reports.items():
        reported[i] = r.position
        ranges[i] = r.ranges
    np.fill_diagonal(ranges, 0.0)
    prior = last.positions if last is not None else np.full((n, 3), np.nan)
    # Temporal gate: a GNSS fix that moved away from the drone's own INS prediction over
    # the window (a slow drag-off, invisible to one snapshot).
    gate = np.zeros(n, dtype=bool)
    sig = np.maximum([c.innovation_sigma[0], c.innovation_sigma[0], c.innovation_sigma[1]], MIN_SIGMA)
    if c.innovation_gate is not None:
        inn = np.full((n, 3), np.nan)
        for i, r in reports.items():
            if r.innovation is not None:
                inn[i] = r.innovation
        # each row summed as np.sum sums one innovation (a drone without a finite one: no gate)
        gate = np.isfinite(inn).all(axis=1) & (np.sum((inn / sig) ** 2, axis=1) > c.innovation_gate)
    # Drag-off over time (`protocol.drift`): each drone's window innovations, and their mean
    # over the drones not already found (a common slow drag of several drones). A drone found
    # dragged is left out of the snapshot detector, as a drone without a fix (it is placed
    # from the ranges below), so the detector decides among the others.
    drift = None
    dragged = np.zeros(n, dtype=bool)
    if c.drift is not None:
        drift = record_drift(reports, n, present & ~gate, c.drift)
        dragged = present & drift.dragged
        if (present & ~dragged).sum() < 4:  # too few left for a snapshot verdict
            dragged[:] = False
    # The detector sees every present drone; only if it trusts a drone the drag-off test
    # found is it run again without those (the usual case, a drone both flag, keeps the
    # detector's verdict and protection levels)
    idx = np.flatnonzero(present)
    v = _detect(reported, ranges, prior, idx, c)
    if dragged.any() and not v.faulty[0][dragged[idx]].all():
        idx = np.flatnonzero(present & ~dragged)
        v = _detect(reported, ranges, prior, idx, c)
    else:
        dragged[:] = False
    positions = np.full((n, 3), np.nan)
    faulty = np.zeros(n, dtype=bool)
    positions[idx] = v.positions[0]
    faulty[idx] = v.faulty[0]
    hpl, vpl = np.full(n, np.nan), np.full(n, np.nan)
    hpl[idx], vpl[idx] = v.hpl[0], v.vpl[0]
    status = str(v.status[0])
    _off_report(positions, faulty & present, reported, prior)  # the detector could not place them
    det_faulty = faulty.copy()
    gate |= present & (drift.dragged if drift is not None else dragged)
    # Latch: drones flagged in the last record stay suspect until their reports agree with
    # the trusted drones again.
    before = last.faulty if last is not None else np.zeros(n, dtype=bool)
    carry = present & before & ~faulty & ~gate
    faulty |= gate
    if (gate | carry | ~present).any():
        trusted = present & ~faulty & ~carry
        if trusted.sum() >= 4:
            start = np.where(present[:, None], reported, np.nanmean(reported[trusted], axis=0))
            cov = gnss_covariance(*c.gnss_sigma)
            # A drone nobody heard (no report, no range to it: one outside the swarm) is not
            # part of the step: not placed, and its missing geometry makes no record degenerate.
            h = np.flatnonzero(present | np.isfinite(ranges[present]).any(axis=0))
            # started from the detector's positions (the shape every range fixes): from the
            # reports alone, with 4 of 9 drones untrusted, Gauss-Newton ended 40 m off
            # (a drone left out of it starts from the prior: its report is spoofed)
            x0 = np.where(np.isfinite(positions), positions, np.where(np.isfinite(prior), prior, start))
            est_h, st = trusted_estimate(
                start[h][None],
                ranges[np.ix_(h, h)][None],
                trusted[h][None],
                cov,
                c.range_sigma,
                x0=x0[h][None],
                prior=prior[h][None],
                prior_sigma=c.prior_sigma,
            )
            est = np.full((n, 3), np.nan)
            est[h] = est_h[0]
            gate_chi2 = c.innovation_gate or 25.9
            disagree = np.sum((reported - est) ** 2 / np.diag(cov), axis=1) > gate_chi2
            faulty |= carry & disagree
            # the final trusted set differs from the detector's: re-estimate what it
            # would have (for `paper`, whose honest positions are the reports, only the
            # newly flagged drones)
            again = faulty & ~det_faulty & present
            # (a drone the drag-off test left out of the detector changes nothing the detector
            # saw: the others keep its positions and protection levels)
            if c.detector != "paper" and (again & ~dragged).any():
                again = present
            # a drone the detector did not protect (level inf: withheld under the alert limits,
            # or its fault undetectable) stays as the detector left it: its position the prior
            # or nan, its levels inf; re-estimated, it took the ranges' placement with levels
            # nan, and every drone aligned its INS to it (`drift.realigns` refuses only inf)
            again = again & ~(np.isinf(hpl) | np.isinf(vpl))
            positions[again] = est[again]
            found = ~present & (anchor_counts(ranges[None], trusted[None])[0] >= 4)
            positions[found] = est[found]
            # re-estimated here, not by the detector: no protection level for them
            hpl[again | found] = np.nan
            vpl[again | found] = np.nan
            if st[0] != "ok" and status == "ok":
                status = str(st[0])
    # and a drone flagged after the detector (gate, latch) and not placed again (too few
    # trusted drones): a networked new leader alone at its deadline committed its own spoofed
    # report, flagged, 31.5 m off
    _off_report(positions, faulty & present, reported, prior)
    if drift is not None and last is not None:
        fallback = ins_fallback(reports, present, faulty, positions, last.faulty, drift)
        if fallback is not None:
            positions, faulty, status = fallback, (last.faulty | drift.dragged) & present, "alarm"
            hpl[:], vpl[:] = np.nan, np.nan
    return StepRecord(
        step,
        term,
        positions,
        faulty,
        ~present,
        status,
        c.detector,
        reports_digest(list(reports.values())),
        hpl,
        vpl,
        params=canonical_params(c.detector_params),
        prior_step=last.step if last is not None else -1,
        prior_positions=None if last is None else np.asarray(last.positions, float),
        prior_faulty=None if last is None else np.asarray(last.faulty, bool),
        reports=tuple(reports[i] for i in sorted(reports)),
    )
