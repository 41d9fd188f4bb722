"""The audit of a leader's records (issue 14, docs/audit.md): a record that does not follow
from its signed evidence is refused, a refusing voter deposes its leader, a censoring leader is
found, honest leaders are never accused, and no honest drone applies a falsified record."""

from __future__ import annotations

import random
from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from pydantic import ValidationError

from swarmraft.protocol import Keyring, StepRecord, SwarmDrone
from swarmraft.protocol.audit import FUTURE_STEPS, POSITION_TOL_M
from swarmraft.protocol.drone import Prior, compute_record
from swarmraft.protocol.records import well_formed
from swarmraft.raft import Entry, EntryKind, MemoryStorage, Message, MsgType, RaftConfig, RaftNode
from swarmraft.sim.mission import run_mission
from swarmraft.sim.runtime import Cluster
from swarmraft.sim.scenario import Scenario
from swarmraft.sim.sensing import ScenarioWorld

N = 9


def leader_run(steps: int, late: int | None = None) -> tuple[ScenarioWorld, Keyring, SwarmDrone, list[bytes]]:
    """A leader's sealed records of ``steps`` steps of a 9-drone world (drone 3 spoofed by
    30 m from 0.5 s), each applied as it is made, but that of step ``late``, applied after
    the next one was verified (committed a step late: the next record's prior is older)."""
    sc = Scenario(
        name="t",
        seed=3,
        drones=N,
        duration_s=max(2.0, 0.1 * steps + 0.5),
        spoof=[{"kind": "jump", "drones": [3], "start_s": 0.5, "magnitude": 30.0}],
    )
    w = ScenarioWorld.build(sc)
    keys = Keyring.generate(N, np.random.default_rng(0))
    leader = SwarmDrone(0, w.protocol, keys, audit=True)
    base_t, base_pos = np.zeros(N), w.traj.positions[0].copy()
    out, pending = [], None
    for k in range(steps):
        ins = w.ins_estimate(k, base_t, base_pos)
        ranges = w.measured_ranges(k, ins)
        for i in range(N):
            r = SwarmDrone(i, w.protocol, keys).make_report(
                k, w.fix[k, i], "gnss", ranges[i], w.innovation(k, i)
            )
            leader.receive(r)
        data = leader.seal(leader.verify_step(k, 1))
        out.append(data)
        if k == late:
            pending = data
            continue
        if pending is not None:
            leader.apply(pending)
            pending = None
        leader.apply(data)
    return w, keys, leader, out


@cache
def honest_chain(steps: int = 14) -> tuple[ScenarioWorld, Keyring, list[bytes]]:
    """A leader's sealed records of ``steps`` steps (`leader_run`), each with the previous
    one as its prior."""
    w, keys, _, out = leader_run(steps)
    return w, keys, out


def voter_through(k: int, own_keys: bool = False) -> tuple[SwarmDrone, list[bytes], Keyring]:
    """A voter that checked and applied the chain's records before step k (``own_keys``: with
    a Keyring of its own, so no signature check made by another drone is remembered)."""
    w, keys, chain = honest_chain()
    v = SwarmDrone(1, w.protocol, Keyring(keys.private, keys.public) if own_keys else keys, audit=True)
    for step, data in enumerate(chain[:k]):
        v.audit.at_step(step)
        rec, reason = v.audit.check(data, 1)
        assert reason is None, reason
        v.apply(data)
    v.audit.at_step(k)  # its clock at step k, whose record comes next
    return v, chain, keys


def resealed(rec: StepRecord, keys: Keyring) -> bytes:
    """``rec`` signed again by its leader (a lying leader signs its lies)."""
    body = replace(rec, signature=b"").body()
    return body + keys.sign_bytes(rec.leader, body)


def test_honest_records_pass_and_round_trip() -> None:
    v, chain, _ = voter_through(12)
    rec = StepRecord.decode(chain[12])
    assert rec.encode() == chain[12]  # deterministic encoding
    assert rec.prior_step == 11 and len(rec.reports) == N and rec.faulty[2]
    assert v.audit.check(chain[12], 1)[1] is None


@pytest.mark.parametrize(
    "lie",
    [
        "move-1cm",
        "move-10m",
        "clear",
        "accuse",
        "status",
        "report-forged",
        "report-dropped",
        "leader-signature",
        "params",
        "prior-forged",
        "prior-old",
        "term",
    ],
)
def test_falsified_records_are_refused(lie: str) -> None:
    v, chain, keys = voter_through(12)
    rec = StepRecord.decode(chain[12])
    term = 1
    if lie.startswith("move"):
        pos = rec.positions.copy()
        pos[4, 0] += 0.01 if lie == "move-1cm" else 10.0
        rec = replace(rec, positions=pos)
    elif lie in ("clear", "accuse"):
        flags = rec.faulty.copy()
        flags[2 if lie == "clear" else 5] = lie == "accuse"
        rec = replace(rec, faulty=flags)
    elif lie == "status":
        rec = replace(rec, status="alarm")
    elif lie == "report-forged":  # a report altered (its drone's signature kept), and the
        r = rec.reports[4]  # verdict honestly computed from it: only the signature tells
        forged = replace(r, position=r.position + [5.0, 0, 0])
        reports = {q.drone: q for q in rec.reports} | {4: forged}
        prior = Prior(rec.prior_step, rec.prior_positions, rec.prior_faulty)
        rec = replace(compute_record(12, 1, reports, prior, v.config), leader=rec.leader)
    elif lie == "report-dropped":  # the record's verdict kept, one of its reports left out
        rec = replace(rec, reports=rec.reports[:4] + rec.reports[5:])
    elif lie == "params":
        rec = replace(rec, params='{"gate":1.0}')
    elif lie == "prior-forged":
        pp = rec.prior_positions.copy()
        pp[4] += 3.0
        rec = replace(rec, prior_positions=pp)
    elif lie == "prior-old":
        rec = replace(rec, prior_step=7)
    elif lie == "term":
        term = 2
    data = resealed(rec, keys)
    if lie == "leader-signature":
        data = chain[12][:-64] + bytes(64)
    got, reason = v.audit.check(data, term)
    assert got is None and reason is not None
    assert v.audit.refused[-1][1] == reason


def test_signatures_checked_at_the_fan_out_are_not_checked_again(monkeypatch) -> None:
    """A voter that received a step's reports directly (the fan-out) checks none of their
    Ed25519 signatures again when the record carries them (its Keyring remembers them);
    without the fan-out it checks every one (and the leader's)."""
    from swarmraft.protocol import signing

    calls = []
    check = signing._check
    monkeypatch.setattr(signing, "_check", lambda key, data, sig: calls.append(sig) or check(key, data, sig))
    v, chain, _ = voter_through(12, own_keys=True)
    rec = StepRecord.decode(chain[12])
    assert all(v.audit.note_report(r) for r in rec.reports)
    calls.clear()
    assert v.audit.check(chain[12], 1)[1] is None
    assert set(calls) <= {rec.signature}  # at most the leader's, never a report's
    fresh, _, _ = voter_through(12, own_keys=True)
    calls.clear()
    assert fresh.audit.check(chain[12], 1)[1] is None
    assert set(calls) == {r.signature for r in rec.reports} | {rec.signature}


def test_a_forged_report_is_refused_though_its_genuine_twin_arrived_directly() -> None:
    """The memo of verified signatures is keyed by a report's bytes: a record carrying an
    altered report (same drone and step, the genuine signature kept) is refused even though
    the voter verified the genuine report at the fan-out."""
    v, chain, keys = voter_through(12)
    rec = StepRecord.decode(chain[12])
    assert all(v.audit.note_report(r) for r in rec.reports)
    r = rec.reports[4]
    forged = replace(r, position=r.position + [5.0, 0, 0])
    reports = {q.drone: q for q in rec.reports} | {4: forged}
    prior = Prior(rec.prior_step, rec.prior_positions, rec.prior_faulty)
    lie = replace(compute_record(12, 1, reports, prior, v.config), leader=rec.leader)
    got, reason = v.audit.check(resealed(lie, keys), 1)
    assert got is None and reason == "drone 5's report signature"


def test_a_report_noted_from_its_bytes_is_held_exactly_as_one_noted_decoded() -> None:
    """`Auditor.note_report_bytes` (the simulator's fan-out: decoded only where the signature
    must be checked) holds what `note_report` holds, with the memo shared between voters as
    in the simulator: a forged copy (the genuine signature kept) is refused after its genuine
    twin was held, a second copy and a copy for a closed step are not held again."""
    for from_bytes in (False, True):
        memo: dict = {}
        v, chain, _ = voter_through(12)
        w, _, _ = voter_through(12)
        v.audit.cache = w.audit.cache = memo
        rec = StepRecord.decode(chain[12])
        r = rec.reports[4]
        forged = replace(r, position=r.position + [5.0, 0, 0])

        def note(auditor, report, from_bytes=from_bytes):  # noqa: ANN001, ANN202
            data = report.encode()
            return auditor.note_report_bytes(data) if from_bytes else auditor.note_report(report, data)

        assert note(v.audit, r) and not note(v.audit, r)  # held once
        assert not note(w.audit, forged)  # the memo holds the genuine bytes, not the drone
        assert note(w.audit, r)
        w.audit.close_step(12)
        other = rec.reports[5]
        assert not note(w.audit, other)  # its step is closed here
        assert v.audit.timely[12] == {4} and w.audit.timely[12] == {4}


def test_a_record_whose_digest_is_not_its_reports_is_refused() -> None:
    v, chain, keys = voter_through(12)
    rec = StepRecord.decode(chain[12])
    got, reason = v.audit.check(resealed(replace(rec, digest="0" * len(rec.digest)), keys), 1)
    assert got is None and reason == "report digest"


def test_tolerance_is_tight() -> None:
    assert POSITION_TOL_M <= 1e-3  # a record is trusted to a millimetre at the very most


def test_learner_refuses_to_apply() -> None:
    """A drone that never validated a record (a learner) checks it before applying it."""
    v, chain, keys = voter_through(12)
    rec = StepRecord.decode(chain[12])
    pos = rec.positions.copy()
    pos[0, 1] += 2.0
    assert v.apply(resealed(replace(rec, positions=pos), keys)) is None
    assert v.refused_applies == 1 and v.state.last_step == 11
    assert v.apply(chain[12]) is not None


def test_a_leader_decides_each_step_once_though_reports_come_late() -> None:
    """A report for a step the leader has already verified (a resend that arrived after the
    verification, when the record is not applied yet) is acknowledged, but the step is not
    verified again: a second record of the step would carry only the late reports, and every
    voter holding the others would count them as left out (a networked swarm on a loaded
    machine proposed two records for half its steps, and its voters deposed an honest leader
    for censorship)."""
    w, keys, _ = honest_chain()
    leader = SwarmDrone(0, w.protocol, keys, audit=True)
    ranges = w.measured_ranges(0, w.ins_estimate(0, np.zeros(N), w.traj.positions[0].copy()))
    reports = [
        SwarmDrone(i, w.protocol, keys).make_report(0, w.fix[0, i], "gnss", ranges[i], w.innovation(0, i))
        for i in range(N)
    ]
    for r in reports[:-1]:
        assert leader.receive(r)
    first = leader.verify_step(0, 1)
    assert first is not None and len(first.reports) == N - 1
    assert leader.receive(reports[-1])  # acknowledged: a resend cannot help
    assert leader.verify_step(0, 1) is None  # the deadline's call: step 0 is decided
    assert leader.rejected == 0  # late, not forged


def test_censorship_windows_restart_with_each_term() -> None:
    """k = 2 of m = 5: three omissions of one drone's timely report in one term make the
    leader faulty; omissions under an earlier term do not count against a new one."""
    w, keys, chain = honest_chain()
    v = SwarmDrone(1, w.protocol, keys, audit=True, censor=(2, 5))
    left_out = 6  # drone 7's reports, held by the voter, left out by the leader

    def record(k: int, term: int) -> Entry:
        rec = StepRecord.decode(chain[k])
        rec = replace(rec, term=term)
        v.audit.note_report(next(r for r in rec.reports if r.drone == left_out))
        kept = tuple(r for r in rec.reports if r.drone != left_out)
        # the verdict without the drone's report, as an honest leader lacking it computes it
        prior = Prior(rec.prior_step, rec.prior_positions, rec.prior_faulty)
        again = compute_record(k, term, {r.drone: r for r in kept}, prior, w.protocol)
        again = replace(again, leader=0)
        return Entry(term, k, resealed(again, keys), EntryKind.NORMAL)

    for k in range(1, 3):
        v.apply(chain[k - 1])
        assert v.audit.validate(record(k, 1))
        v.audit.close_step(k)  # judged once the step has closed here
    assert v.audit.take_suspicion() is None  # two omissions: not more than k = 2
    for k in range(3, 5):  # a new term: the window restarts
        v.apply(chain[k - 1])
        assert v.audit.validate(record(k, 2))
        v.audit.close_step(k)
    assert v.audit.take_suspicion() is None
    v.apply(chain[4])
    assert v.audit.validate(record(5, 2))
    assert v.audit.take_suspicion() is None  # the step is open: not judged yet
    v.audit.close_step(5)
    why = v.audit.take_suspicion()
    assert why is not None and "drone 7" in why


def test_raft_validator_keeps_the_valid_prefix_and_deposes_the_leader() -> None:
    """Followers refuse entries b"lie": they acknowledge only the valid prefix, send no
    reject, count the refusal and start a forced election; the lie never commits."""
    c = Cluster(5, seed=4, validate=lambda node, e: e.data != b"lie")
    assert c.run_until(lambda: c.leader() is not None, 3000)
    lead = c.leader()
    term = c.status(lead).term
    c.propose_batch([b"ok1", b"lie", b"ok2"])
    c.run(1000)
    assert all(b"lie" not in c.applied(i) for i in c.ids)
    assert all(c.applied(i)[:1] == [b"ok1"] for i in c.ids)
    assert sum(c.status(i).refused for i in c.ids) >= 3
    assert c.leader() is not None and c.status(c.leader()).term > term
    assert c.messages["MsgVote"] > 0


def test_raft_refusal_sends_no_reject() -> None:
    node = RaftNode(
        RaftConfig(1, (2, 3)), MemoryStorage(), random.Random(0), validate=lambda e: e.data != b"x"
    )
    node.step(Message(MsgType.HEARTBEAT, 2, 1, 1))
    node.advance(node.ready())
    good, bad = Entry(1, 1, b"a"), Entry(1, 2, b"x")
    node.step(Message(MsgType.APP, 2, 1, 1, log_term=0, index=0, entries=(good, bad), commit=0))
    rd = node.ready()
    acks = [m for m in rd.messages if m.type == MsgType.APP_RESP]
    assert len(acks) == 1 and not acks[0].reject and acks[0].index == 1
    assert [e.data for e in rd.entries] == [b"a"]
    assert node.status.refused == 1


def refusing(node_id: int, peers: tuple[int, ...]) -> tuple[RaftNode, list[Message]]:
    """Node ``node_id`` following leader 2 (term 1) after refusing its entry b"x"; the
    messages it sent then."""
    node = RaftNode(
        RaftConfig(node_id, peers), MemoryStorage(), random.Random(0), validate=lambda e: e.data != b"x"
    )
    node.step(Message(MsgType.HEARTBEAT, 2, node_id, 1))
    node.advance(node.ready())
    lie = Entry(1, 1, b"x")
    node.step(Message(MsgType.APP, 2, node_id, 1, log_term=0, index=0, entries=(lie,), commit=0))
    rd = node.ready()
    node.advance(rd)
    return node, rd.messages


def test_refusal_deposes_the_leader_with_one_forced_election() -> None:
    """Every voter refuses a lie at about the same time: only the first voter after the liar
    in id order campaigns (forced: the reason is carried), so the vote does not split; the
    others stop following the liar, so their election timers run."""
    successor, sent = refusing(3, (1, 2))  # after 2 comes 3
    assert successor.role == "candidate" and successor.term == 2
    votes = [m for m in sent if m.type == MsgType.VOTE]
    assert {m.to for m in votes} == {1, 2} and all(m.force for m in votes)
    other, sent = refusing(1, (2, 3))
    assert other.role == "follower" and other.lead is None and other.term == 1
    assert not [m for m in sent if m.type in (MsgType.VOTE, MsgType.PRE_VOTE)]
    # it votes for the successor's forced election
    other.step(Message(MsgType.VOTE, 3, 1, 2, index=0, log_term=0, force=True))
    assert [m.reject for m in other.ready().messages if m.type == MsgType.VOTE_RESP] == [False]


def test_a_deposed_leader_is_not_followed_or_voted_for_until_another_leads() -> None:
    node, _ = refusing(1, (2, 3))
    node.step(Message(MsgType.HEARTBEAT, 2, 1, 1))
    assert node.lead is None  # dropped, as if lost
    node.step(Message(MsgType.VOTE, 2, 1, 3, index=1, log_term=1, force=True))
    node.step(Message(MsgType.PRE_VOTE, 2, 1, 4, index=1, log_term=1))
    answers = [m for m in node.ready().messages if m.type in (MsgType.VOTE_RESP, MsgType.PRE_VOTE_RESP)]
    assert answers and all(m.reject for m in answers)
    node.step(Message(MsgType.HEARTBEAT, 3, 1, 5))  # another leader: 2 is trusted again
    node.advance(node.ready())
    node.step(Message(MsgType.VOTE, 2, 1, 6, index=1, log_term=1, force=True))
    assert [m.reject for m in node.ready().messages if m.type == MsgType.VOTE_RESP] == [False]


def test_a_deposed_leader_elected_again_is_followed() -> None:
    """Only the deposed leadership's messages are dropped: elected again in a later term by
    the others, the deposed leader is followed (else this voter would time out and churn)."""
    node, _ = refusing(1, (2, 3))
    node.step(Message(MsgType.HEARTBEAT, 2, 1, 1))
    assert node.lead is None
    node.step(Message(MsgType.HEARTBEAT, 2, 1, 3))
    assert node.lead == 2 and node.term == 3


def lying(mode: str, seed: int, drones: int = N, duration: float = 6.0) -> Scenario:
    target = 3 if mode == "clear" else 5
    return Scenario(
        name="lie",
        seed=seed,
        drones=drones,
        duration_s=duration,
        spoof=[{"kind": "jump", "drones": [3], "start_s": 1.0, "magnitude": 30.0}],
        fault=[{"kind": "lying-leader", "at_s": 2.5, "mode": mode, "drone": target}],
    )


def replaced_at(log, liar: int, after_s: float) -> float:  # noqa: ANN001
    """The first step time after ``after_s`` at which another drone leads at the deadline."""
    for k in np.flatnonzero(log.t >= after_s):
        if log.leader[k] not in (0, liar):
            return float(log.t[k])
    return float("inf")


@pytest.mark.parametrize("mode", ["move", "clear", "accuse", "censor"])
@pytest.mark.parametrize("seed", [1, 2])
def test_lying_leader_is_caught(mode: str, seed: int) -> None:
    log = run_mission(lying(mode, seed))  # raises if an honest drone applies a falsified record
    a = log.audit
    liar = a["liar"]
    assert liar is not None
    if mode == "censor":
        assert a["censorship_findings"] > 0 and a["refused_entries"] == 0
        start = 2.5
        assert replaced_at(log, liar, start) - start <= 2.0
    else:
        assert a["falsified_proposed"] > 0 and a["refused_entries"] > 0
        start = a["first_lie_s"]
        assert replaced_at(log, liar, start) - start <= 1.0
    end = replaced_at(log, liar, start)
    skipped = log.t[~log.committed & (log.t > 1.0)]  # after the first election
    assert not ((skipped < start - 0.1) | (skipped > end)).any()  # skips only in the window
    assert log.leader[-1] != liar


def test_honest_leaders_are_never_accused() -> None:
    """A mission with spoofing, an outage, a leader crash and 10 % loss: no entry refused, no
    censorship finding, and the same records as the mission without the audit."""
    kw = dict(
        name="honest",
        seed=5,
        drones=N,
        duration_s=6.0,
        network={"loss": 0.1},
        spoof=[{"kind": "jump", "drones": [2], "start_s": 1.0, "magnitude": 30.0}],
        outage=[{"drones": [7], "start_s": 2.0}],
        fault=[{"kind": "crash-leader", "at_s": 3.0}],
    )
    log = run_mission(Scenario(**kw))
    assert log.audit["refused_entries"] == 0 and log.audit["censorship_findings"] == 0
    assert log.audit["refused_applies"] == 0
    off = run_mission(Scenario(**{**kw, "protocol": {"audit": False}}))
    assert np.array_equal(log.verified, off.verified, equal_nan=True)
    assert np.array_equal(log.faulty, off.faulty) and np.array_equal(log.leader, off.leader)
    assert list(log.status) == list(off.status)


@pytest.mark.parametrize(
    ("fault", "field"),
    [
        ({"kind": "lying-leader", "at_s": 1.0, "drone": 2}, "fault[0].mode"),
        ({"kind": "lying-leader", "at_s": 1.0, "mode": "move"}, "fault[0].drone"),
        ({"kind": "crash", "at_s": 1.0, "drone": 2, "mode": "move"}, "fault[0].mode"),
        (
            {"kind": "lying-leader", "at_s": 1.0, "drone": 2, "mode": "clear", "offset_m": 3},
            "fault[0].offset_m",
        ),
        ({"kind": "lying-leader", "at_s": 1.0, "drone": 2, "mode": "bend"}, "mode"),
    ],
)
def test_lying_leader_bad_input_is_one_line(fault: dict, field: str) -> None:
    with pytest.raises(ValidationError) as exc:
        Scenario(drones=5, duration_s=3.0, fault=[fault])
    assert field in str(exc.value)


@pytest.mark.parametrize("name", ["paper-recovery-6-2", "packet-loss-20"])
def test_shipped_scenarios_never_accuse_their_leaders(name: str) -> None:
    """A sample of `accept_audit.py honest`: shipped scenarios (the first 8 s) on two seeds."""
    import tomllib

    from swarmraft.sim.scenario import shipped_scenarios

    data = tomllib.loads(shipped_scenarios()[name].read_text())
    data["duration_s"] = min(data.get("duration_s", 60.0), 8.0)
    for seed in (1, 2):
        log = run_mission(Scenario(**{**data, "seed": seed}))
        assert log.audit["refused_entries"] == 0 and log.audit["censorship_findings"] == 0
        assert log.audit["refused_applies"] == 0 and log.committed.sum() > 0


def test_the_record_memo_returns_what_compute_record_would_for_every_change_of_input() -> None:
    """The simulator's `RecordMemo` shares one verification between the leader and the
    auditors; each input that `compute_record` reads must change the memo's key, or a
    re-run would be given another input's record."""
    from swarmraft.protocol.drone import RecordMemo, memo_compute

    w, keys, chain = honest_chain()
    rec = StepRecord.decode(chain[10])
    reports = {r.drone: r for r in rec.reports}
    prior = Prior(rec.prior_step, rec.prior_positions, rec.prior_faulty)
    c = w.protocol
    memo = RecordMemo()
    first = memo_compute(memo, rec.step, rec.term, reports, prior, c)
    assert memo_compute(memo, rec.step, rec.term, reports, prior, c) is first and memo.hits == 1
    other_report = dict(reports)
    r3 = reports[3]
    other_report[3] = keys.sign(replace(r3, position=r3.position + [5.0, 0.0, 0.0]))
    moved = prior.positions.copy()
    moved[3] += [5.0, 0.0, 0.0]
    flags = prior.faulty.copy()
    flags[2] = ~flags[2]
    variants = [
        (rec.step, rec.term + 1, reports, prior, c),
        (rec.step, rec.term, other_report, prior, c),
        (rec.step, rec.term, {i: r for i, r in reports.items() if i != 5}, prior, c),
        (rec.step, rec.term, reports, Prior(prior.step, moved, prior.faulty), c),
        (rec.step, rec.term, reports, Prior(prior.step, prior.positions, flags), c),
        (rec.step, rec.term, reports, Prior(prior.step - 1, prior.positions, prior.faulty), c),
        (rec.step, rec.term, reports, None, c),
        (rec.step, rec.term, reports, prior, replace(c, detector="paper")),
    ]
    for args in variants:
        got, want = memo_compute(memo, *args), compute_record(*args)
        assert got.encode() == want.encode()
    assert memo.hits == 1
    assert len({first.encode(), *(compute_record(*a).encode() for a in variants[1:2] + variants[3:])}) > 2


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({"position": np.array([np.nan, 0.0, 0.0])}, "position is not 3 numbers within 1e+07 m"),
        ({"position": np.array([1.4e154, 0.0, 0.0])}, "position is not 3 numbers within 1e+07 m"),
        ({"ranges": np.full(3, 10.0)}, "3 ranges in a swarm of 9"),
        ({"ranges": np.r_[np.inf, np.full(N - 1, 10.0)]}, "a range that is not a distance in [0, 1e+07] m"),
        ({"ranges": np.r_[-50.0, np.full(N - 1, 10.0)]}, "a range that is not a distance in [0, 1e+07] m"),
        ({"ranges": np.r_[1e154, np.full(N - 1, 10.0)]}, "a range that is not a distance in [0, 1e+07] m"),
        ({"ins": np.array([1e300, 0.0, 0.0])}, "an ins value beyond 1e+07 m"),
    ],
)
def test_a_malformed_signed_report_is_kept_by_no_one(change, why) -> None:
    """A compromised drone signs what it likes: a nan position, a short range row or an
    infinite range, signed, raised inside the leader's detector and stopped its step, as did
    a finite position of 1.4e154 m (the solver's squares overflowed: a LinAlgError in every
    statistical detector). The leader keeps no such report (the step goes on without that
    drone), a voter holds none at the fan-out, and a record that carries one is refused."""
    v, chain, keys = voter_through(12)
    rec = StepRecord.decode(chain[12])
    bad = keys.sign(replace(rec.reports[4], signature=b"", **change))
    assert bad.malformed(N) == why and keys.verify(bad)  # signed: only its content is wrong
    w, _, _ = honest_chain()
    leader = SwarmDrone(0, w.protocol, keys, audit=True)
    assert not leader.receive(bad) and leader.rejected == 1
    assert not v.audit.note_report(bad)
    reports = {q.drone: q for q in rec.reports}
    prior = Prior(rec.prior_step, rec.prior_positions, rec.prior_faulty)
    honest = replace(compute_record(12, 1, reports, prior, v.config), leader=rec.leader)
    carried = tuple(bad if q.drone == 4 else q for q in honest.reports)
    assert well_formed(honest.reports, N) and not well_formed(carried, N)  # all at once
    got, reason = v.audit.check(resealed(replace(honest, reports=carried), keys), 1)
    assert got is None and reason == f"drone 5's report: {why}"


@pytest.mark.parametrize("scale", [1e300, np.inf])
def test_a_record_whose_re_run_raises_is_refused_and_its_leader_deposed(scale: float) -> None:
    """A leader signs the prior it likes; one that makes the verification raise (positions of
    1e300 or inf: a LinAlgError in the solver) is a record that does not follow from its
    evidence. Before, the exception left the validator through `RaftNode.step`: no
    acknowledgement, no refusal, no election, and the voter followed the liar for good."""
    v, chain, keys = voter_through(12)
    rec = StepRecord.decode(chain[12])
    data = resealed(replace(rec, prior_positions=rec.prior_positions * scale), keys)
    got, reason = v.audit.check(data, 1)
    assert got is None and reason.startswith("re-run failed")
    node = RaftNode(RaftConfig(3, (1, 2)), MemoryStorage(), random.Random(0), validate=v.audit.validate)
    node.step(Message(MsgType.HEARTBEAT, 2, 3, 1))
    node.advance(node.ready())
    node.step(Message(MsgType.APP, 2, 3, 1, log_term=0, index=0, entries=(Entry(1, 1, data),), commit=0))
    rd = node.ready()
    assert node.status.refused == 1 and not rd.entries
    assert node.role == "candidate" and node.term == 2  # the successor of leader 2 campaigns


def test_a_node_says_which_appends_it_would_drop_unread() -> None:
    """`RaftNode.ignores`: a host that audits an append before stepping it (the networked
    drone) skips the audit of appends the node drops unread: the deposed leader's (a liar
    sends its next records while its first lie is audited) and a stale term's."""
    node, _ = refusing(1, (2, 3))  # deposed leader 2 in term 1
    from_liar = Message(MsgType.APP, 2, 1, 1, log_term=0, index=0, entries=(Entry(1, 1, b"y"),), commit=0)
    assert node.ignores(from_liar)
    assert node.ignores(replace(from_liar, type=MsgType.HEARTBEAT, entries=()))
    assert not node.ignores(replace(from_liar, type=MsgType.VOTE))  # not an append
    assert not node.ignores(replace(from_liar, frm=3, term=2))  # the next leader's
    node.step(Message(MsgType.HEARTBEAT, 3, 1, 2))  # leader 3 in term 2
    assert node.ignores(replace(from_liar, frm=3, term=1))  # a stale term
    assert not node.ignores(replace(from_liar, frm=3, term=2))
    before = (node.term, node.lead, node.status.last_index)
    node.ignores(from_liar)
    assert (node.term, node.lead, node.status.last_index) == before  # a query only


def test_a_record_ahead_of_the_voters_clock_is_refused() -> None:
    """A liar signs its own report for a step far ahead and a record of it alone (status
    `degenerate`, the re-run agrees): accepted, every drone then ignored each later record
    and report for good (its last step the far one). A record up to FUTURE_STEPS ahead of the
    voter's clock passes (clocks differ a little); one further is refused."""
    w, keys, chain = honest_chain()
    own = StepRecord.decode(chain[12]).reports[0]
    liar = SwarmDrone(0, w.protocol, keys)

    def lone(step: int) -> bytes:
        report = liar.make_report(step, own.position, "gnss", own.ranges, own.innovation)
        return resealed(replace(compute_record(step, 1, {0: report}, None, w.protocol), leader=0), keys)

    v, _, _ = voter_through(12)  # clock at step 12
    got, reason = v.audit.check(lone(2**31 - 1), 1)
    assert got is None and reason == "step 2147483647 is ahead of this drone's clock (step 12)"
    got, reason = v.audit.check(lone(12 + FUTURE_STEPS + 1), 1)
    assert got is None and reason.endswith("ahead of this drone's clock (step 12)")
    got, reason = v.audit.check(lone(12 + FUTURE_STEPS), 1)
    assert reason is None and got.step == 15
    v.audit.at_step(2**31 - 1)  # later, its clock there: the record passes
    assert v.audit.check(lone(2**31 - 1), 1)[1] is None


def test_a_mission_keeps_every_drones_audit_clock_at_its_step() -> None:
    """The simulator tells each drone's audit which step its clock is at (`Auditor.at_step`),
    as each step begins, the crashed and restarted ones too: without it nothing is ahead."""
    from swarmraft.sim.mission import Mission

    sc = lying("move", 1, duration=3.0).model_dump()
    sc = Scenario.model_validate({**sc, "fault": [{"kind": "crash-leader", "at_s": 1.5}]})
    m = Mission(sc)
    log = m.run()
    assert {d.audit.clock for d in m.drones} == {len(log.t) - 1}


def test_a_prior_the_voter_does_not_hold_is_refused() -> None:
    """A liar skips step 12 and proposes step 13 with a prior "for step 12" it made up (a
    spoofed drone moved 200 m, an honest one latched): no voter holds a record for step 12,
    and such a prior was accepted as unchecked (counted only): the re-run from it agreed, and
    drones were moved and an honest one flagged. Raft's log matching puts every honest prior
    in the voter's log (its entry comes before the record's), held as it was validated, or
    re-read from storage after a restart (`Auditor.remember`); so a prior not held is refused."""
    w, keys, chain = honest_chain()
    honest13 = StepRecord.decode(chain[13])
    reports = {r.drone: r for r in honest13.reports}
    base = StepRecord.decode(chain[11])
    fake_pos, fake_flags = base.positions.copy(), base.faulty.copy()
    fake_pos[2] += [200.0, 0.0, 0.0]
    fake_flags[5] = True
    v, _, _ = voter_through(12)  # audited and applied steps 0-11; step 12 never proposed
    v.audit.at_step(13)
    honest_prior, made_up = Prior(11, base.positions, base.faulty), Prior(12, fake_pos, fake_flags)
    for prior, refused in [(honest_prior, False), (made_up, True)]:
        data = resealed(replace(compute_record(13, 1, reports, prior, v.config), leader=0), keys)
        got, reason = v.audit.check(data, 1)
        if refused:
            assert got is None and reason == "prior step 12: this drone holds no record for it"
        else:
            assert reason is None
    # a restarted voter re-reads its own log: its records are priors again
    fresh = SwarmDrone(1, w.protocol, keys, audit=True)
    fresh.audit.at_step(13)
    for data in chain[:13]:
        fresh.audit.remember(data)
    assert fresh.audit.check(chain[13], 1)[1] is None


def test_a_leaders_snapshot_is_audited_before_it_is_installed() -> None:
    """A snapshot holds the state the entries it replaces made: a liar that could send any (a
    record moving drone 5 by 500 m, not even signed, and a last step a million ahead) got
    round the audit of entries, and the follower installed it. Now a snapshot whose records
    do not pass `check` in order, or whose last step is not its newest record's or is ahead
    of the drone's clock, is refused as an entry is: not installed, not acknowledged,
    counted, and the leader deposed. An honest snapshot (the audited chain) installs."""
    from swarmraft.protocol.drone import Applied
    from swarmraft.raft import Snapshot

    w, keys, chain = honest_chain()
    h = StepRecord.decode(chain[12])
    moved = h.positions.copy()
    moved[4, 0] += 500.0
    lies = {
        "moved": Applied({12: replace(h, positions=moved)}, [], 12, 0),
        "far": Applied({10**6: replace(h, step=10**6)}, [], 10**6, 0),
        "last step": Applied({12: h}, [], 10**6, 0),
    }

    def follower() -> tuple[SwarmDrone, RaftNode]:
        v = SwarmDrone(2, w.protocol, keys, audit=True)
        v.audit.at_step(13)
        node = RaftNode(
            RaftConfig(3, (1, 2)),
            MemoryStorage(),
            random.Random(0),
            validate=v.audit.validate,
            validate_snapshot=v.audit.validate_snapshot,
        )
        node.step(Message(MsgType.HEARTBEAT, 2, 3, 1))
        node.advance(node.ready())
        return v, node

    for name, state in lies.items():
        v, node = follower()
        node.step(Message(MsgType.SNAP, 2, 3, 1, snapshot=Snapshot(50, 1, state.encode())))
        rd = node.ready()
        assert rd.snapshot is None and node.status.refused == 1, name
        assert not [m for m in rd.messages if m.type == MsgType.APP_RESP], name
        assert node.role == "candidate" and node.term == 2, name  # leader 2 deposed by its successor
        assert v.audit.refused[-1][1].startswith("snapshot at index 50: "), name
    honest = Applied({k: StepRecord.decode(d) for k, d in enumerate(chain[:13])}, [], 12, 0)
    v, node = follower()
    node.step(Message(MsgType.SNAP, 2, 3, 1, snapshot=Snapshot(50, 1, honest.encode())))
    rd = node.ready()
    assert rd.snapshot is not None and node.status.refused == 0


def test_a_record_audited_in_one_term_is_refused_in_an_entry_of_another() -> None:
    """The shortcut for bytes already audited skipped the term check: a record of term 1,
    passed once, went into an entry of term 2 unchecked."""
    v, chain, _ = voter_through(13)  # chain[12] audited in term 1
    assert v.audit.validate(Entry(1, 20, chain[12]))
    assert not v.audit.validate(Entry(2, 21, chain[12]))
    assert v.audit.refused[-1][1] == "a record of term 1 in an entry of term 2"


def test_a_drone_state_that_does_not_decode_is_a_value_error() -> None:
    """`Applied.decode` promises a ValueError naming what is wrong; a record inside whose
    JSON text is `5` raised TypeError, one with a bad source byte IndexError."""
    import json
    import struct

    from swarmraft.protocol.drone import Applied

    _, _, chain = honest_chain()
    rec = StepRecord.decode(chain[12])
    body = rec.body()
    text = json.dumps([rec.status, rec.detector, rec.digest, rec.params]).encode()
    bad = body[: len(body) - len(text) - 4] + struct.pack("<I", 1) + b"5" + rec.signature
    blob = Applied({}, [], 0, 0).encode()[:-4] + struct.pack("<I", 1) + struct.pack("<I", len(bad)) + bad
    with pytest.raises(ValueError, match="drone state: a record does not decode"):
        Applied.decode(blob)


@pytest.mark.parametrize("order", ["reports first", "record first"])
def test_omissions_are_judged_against_the_reports_held_when_the_step_closes(order: str) -> None:
    """A leader that proposed before the fan-out's copies arrived was never found leaving a
    report out (the record was judged as it came, against nothing held yet): now a record is
    judged when its step closes here, whichever came first."""
    w, keys, chain = honest_chain(21)
    v = SwarmDrone(1, w.protocol, keys, audit=True, censor=(10, 20))
    found = None
    for k in range(21):
        rec = StepRecord.decode(chain[k])
        kept = {r.drone: r for r in rec.reports if r.drone != 4}  # drone 5's left out
        lie = replace(compute_record(k, 1, kept, None, w.protocol), leader=0)
        entry = Entry(1, k + 1, resealed(lie, keys), EntryKind.NORMAL)
        others = [r for r in rec.reports if r.drone != 1]
        v.audit.at_step(k)
        if order == "record first":
            assert v.audit.validate(entry)
        for r in others:
            v.audit.note_report(r)
        if order == "reports first":
            assert v.audit.validate(entry)
        v.audit.close_step(k)
        if found is None and (why := v.audit.take_suspicion()) is not None:
            found = (k, why)
    assert found == (10, "drone 5's reports left out of 11 of the last 20 steps")


def test_an_honest_snapshot_whose_records_priors_reach_before_it_installs() -> None:
    """A leader's prior is its newest settled applied record within 3 steps, so a record's
    prior is often not the record before it (that one an alarm, or not applied yet when the
    next step was verified). A snapshot trimmed so that such a prior falls before its oldest
    record was refused ('prior step k-1: this drone holds no record for it') by every drone
    that needed it: found by a review, end to end in the simulator (the drone stayed behind
    and deposed each honest leader that sent it). A prior before the snapshot's oldest record
    is not checked; one inside it must be the record held for that step."""
    from swarmraft.protocol.drone import RECORDS_KEPT, Applied
    from swarmraft.raft import Snapshot

    steps = 40
    w, keys, leader, _ = leader_run(steps, late=steps - RECORDS_KEPT)
    st = leader.state
    oldest = min(st.records)
    assert st.records[oldest + 1].prior_step < oldest  # the case
    follower = SwarmDrone(2, w.protocol, keys, audit=True)  # behind: holds nothing
    follower.audit.at_step(steps)
    honest = Applied(dict(st.records), st.skipped, st.last_step, st.ignored)
    assert follower.audit.validate_snapshot(Snapshot(5000, 1, honest.encode())), follower.audit.refused[-1:]


def test_records_of_two_terms_for_one_step_are_both_judged_each_for_its_leader() -> None:
    """Two records for one open step (the old leader's, then the new one's): the close judges
    the new leader's, and the old term's is not counted against it nor resets its tally (only
    the first to come was kept: the old one, judged for term 1)."""
    w, keys, chain = honest_chain()
    v = SwarmDrone(1, w.protocol, keys, audit=True, censor=(0, 5))
    rec = StepRecord.decode(chain[3])
    kept = {r.drone: r for r in rec.reports if r.drone != 6}
    for r in rec.reports:
        v.audit.note_report(r)
    old = replace(compute_record(3, 1, kept, None, w.protocol), leader=0)
    new = replace(compute_record(3, 2, kept, None, w.protocol), leader=2)
    v.audit._censorship(old)  # the old leader's record came first
    v.audit._censorship(new)
    v.audit.close_step(3)
    assert v.audit.omission_term == 2 and v.audit.omissions == {6: [3]}  # the new leader's, once
    assert v.audit.take_suspicion() == "drone 7's reports left out of 1 of the last 5 steps"


def test_a_lagging_clock_catches_up_with_a_majoritys_reports() -> None:
    """A networked drone's clock is its wall clock: one lagging the others' by more than
    FUTURE_STEPS steps refused every honest record as ahead (a review's finding). Signed
    reports of a step from a majority of the swarm move its clock there; a minority's do not
    (a liar and its accomplices cannot push it ahead)."""
    w, keys, chain = honest_chain()
    v, _, _ = voter_through(12)  # clock at 12
    rec = StepRecord.decode(chain[12])

    def at(step: int, drones: range) -> None:
        for r in rec.reports:
            if r.drone in drones:
                v.audit.note_report(keys.sign(replace(r, step=step, signature=b"")))

    at(20, range(2, 5))  # 3 others (4 with itself) of 9: a minority
    assert v.audit.clock == 12
    at(20, range(2, 6))  # 4 others, 5 with itself: a majority
    assert v.audit.clock == 20
