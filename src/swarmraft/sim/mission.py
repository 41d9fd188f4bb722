"""A SwarmRaft mission in the simulator: drones move, sense, report to the Raft leader, and
apply the verified positions committed through the Raft log, with the network model and the
scenario's faults. Returns a `MissionLog` of raw per-step data; metrics and files are the
experiments layer's job."""

from __future__ import annotations

import gc
import hashlib
import random
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace

import numpy as np

from swarmraft.protocol import Keyring, Report, StepRecord, SwarmDrone
from swarmraft.protocol.audit import KEEP_STEPS
from swarmraft.protocol.committee import initial_committee, next_change
from swarmraft.protocol.drift import DriftVerdict, realign_test, realigns
from swarmraft.protocol.drone import RecordMemo
from swarmraft.protocol.memo import BoundedMemo, record_digest
from swarmraft.raft import ConfState, Entry, EntryKind, Snapshot, SnapshotPolicy, Storage
from swarmraft.raft.types import ConfChangeRefused, NotLeader
from swarmraft.sim.agreement import RecordAgreement
from swarmraft.sim.lying import drops_report, falsify
from swarmraft.sim.network import LinkModel
from swarmraft.sim.runtime import Cluster
from swarmraft.sim.scenario import Scenario
from swarmraft.sim.sensing import ScenarioWorld
from swarmraft.world.ins import InsDrift, ins_sigma
from swarmraft.world.motion import Trajectory


class Idle(str):
    """What a fault says when it found nothing to do (a restart of a drone that is up, no
    leader to crash): an idle fault, not an event, in the simulator and on processes
    (`net.localswarm`)."""


@dataclass
class MissionLog:
    """Per step k (S steps) and drone i (n drones)."""

    scenario: Scenario
    t: np.ndarray  # (S,) s
    truth: np.ndarray  # (S, n, 3)
    gnss: np.ndarray  # (S, n, 3) receiver output (spoofed where spoofed), nan in an outage
    honest_gnss: np.ndarray  # (S, n, 3) what an unspoofed receiver would output
    reported: np.ndarray  # (S, n, 3) what the drone reported, nan if it sent nothing
    ins_alone: np.ndarray  # (S, n, 3) INS dead reckoning from the start, never reset
    ins_aligned: np.ndarray  # (S, n, 3) in a GNSS outage: INS aligned to the truth at its start
    spoofed: np.ndarray  # (S, n) bool
    outage: np.ndarray  # (S, n) bool
    alive: np.ndarray  # (S, n) bool
    verified: np.ndarray  # (S, n, 3) committed positions, nan where missing or skipped
    hpl: np.ndarray  # (S, n) committed horizontal protection levels, m (nan: none)
    vpl: np.ndarray  # (S, n) committed vertical protection levels, m
    faulty: np.ndarray  # (S, n) bool
    missing: np.ndarray  # (S, n) bool
    committed: np.ndarray  # (S,) bool: the step has a record
    status: np.ndarray  # (S,) str
    leader: np.ndarray  # (S,) node id at the deadline, 0 = none
    term: np.ndarray  # (S,)
    latency_ms: np.ndarray  # (S,) step start to first apply of its record
    raft_messages: np.ndarray  # (S,) Raft messages sent during the step
    report_messages: np.ndarray  # (S,) reports sent during the step
    refused_proposals: int = 0  # records a leader refused (its cap on uncommitted bytes)
    # every record each drone applied, checked for identical digests per step (bounded)
    agreement: RecordAgreement = field(default_factory=RecordAgreement)
    events: list[tuple[float, str]] = field(default_factory=list)
    # faults that found nothing to do (a restart of a drone that is up): said, not events
    idle_faults: list[tuple[float, str]] = field(default_factory=list)
    ins_sigma_window: float = 0.0
    detector_params: dict = field(default_factory=dict)  # as used (calibrated thresholds included)
    audit: dict = field(default_factory=dict)  # the audit's counts (`Mission.audit_summary`)
    # (S, n) bool: the drone is in the swarm (joined and not left); None: every drone always
    member: np.ndarray | None = None
    # s before an event whose skipped steps are put down to it too: on processes a step's
    # record can be on its way when a fault lands (a networked run: one step); 0 in the
    # simulator, where a fault cannot reach back
    in_flight_s: float = 0.0

    def in_swarm(self) -> np.ndarray:
        """(S, n) bool: ``member``, or every drone at every step when nobody joins or leaves."""
        return self.member if self.member is not None else np.ones(self.spoofed.shape, bool)

    def first_steps(self, k: int) -> MissionLog:
        """This log cut to its first k steps (and the events up to the last of them): a run
        stopped early is summarised over the steps it flew, not over the ones it never reached."""
        S = len(self.t)
        k = max(0, min(k, S))
        cut = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == S:
                cut[f.name] = v[:k].copy()
        end = float(self.t[k - 1]) if k else -np.inf
        cut["events"] = [(t, what) for t, what in self.events if t <= end + 1e-9]
        cut["idle_faults"] = [(t, what) for t, what in self.idle_faults if t <= end + 1e-9]
        return replace(self, **cut)


def resident_zeros(shape: int | tuple[int, ...], dtype: type) -> np.ndarray:
    """Zeros with every page written now: a large ``np.zeros`` maps untouched zero pages that
    only take memory as the run writes its steps, so a long mission's memory would creep up
    by its per-step arrays; written up front, they are all in the first measurement and the
    mission's memory stays flat after it (bench_endurance.py)."""
    return np.full(shape, 0, dtype)


def world_log(w: ScenarioWorld) -> MissionLog:
    """A mission log with what the world alone determines filled in (time, truth, GNSS,
    spoofing, outages, INS alone); what the swarm did (reports, records, leaders, messages)
    is left for its runner to fill: nan, False, 0 or "skipped"."""
    sc, traj = w.sc, w.traj
    n, S = sc.drones, sc.steps + 1
    nan3 = np.full((S, n, 3), np.nan)
    log = MissionLog(
        scenario=sc,
        t=traj.t[:S],
        truth=traj.positions[:S],
        gnss=nan3.copy(),
        honest_gnss=nan3.copy(),
        reported=nan3.copy(),
        ins_alone=nan3.copy(),
        ins_aligned=nan3.copy(),
        spoofed=resident_zeros((S, n), bool),
        outage=resident_zeros((S, n), bool),
        alive=resident_zeros((S, n), bool),
        leader=resident_zeros(S, int),
        term=resident_zeros(S, int),
        **no_records(S, n),
        raft_messages=resident_zeros(S, int),
        report_messages=resident_zeros(S, int),
        ins_sigma_window=ins_sigma(w.grade, sc.protocol.innovation_window_s),
    )
    truth = traj.positions[:S]
    log.gnss[:] = w.gnss_output(slice(0, S))
    log.honest_gnss[:] = truth + w.gnss_err[:S]
    log.spoofed[:], log.outage[:] = w.spoofed[:S], ~w.has_fix[:S]
    log.ins_alone[:] = truth + w.drift.error(np.broadcast_to(traj.t[:S, None], (S, n)))
    return log


def ins_aligned_in_outages(log: MissionLog, drift: InsDrift) -> None:
    """Fill ``log.ins_aligned``, the baseline a user means by "INS alone" in an outage: each
    drone's INS aligned to its true position at the step its GNSS was lost, then dead
    reckoning (a perfect alignment: the most this baseline can be given)."""
    for i in range(log.scenario.drones):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], log.outage[:, i].astype(int), [0]])))
        own = InsDrift(drift.accel[i : i + 1], drift.gyro[i : i + 1])
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            log.ins_aligned[a:b, i] = log.truth[a:b, i] + own.error(log.t[a:b] - log.t[a])


#: When a mission's drones snapshot their replicated state and compact their Raft logs: every
#: 1000 applied entries (100 s at 10 Hz: a log never holds more than 1500 entries, about 0.6 MB
#: for 9 drones), keeping 500 below the snapshot (50 s: a drone down for less catches up with
#: appends, as it always did; one down longer gets the leader's snapshot).
MISSION_SNAPSHOTS = SnapshotPolicy(every=1000, keep=500)

#: How often (in steps) the mission closes the steps no drone can apply any more
#: (`RecordAgreement.prune`): between two, at most this many more steps are held.
AGREEMENT_PRUNE_STEPS = 100

#: ``on_step(log, k)``: called once step k's interval has passed (its deadline too), with a
#: live copy of the mission log (see `Mission`); it must only read.
StepHook = Callable[[MissionLog, int], None]


class Mission:
    """A mission in the simulator. With ``on_step``, a live copy of the log is kept beside the
    result: it shares every array the run fills as it goes (reports, liveness, leaders, terms,
    messages, events) and holds its own copy of the record arrays (verified positions, flags,
    levels, status, latency), filled when a record is first applied, so the hook sees records
    as they commit. The results are those of a run without the hook (the hook's log is never
    read back).

    ``snapshots``: when drones snapshot and compact their logs (`MISSION_SNAPSHOTS`; None:
    never); ``check_invariants``: the Raft invariant checker, on by default (it keeps a hash
    of every entry: long runs that measure memory turn it off); ``storage(i)``: drone i's Raft
    storage (in memory when None)."""

    def __init__(
        self,
        sc: Scenario,
        on_step: StepHook | None = None,
        *,
        snapshots: SnapshotPolicy | None = MISSION_SNAPSHOTS,
        check_invariants: bool = True,
        storage: Callable[[int], Storage] | None = None,
    ) -> None:
        self.sc = sc
        self.on_step = on_step
        n = sc.drones
        # Every random draw of the world, in the order the mission has always made them
        # (shared with the networked runtime: sim.sensing).
        self.world = w = ScenarioWorld.build(sc)
        self.traj: Trajectory = w.traj
        self.gnss_err, self.grade, self.drift, self.timeline, self.uwb = (
            w.gnss_err,
            w.grade,
            w.drift,
            w.timeline,
            w.uwb,
        )
        link = LinkModel.of(sc.network)
        committee = sc.protocol.committee
        # who is in the swarm now: every drone but those that join later (`sc.joiners`); a
        # drone that leaves is taken out at once and is `_leaving` until its removal from the
        # Raft configuration is committed, when its node shuts down for good (`left`)
        self.dynamic = sc.dynamic
        self.swarm: set[int] = set(range(1, n + 1)) - sc.joiners
        self._leaving: set[int] = set()
        self.left: set[int] = set()
        if committee:
            conf = initial_committee(sorted(self.swarm), committee)
        elif sc.joiners:  # every drone of the swarm votes; the others are not members yet
            conf = ConfState(tuple(sorted(self.swarm)))
        else:
            conf = None
        self.auditing = sc.protocol.audit
        self.cluster = Cluster(
            n,
            seed=sc.seed,
            tick_ms=sc.raft.tick_ms,
            election_tick=sc.raft.election_tick,
            heartbeat_tick=sc.raft.heartbeat_tick,
            network=link,
            on_apply=self._on_apply,
            raft_options={"voters": conf.voters, "learners": conf.learners} if conf else None,
            check_invariants=check_invariants,
            snapshots=snapshots,
            app_snapshot=lambda node: self.drones[node - 1].snapshot(),
            app_restore=lambda node, snap: self.drones[node - 1].restore(snap.data),
            storage=storage,
            validate=self._validate if self.auditing else None,
            validate_snapshot=self._validate_snapshot if self.auditing else None,
        )
        for j in sorted(sc.joiners):  # not started before it joins (its storage is empty)
            self.cluster.crash(j)
        # the committee's leader: when it last heard from each drone (ms), and since when it leads
        self._heard: dict[int, float] = {}
        self._heard_by: int | None = None
        self.window_steps = w.window_steps
        self.innovation_sigma = w.innovation_sigma
        self.calibration = w.calibration
        self.pcfg = w.protocol
        self.keys = Keyring.generate(n, w.rng_keys)
        # the evidence checks depend only on a record's bytes: drones share them (docs/audit.md);
        # the reports and records of the last KEEP_STEPS steps or so (older ones are checked again)
        self._audit_cache: dict = BoundedMemo(KEEP_STEPS * (n + 2))
        # and a record's verification is a pure function of its inputs: the leader's and the
        # auditors' re-runs of it are one computation (protocol.drone.RecordMemo)
        self._record_memo = RecordMemo()
        self.drones = [self._new_drone(i) for i in range(n)]
        # the report fan-out's own generator: it must not shift the draws of the rest of the run
        self._fan_rng = random.Random(sc.seed * 7_919 + 17)
        self.liar: int | None = None  # the compromised drone (node id), lying-leader fault
        self._lie = next((f for f in sc.fault if f.kind == "lying-leader"), None)
        self._lying = False
        self.falsified: dict[bytes, int] = {}  # digest of a falsified record -> its step
        self._realign_tests = BoundedMemo(64)  # `_realign_test` by record digest
        self.first_lie_s: float | None = None
        self.refusals: list[tuple[float, int, int, str]] = []  # (s, node, step, reason)
        self.suspicions: list[tuple[float, int, str]] = []  # (s, node, why)
        # INS state: the last position it was aligned to (time, position); it then integrates
        # the true motion plus its drift.
        self.ins_base_t = np.zeros(n)
        self.ins_base_pos = self.traj.positions[0].copy()
        self.log = world_log(w)
        if self.dynamic:
            self.log.member = np.zeros(self.log.spoofed.shape, bool)
        self.live = _live_copy(self.log) if on_step is not None else None
        self.sent_to: dict[int, int | None] = {}

    def _new_drone(self, i: int) -> SwarmDrone:
        sc = self.sc
        return SwarmDrone(
            i,
            self.pcfg,
            self.keys,
            audit=self.auditing,
            recompute_cache=self._audit_cache,
            censor=(sc.protocol.censor_k, sc.protocol.censor_m),
            record_memo=self._record_memo if self.auditing else None,
        )

    # -- sensing and reporting --------------------------------------------------------------
    def _ins(self, k: int) -> np.ndarray:
        """Each drone's INS estimate at step k: aligned at its base, then dead reckoning."""
        return self.world.ins_estimate(k, self.ins_base_t, self.ins_base_pos)

    def _step(self, k: int) -> None:
        sc, n, log = self.sc, self.sc.drones, self.log
        w = self.world
        fix, has_fix = w.fix[k], w.has_fix[k]
        ins = self._ins(k)
        ranges = w.measured_ranges(k, ins)
        if self.dynamic:
            # a drone outside the swarm takes no part: no report, and no two-way ranging with
            # it (its radio does not answer), so nobody places it from ranges either
            out = [i for i in range(n) if i + 1 not in self.swarm]
            ranges[out, :] = np.nan
            ranges[:, out] = np.nan
            log.member[k] = [i + 1 in self.swarm for i in range(n)]
        self._rows[k] = ranges
        if self.auditing:
            for d in self.drones:
                d.audit.at_step(k)  # every drone's clock, alive or not (a restart keeps it)
        for i in range(n):
            node = i + 1
            alive = self.cluster.alive(node)
            log.alive[k, i] = alive
            if not alive or self.cluster.paused(node):  # a paused process sends nothing
                continue
            if node not in self.swarm:
                continue
            pos, source = (fix[i], "gnss") if has_fix[i] else (ins[i], "ins")
            innov = self._innovation(k, i) if has_fix[i] else None
            drift = w.innovations(k, i) if has_fix[i] else None
            report = self.drones[i].make_report(k, pos, source, ranges[i], innov, drift, ins[i])
            log.reported[k, i] = pos
            self._send_report(node, report)
            if self.auditing:
                self._fan_out(node, report)
        dl = sc.protocol.deadline_ms
        self.cluster.loop.after(dl / 2, self._retry, k)
        self.cluster.loop.after(dl, self._deadline, k)

    def _innovation(self, k: int, i: int) -> np.ndarray | None:
        return self.world.innovation(k, i)

    def _send_report(self, node: int, report: Report) -> None:
        lead = self.cluster.nodes[node].lead if self.cluster.nodes.get(node) else None
        self.sent_to[node] = lead
        if lead is None:
            return
        self.log.report_messages[report.step] += 1
        if lead == node:
            self._receive(node, report.encode())
        else:
            self.cluster.send_app(node, lead, self._receive, report.encode())

    def _fan_out(self, node: int, report: Report) -> None:
        """The report to every voter (in the sender's view of the configuration) but itself
        and the leader it went to (the audit's censorship check: only voters can depose a
        leader; with a committee, learners get no copy), on the fan-out's own generator. The
        sender does not hold its own report for the check (as the drone process does): it
        holds it whether or not it reached a leader (a learner that knows no leader yet sends
        it nowhere), and the other voters hold it from this copy."""
        data = report.encode()
        for j in self.cluster.nodes[node].conf_state.voters:
            if j != node and j != self.sent_to.get(node) and j in self.swarm:
                self.cluster.send_app(node, j, self._fanned, data, rng=self._fan_rng)

    def _fanned(self, node: int, data: bytes) -> None:
        self.drones[node - 1].audit.note_report_bytes(data)

    def _retry(self, k: int) -> None:
        """Resend step k's report if the leader did not acknowledge it, or if the leader
        changed (or became known) since it was sent."""
        for i in range(self.sc.drones):
            node = i + 1
            rn = self.cluster.nodes.get(node)
            if rn is None or rn.lead is None or k not in self._rows or self.cluster.paused(node):
                continue
            if not np.isfinite(self.log.reported[k, i]).all():
                continue
            if (node, k) in self._acked and rn.lead == self.sent_to.get(node):
                continue
            source = "gnss" if not self.log.outage[k, i] else "ins"
            innov = self._innovation(k, i) if source == "gnss" else None
            drift = self.world.innovations(k, i) if source == "gnss" else None
            ins = self._ins(k)[i]
            report = self.drones[i].make_report(
                k, self.log.reported[k, i], source, self._rows[k][i], innov, drift, ins
            )
            self._send_report(node, report)

    def _receive(self, node: int, data: bytes) -> None:
        rep = Report.decode(data)
        drone = self.drones[node - 1]
        lie = self._lie
        if self._lying and node == self.liar and drops_report(lie, rep):
            return  # the lying leader drops the drone's reports
        if drone.audit is not None and rep.drone != node - 1:
            # not its own (a drone holds that whoever leads: the drone process's rule; held,
            # a leader that stepped down counted its own in-flight reports against the next)
            drone.audit.note_report(rep)
        accepted = drone.receive(rep)
        if accepted:
            sender = rep.drone + 1
            if node == self._heard_by:
                self._heard[sender] = self.cluster.now
            if sender == node:
                self._acked.add((sender, rep.step))
            else:
                self.cluster.send_app(node, sender, self._ack, rep.step)
        if accepted and drone.has_all(rep.step) and self.cluster.leader() == node:
            self._propose(node, rep.step)

    def _ack(self, node: int, step: int) -> None:
        self._acked.add((node, step))

    def _deadline(self, k: int) -> None:
        if self.auditing:
            for i, d in enumerate(self.drones):
                d.audit.close_step(k)  # a record of step k that came before is judged now
                self._suspect(i + 1)
        lead = self.cluster.leader()
        self.log.leader[k] = lead or 0
        if lead is None:
            return
        self.log.term[k] = self.cluster.nodes[lead].term
        self._propose(lead, k)
        if self.sc.protocol.committee or self.dynamic:
            self._committee(lead)

    def _committee(self, lead: int) -> None:
        """The leader keeps the committee whole (`protocol.committee`) and the configuration
        in step with the swarm (drones joining and leaving): it notes whom it heard from (Raft
        answers in the last check-quorum period, or a report) and proposes the one change the
        rules ask for, if any (a change still pending is refused: retried next step). A
        leader that leaves hands leadership over first; a leaving drone whose removal the
        leader has committed shuts down."""
        c, now = self.cluster, self.cluster.now
        node = c.nodes[lead]
        assert node is not None
        if self._heard_by != lead:  # a new leader starts with everyone just heard
            self._heard, self._heard_by = dict.fromkeys(c.ids, now), lead
        for i, pr in node.prs.items():
            if pr.recent_active:  # answered in the current check-quorum period
                self._heard[i] = now
        conf, last, gap = node.conf_state, node.log.last_index(), node.config.promote_gap
        if self._leaving:
            self._shut_down_removed(node)
            if lead in self._leaving:
                # it hands over to a live voter that stays; with none yet (a committee of one)
                # the rule below promotes a learner first
                if node.lead_transferee is not None:
                    return
                if any(v != lead and v not in self._leaving and c.alive(v) for v in conf.voters):
                    self.log.events.append((now / 1000, self._transfer(None, leaving=True)))
                    return
        caught_up = [lr for lr in conf.learners if lr in node.prs and node.prs[lr].match + gap >= last]
        silent = {i: (now - t) / 1000 for i, t in self._heard.items()}
        pc = self.sc.protocol
        swarm = sorted(self.swarm) if self.dynamic else c.ids
        size, dead_s = pc.committee or None, pc.committee_dead_after_s
        cc = next_change(conf, lead, swarm, silent, caught_up, size, dead_s, self._leaving)
        if cc is None:
            return
        try:
            c.propose_conf_change(cc, via=lead)
        except (ConfChangeRefused, NotLeader):
            return
        what = "committee" if pc.committee else "membership"
        self.log.events.append((now / 1000, f"{what}: {cc.type.value} drone {cc.node}"))

    def _shut_down_removed(self, node) -> None:  # noqa: ANN001 (the leader's RaftNode)
        """Leaving drones that are no longer in the leader's committed configuration go: their
        node stops for good (as etcd's member stops once it is removed)."""
        committed = node.log.committed >= node.confs.last_index
        for d in sorted(self._leaving):
            if committed and d not in node.conf_state.members:
                self._leaving.discard(d)
                self.left.add(d)
                if self.cluster.alive(d):
                    self.cluster.crash(d)
                self.log.events.append((self.cluster.now / 1000, f"drone {d} left: its removal is committed"))

    def _propose(self, lead: int, k: int) -> None:
        node = self.cluster.nodes[lead]
        drone = self.drones[lead - 1]
        rec = drone.verify_step(k, node.term)
        if rec is None:
            return
        if not self.auditing:
            self.cluster.propose(rec.encode(), via=lead)
            return
        if self._lying and self.liar is None:
            self.liar = lead  # the fault takes the first leader after its time
        lie = falsify(rec, self._lie) if self._lying and lead == self.liar else None
        data = drone.seal(lie if lie is not None else rec)
        if lie is not None:
            self.falsified[hashlib.sha256(data).digest()] = k
            if self.first_lie_s is None:
                self.first_lie_s = self.cluster.now / 1000
                self.log.events.append((self.first_lie_s, f"leader {lead} proposed a falsified record"))
        self.cluster.propose(data, via=lead)

    def _validate(self, node: int, entry: Entry) -> bool:
        """Node's validator (its drone's audit); a refusal and a censorship finding are logged,
        and a censorship finding deposes the leader (Raft deposes it on a refusal)."""
        audit = self.drones[node - 1].audit
        n_refused = len(audit.refused)
        ok = audit.validate(entry)
        now = self.cluster.now / 1000
        if not ok:
            step, reason = audit.refused[n_refused]
            self.refusals.append((now, node, step, reason))
        self._suspect(node)
        return ok

    def _suspect(self, node: int) -> None:
        """A censorship finding of node's audit (after a record or a step's close) is logged
        and deposes the leader, once the event at hand is done (`RaftNode.depose`), unless
        the term moved on."""
        audit = self.drones[node - 1].audit
        term = audit.omission_term
        why = audit.take_suspicion()
        if why is not None:
            self.suspicions.append((self.cluster.now / 1000, node, why))
            self.cluster.loop.after(0, self._depose, node, term)

    def _validate_snapshot(self, node: int, snap: Snapshot) -> bool:
        """Node's validator of a leader's snapshot (its drone's audit); a refusal is logged."""
        audit = self.drones[node - 1].audit
        n_refused = len(audit.refused)
        ok = audit.validate_snapshot(snap)
        if not ok:
            step, reason = audit.refused[n_refused]
            self.refusals.append((self.cluster.now / 1000, node, step, reason))
        return ok

    def _depose(self, node: int, term: int) -> None:
        rn = self.cluster.nodes.get(node)
        if rn is not None:
            self.cluster.depose(node, rn.lead, term)

    def audit_summary(self) -> dict:
        """Counts of the audit: refused entries (at append, by honest drones), refused applies,
        censorship findings, falsified records proposed."""
        honest = [i for i in range(self.sc.drones) if i + 1 != self.liar]
        return {
            "refused_entries": sum(1 for _, node, _, _ in self.refusals if node != self.liar),
            "refused_applies": sum(self.drones[i].refused_applies for i in honest),
            "censorship_findings": sum(1 for _, node, _ in self.suspicions if node != self.liar),
            "falsified_proposed": len(self.falsified),
            "liar": self.liar,
            "first_lie_s": self.first_lie_s,
            "first_refusal_s": next((t for t, node, _, _ in self.refusals if node != self.liar), None),
            "first_finding_s": next((t for t, node, _ in self.suspicions if node != self.liar), None),
        }

    # -- applying ---------------------------------------------------------------------------
    def _on_apply(self, node: int, entry: Entry) -> None:
        if entry.kind != EntryKind.NORMAL:  # a no-op, or a membership change
            return
        i = node - 1
        if self.falsified and node != self.liar and hashlib.sha256(entry.data).digest() in self.falsified:
            now = self.cluster.now
            raise AssertionError(f"invariant: honest drone {node} applies a falsified record ({now} ms)")
        rec = self.drones[i].apply(entry.data)
        if rec is None:
            return
        self.log.agreement.note(node, rec.step, rec.digest, entry.index)
        now = self.cluster.now
        # A step's record goes into the log when it is first applied (every node applies the
        # same: tests check digests), with its latency; nothing per step is kept besides.
        if rec.step < len(self.log.t) and not self.log.committed[rec.step]:
            latency = now - rec.step * self.sc.dt_s * 1000
            _note_record(self.log, rec, latency)
            if self.live is not None:
                _note_record(self.live, rec, latency)
        # The drone takes its verified position: its INS track is aligned to it while the record
        # trusts it and the swarm is not being pulled (`protocol.drift.realigns`). Not when
        # replaying old records after a restart.
        k_now = min(int(now / 1000 / self.sc.dt_s), self.sc.steps)
        test = lambda: self._realign_test(entry.data, rec)  # noqa: E731 (run only if needed)
        if rec.step >= k_now - 5 and realigns(rec, i, self.pcfg.drift, test):
            self.ins_base_t[i] = self.traj.t[rec.step]
            self.ins_base_pos[i] = rec.positions[i]

    def _realign_test(self, data: bytes, rec: StepRecord) -> DriftVerdict:
        """`drift.realign_test` of the record in ``data``, once per record (every drone that
        applies it would run the same test on the same bytes: 8 % of a 17-drone mission)."""
        key = record_digest(data)
        test = self._realign_tests.get(key)
        if test is None:
            test = self._realign_tests[key] = realign_test(rec, self.pcfg.drift)
        return test

    def _reread_log(self, node: int) -> None:
        """A restarted drone's audit reads its own log back (`Auditor.remember`): the records
        it held as priors before the crash (a prior it does not hold is refused)."""
        audit = self.drones[node - 1].audit
        if audit is None:
            return
        st = self.cluster.storage[node]
        for e in st.entries(st.first_index(), st.last_index() + 1):
            if e.kind == EntryKind.NORMAL:
                audit.remember(e.data)

    # -- faults -----------------------------------------------------------------------------
    def _fault(self, f) -> None:  # noqa: ANN001 (a FaultConfig)
        """Apply fault ``f`` and log what it did: an event, or, for a fault that found nothing
        to do (`Idle`), an idle fault, which excuses no skipped step
        (`experiments.mission.skipped_causes`)."""
        what = self._act(f)
        done = self.log.idle_faults if isinstance(what, Idle) else self.log.events
        done.append((self.cluster.now / 1000, str(what)))

    def _act(self, f) -> str:  # noqa: ANN001 (a FaultConfig)
        """Fault ``f`` applied; what it did (an `Idle` text where it found nothing to do)."""
        c = self.cluster
        if f.kind == "crash":
            if not c.alive(f.drone):
                return Idle(f"crash: drone {f.drone} is down already, nothing done")
            c.crash(f.drone)
            self.drones[f.drone - 1] = self._new_drone(f.drone - 1)  # volatile state lost
            return f"drone {f.drone} crashed"
        elif f.kind == "crash-leader":
            lead = c.leader()
            if lead is None:
                return Idle("crash-leader: no leader, nothing crashed")
            c.crash(lead)
            self.drones[lead - 1] = self._new_drone(lead - 1)
            return f"leader {lead} crashed"
        elif f.kind == "transfer-leader":
            return self._transfer(f.drone)
        elif f.kind == "restart":
            if c.alive(f.drone):
                return Idle(f"restart: drone {f.drone} is up, nothing done")
            c.restart(f.drone)
            self._reread_log(f.drone)
            return f"drone {f.drone} restarted"
        elif f.kind == "pause":
            who = [f.drone] if f.drone is not None else list(c.ids)
            for d in who:
                c.pause(d, f.for_s * 1000)
            name = f"drone {f.drone}" if f.drone is not None else "every drone"
            return f"{name} paused for {f.for_s:g} s"
        elif f.kind == "partition":
            c.partition(*f.groups)
            return f"partition {f.groups}"
        elif f.kind == "lying-leader":
            self._lying = True
            self.liar = c.leader()
            who = f"leader {self.liar}" if self.liar is not None else "the next leader"
            return f"{who} compromised: lies ({f.mode} drone {f.drone})"
        elif f.kind == "join":
            if not c.alive(f.drone):
                c.restart(f.drone)  # a new node, with empty storage: not a member yet
            self.swarm.add(f.drone)
            self._heard[f.drone] = c.now  # it announces itself: heard now
            return f"drone {f.drone} joins the swarm"
        elif f.kind == "leave":
            self.swarm.discard(f.drone)
            self._leaving.add(f.drone)
            for d in self.drones:  # the leader no longer waits for its reports
                d.forget(f.drone - 1)
            return f"drone {f.drone} leaves the swarm"
        elif f.kind == "heal":
            c.heal()
            return "network healed"
        else:
            c.set_loss(f.value)
            return f"loss set to {f.value:.0%}"

    def _transfer(self, to: int | None, leaving: bool = False) -> str:
        """The leader hands over to drone ``to``, or (None) to the voter whose log is the most
        complete (highest match index; the lowest id on a tie) and that stays in the swarm.
        Returns the event's text (``leaving``: the leader leaves the swarm), an `Idle` one
        saying why where nothing was handed over."""
        c = self.cluster
        lead = c.leader()
        if lead is None:
            return Idle("transfer-leader: no leader, nothing handed over")
        node = c.nodes[lead]
        assert node is not None
        if to is None:
            others = [v for v in node.conf_state.voters if v != lead and v not in self._leaving]
            if leaving:  # hand over to a drone that can take it
                others = [v for v in others if c.alive(v)]
            if not others:
                return Idle(f"transfer-leader: leader {lead} is the only voter")
            to = max(others, key=lambda v: (node.prs[v].match, -v))
        if to == lead:
            return Idle(f"transfer-leader: drone {to} leads already")
        if not c.alive(to):
            return Idle(f"transfer-leader: drone {to} is down, leader {lead} keeps leading")
        c.transfer_leader(to)
        return f"leader {lead} hands over to drone {to}" + (" (it leaves the swarm)" if leaving else "")

    # -- running ----------------------------------------------------------------------------
    def run(self, progress: Callable[[int], None] | None = None) -> MissionLog:
        sc, c = self.sc, self.cluster
        dt_ms = sc.dt_s * 1000
        self._rows: dict[int, np.ndarray] = {}
        self._acked: set[tuple[int, int]] = set()
        for f in sc.fault:
            c.loop.at(f.at_s * 1000, self._fault, f)
        raft0, steps = 0, sc.steps
        for k in range(steps + 1):
            c.run(max(0.0, k * dt_ms - c.now))
            if k > 0 and self.on_step is not None:
                self.on_step(self.live, k - 1)
            self._step_with_history(k)
            total = sum(c.sent.values())
            if k > 0:
                self.log.raft_messages[k - 1] = total - raft0
            raft0 = total
            if progress:
                progress(1)
        c.run(dt_ms)
        self.log.raft_messages[steps] = sum(c.sent.values()) - raft0
        self.log.refused_proposals = c.refused  # each such step is skipped unless proposed again
        if self.on_step is not None:
            self.on_step(self.live, steps)
        c.run(2 * sc.protocol.deadline_ms + 500)  # let the last records commit (not counted)
        return self._finish()

    def _step_with_history(self, k: int) -> None:
        if k % AGREEMENT_PRUNE_STEPS == 0:
            self.log.agreement.prune(self._can_apply())
        self._rows = {s: r for s, r in self._rows.items() if s >= k - 2}
        # a step's retry needs its ranges row: acknowledgements of older steps are not read
        self._acked = {a for a in self._acked if a[1] >= k - 2}
        self._step(k)

    def _can_apply(self) -> Callable[[int, int], bool]:
        """Whether some drone can still apply a record of a step from the entry at an index:
        a live drone any record above its last step, and after a crash (which may come at any
        time) any entry of its storage above its snapshot; a drone that is down, an entry
        above its snapshot that its storage holds, or that a live drone's storage holds (to
        be sent when it is back). An entry no storage holds reaches nobody (a restarted or
        lagging drone gets a snapshot instead)."""
        c = self.cluster
        live: list[tuple[int, int]] = []  # (last step applied, snapshot index)
        down: list[tuple[int, int]] = []  # (snapshot index, last index held)
        for node, st in c.storage.items():
            if c.alive(node):
                live.append((self.drones[node - 1].state.last_step, st.snapshot().index))
            else:
                down.append((st.snapshot().index, st.last_index()))
        live_first = min((c.storage[i].first_index() for i in c.alive_ids()), default=float("inf"))

        def can_apply(step: int, index: int) -> bool:
            return any(step > last or index > snap for last, snap in live) or any(
                snap < index and (index <= last or index >= live_first) for snap, last in down
            )

        return can_apply

    def _finish(self) -> MissionLog:
        log = self.log
        log.status = log.status.astype(str)
        ins_aligned_in_outages(log, self.drift)
        log.detector_params = dict(self.pcfg.detector_params)
        if self.auditing:
            log.audit = self.audit_summary()
        return log


def _live_copy(log: MissionLog) -> MissionLog:
    """A log sharing ``log``'s arrays but for its own (empty) record arrays."""
    n = log.scenario.drones
    S = len(log.t)
    return replace(log, **no_records(S, n))


def no_records(S: int, n: int) -> dict[str, np.ndarray]:
    """A log's record arrays before any record: nan positions, levels and latencies, no
    flags, every step skipped."""
    return {
        "verified": np.full((S, n, 3), np.nan),
        "hpl": np.full((S, n), np.nan),
        "vpl": np.full((S, n), np.nan),
        "faulty": resident_zeros((S, n), bool),
        "missing": resident_zeros((S, n), bool),
        "committed": resident_zeros(S, bool),
        "status": np.full(S, "skipped", dtype=object),
        "latency_ms": np.full(S, np.nan),
    }


def _note_record(log: MissionLog, rec: StepRecord, latency_ms: float) -> None:
    """Step ``rec.step`` of ``log`` takes the record's positions, levels, flags and status."""
    k = rec.step
    log.committed[k] = True
    log.verified[k] = rec.positions
    if rec.hpl is not None:
        log.hpl[k], log.vpl[k] = rec.hpl, rec.vpl
    log.faulty[k] = rec.faulty
    log.missing[k] = rec.missing
    log.status[k] = rec.status
    log.latency_ms[k] = latency_ms


def run_mission(
    sc: Scenario, progress: Callable[[int], None] | None = None, on_step: StepHook | None = None
) -> MissionLog:
    """Run a mission; ``on_step(log, k)`` (optional) sees each step once its interval has
    passed, without changing the results.

    The finished mission is freed before the log is returned: its Raft nodes, drones and
    world reference one another (callbacks), so only a full pass of the cyclic collector
    frees them, and a mission's many long-lived objects put that pass off: its records and
    ranges stayed in memory under the outputs and figures made from the log."""
    mission = Mission(sc, on_step)
    log = mission.run(progress)
    del mission
    gc.collect()
    return log
