"""The drag-off test over time (protocol.drift) and what a mission does with it: a coordinated
slow drag is caught, honest drones are not pulled beyond raw GNSS, INS tracks do not follow
suspect positions, and a verdict against the previous record and the INS is an alarm."""

from dataclasses import replace

import numpy as np
import pytest

from swarmraft.experiments.mission import error_series, load_scenario, summarize
from swarmraft.protocol import Report, StepRecord
from swarmraft.protocol.drift import DriftModel, DriftVerdict, drift_test, realigns
from swarmraft.protocol.drone import ins_fallback
from swarmraft.sim.mission import Mission
from swarmraft.sim.sensing import ScenarioWorld


def _innovations(w: ScenarioWorld, k: int) -> np.ndarray:
    return np.array([w.innovations(k, i) for i in range(w.sc.drones)])


def test_honest_innovations_match_the_noise_model_and_never_trip_the_test():
    """Over 8 honest worlds (no spoof), each drone's window innovation has the model's spread,
    and no drone, nor the swarm's mean, reaches the 1e-6 threshold (nor the swarm the 1e-3
    suspect level)."""
    rows, worst, worst_swarm = [], 0.0, 0.0
    for seed in range(1, 9):
        w = ScenarioWorld.build(load_scenario("coordinated-drag", seed=seed, spoof=[], duration_s=45))
        m = w.protocol.drift
        for k in range(50, w.sc.steps + 1, 10):
            inn = _innovations(w, k)
            v = drift_test(inn, np.ones(w.sc.drones, bool), m)
            assert not v.dragged.any()
            worst, worst_swarm = max(worst, v.stat.max()), max(worst_swarm, v.swarm)
            rows.append(inn[:, 0])
    spread = np.concatenate(rows).std(axis=0)
    assert np.allclose(spread, np.sqrt(m.variance()[0]), rtol=0.15)
    assert worst < m.threshold(m.false_alarm) and worst_swarm < m.threshold(m.suspect)


def test_a_common_slow_drag_is_found_by_the_swarm_mean_before_any_one_drone():
    """4 of 9 dragged at 0.3 m/s in one direction: the swarm-wide mean finds all four while no
    drone's own statistic is over its threshold, and never finds an honest drone."""
    w = ScenarioWorld.build(load_scenario("coordinated-drag", seed=1))
    m = w.protocol.drift
    dragged = np.zeros(9, bool)
    dragged[[1, 3, 5, 7]] = True
    first = None
    for k in range(100, w.sc.steps + 1, 5):
        v = drift_test(_innovations(w, k), np.ones(9, bool), m)
        assert not (v.dragged & ~dragged).any()
        if first is None and v.dragged[dragged].all():
            first = k
            assert (v.stat[dragged] < m.threshold(m.false_alarm)).any()
    assert first is not None
    off = np.linalg.norm(w.fix[first] - w.traj.positions[first], axis=1)[dragged]
    assert off.max() < 10


def test_the_swarm_mean_is_what_catches_it():
    """The same world with the swarm's mean taken over nobody (per-drone tests only): the
    drag is not found within 30 s (the INS biases hide 0.3 m/s from any one drone)."""
    w = ScenarioWorld.build(load_scenario("coordinated-drag", seed=1, duration_s=40))
    m = w.protocol.drift
    found = [drift_test(_innovations(w, k), np.zeros(9, bool), m).dragged.sum() for k in range(100, 401, 10)]
    assert max(found) < 4


def _report(drone: int, ins=None, drift=None) -> Report:
    return Report(3, drone, np.arange(3.0), "gnss", np.ones(4), np.zeros(3), b"s" * 64, drift, ins)


def test_reports_carry_drift_and_ins_and_old_reports_encode_as_before():
    r = _report(1, ins=np.array([1.0, 2.0, 3.0]), drift=np.arange(24.0).reshape(8, 3))
    back = Report.decode(r.encode())
    assert np.array_equal(back.drift, r.drift) and np.array_equal(back.ins, r.ins)
    assert back.signature == r.signature
    old = _report(1)
    head = np.array([3, 1], "<i4").tobytes() + bytes([0, 1]) + np.array([4], "<u2").tobytes()
    body = head + np.concatenate([old.position, old.ranges, old.innovation]).astype("<f8").tobytes()
    assert old.body() == body
    assert Report.decode(old.encode()).drift is None and Report.decode(old.encode()).ins is None


def _record(faulty, status="ok", reports=()) -> StepRecord:
    n = len(faulty)
    return StepRecord(
        5,
        1,
        np.zeros((n, 3)),
        np.array(faulty),
        np.zeros(n, bool),
        status,
        "joint",
        "",
        reports=tuple(reports),
    )


def test_an_ins_track_aligns_only_to_a_settled_record_that_trusts_it_while_the_swarm_is_not_pulled():
    model = DriftModel(windows=2)
    calm = [_report(i, drift=np.zeros((2, 3))) for i in range(4)]
    assert realigns(_record([False] * 4, reports=calm), 0, model)
    assert not realigns(_record([True, False, False, False], reports=calm), 0, model)  # flagged
    assert not realigns(_record([False] * 4, "alarm", calm), 0, model)  # unsettled
    # every drone's innovation 1 m east in both windows: the swarm is being pulled, nobody aligns
    pulled = [_report(i, drift=np.tile([1.0, 0, 0], (2, 1))) for i in range(4)]
    assert not any(realigns(_record([False] * 4, reports=pulled), i, model) for i in range(4))


def test_an_ins_track_does_not_align_to_a_position_the_record_does_not_protect():
    """A drone whose level is inf in the record (its position withheld for a level above the
    alert limits: the record carries the prior, the previous step's position; or unchecked)
    is not aligned to: a drone withheld step after step would have its track pinned to a
    position it has flown away from. A finite level, or none at all (`paper`: nan), aligns."""
    model = DriftModel(windows=2)
    calm = [_report(i, drift=np.zeros((2, 3))) for i in range(4)]
    rec = replace(_record([False] * 4, "degenerate", calm), hpl=np.array([np.inf, 10.0, np.nan, 10.0]))
    assert [realigns(rec, i, model) for i in range(4)] == [False, True, True, True]


def _verdict(suspect, dragged=None) -> DriftVerdict:
    s = np.array(suspect)
    return DriftVerdict(
        np.zeros(len(s)), 0.0, np.zeros(len(s), bool) if dragged is None else dragged, s, False
    )


def test_a_verdict_against_the_last_record_and_the_ins_falls_back_to_the_ins_tracks():
    reports = {i: _report(i, ins=np.full(3, float(i))) for i in range(4)}
    present = np.ones(4, bool)
    before = np.zeros(4, bool)
    anew = np.array([False, False, True, False])  # drone 3 flagged anew
    verdict = np.full((4, 3), -1.0)
    # the INS finds nothing wrong with it: the record falls back to every drone's INS track
    fb = ins_fallback(reports, present, anew, verdict, before, _verdict([False] * 4))
    assert fb is not None and np.array_equal(fb[:, 0], np.arange(4.0))
    # a drone the last record flagged keeps the verdict's position (its track is stale)
    cleared = np.array([True, False, False, False])
    fb = ins_fallback(reports, present, anew, verdict, cleared, _verdict([False] * 4))
    assert fb is not None and np.array_equal(fb[:, 0], [-1.0, 1.0, 2.0, 3.0])
    # the INS finds it suspect too (a fresh spoof): the verdict stands
    fresh = _verdict([False, False, True, False])
    assert ins_fallback(reports, present, anew, verdict, before, fresh) is None
    # nothing changed since the last record: the verdict stands
    assert ins_fallback(reports, present, anew, verdict, anew, _verdict([False] * 4)) is None


@pytest.fixture(scope="module")
def coordinated_drag():
    sc = load_scenario("coordinated-drag", duration_s=32)
    mission = Mission(sc)
    log = mission.run()
    errors = error_series(log)
    return mission, log, summarize(log, errors)


def test_coordinated_drag_is_caught_before_ten_metres_and_honest_drones_stay_below_raw_gnss(coordinated_drag):
    _, _, s = coordinated_drag
    assert len(s["detections"]) == 4
    for d in s["detections"]:
        assert d["flagged_at_least_once"] and d["reported_error_at_first_detection_m"] < 10
    assert s["honest_worse_than_gnss"]["longest_s"] <= 1.0
    assert s["honest_false_positive_rate"] == 0


def test_dragged_drones_ins_tracks_stay_where_they_were_before_suspicion(coordinated_drag):
    """Once a dragged drone is flagged for good its INS track is no longer aligned to its
    committed position (which the drag had pulled): its last alignment is from before its
    sustained detection (between the first and the sustained one, a record that clears it
    while the trusted drones' mean is under the suspect level may still align it), while
    every honest drone's is from the last second."""
    mission, log, s = coordinated_drag
    for d in s["detections"]:
        i = d["drone"] - 1
        assert d["time_to_sustained_detection_s"] is not None
        assert mission.ins_base_t[i] < d["start_s"] + d["time_to_sustained_detection_s"]
    honest = [i for i in range(9) if i not in (1, 3, 5, 7)]
    assert (mission.ins_base_t[honest] >= log.t[-1] - 1.0).all()


def test_auditors_reproduce_every_drag_record_from_its_evidence(coordinated_drag):
    mission, _, _ = coordinated_drag
    audit = mission.audit_summary()
    assert audit["refused_entries"] == 0 and audit["refused_applies"] == 0


def test_a_remembered_innovation_is_the_one_computed_afresh_and_cannot_be_changed():
    """`ScenarioWorld.innovation` remembers its answers (a bounded memo: the drag-off test
    asks for each window again M - 1 times): asked in any order, twice, or after the memo
    forgot it, the answer is bit for bit what a fresh world computes, and read-only (a caller
    that changed it would change every later report)."""
    from swarmraft.sim import sensing
    from swarmraft.sim.scenario import Scenario

    sc = Scenario(
        name="t",
        seed=4,
        drones=5,
        duration_s=20.0,
        spoof=[{"kind": "drag", "drones": [2], "start_s": 5, "rate": 0.3}],
    )
    w = ScenarioWorld.build(sc)
    keys = [(k, i) for k in range(sc.steps, -1, -7) for i in range(5)]
    first = [w.innovation(k, i) for k, i in keys]
    assert sum(x is not None for x in first) > len(keys) // 2
    w._innovations = sensing.BoundedMemo(3)  # forgets nearly everything
    for (k, i), a in zip(keys, first, strict=True):
        fresh = ScenarioWorld.build(sc)._innovation(k, i)
        for b in (w.innovation(k, i), w.innovation(k, i), fresh):
            assert (a is None) == (b is None)
            if a is not None:
                assert a.tobytes() == b.tobytes()
        if a is not None:
            with pytest.raises(ValueError):
                a[0] = 1.0
    assert len(w._innovations) <= 3
