"""What a mission's summary tells a user: wrong partitions, detection over time, honest
baselines, warnings, and the --json output for scripts."""

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from swarmraft.cli import main
from swarmraft.experiments.mission import SUSTAIN_S, error_series, load_scenario, summarize
from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario

ROOT = Path(__file__).parent.parent


def _demo_file() -> Path:
    """The demo scenario, wherever the tree keeps it (repo folder or package data)."""
    for p in [ROOT / "scenarios" / "demo.toml", *sorted((ROOT / "src").rglob("scenarios/demo.toml"))]:
        if p.exists():
            return p
    raise FileNotFoundError("demo.toml")


def _wrong_steps_by_hand(log) -> list[int]:
    """Committed steps where some alive drone that reported is flagged while honest, or
    spoofed while not flagged: counted drone by drone, independently of the summary."""
    out = []
    for k in range(len(log.t)):
        if not log.committed[k]:
            continue
        for i in range(log.scenario.drones):
            if log.alive[k, i] and not log.missing[k, i] and log.faulty[k, i] != log.spoofed[k, i]:
                out.append(k)
                break
    return out


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    res = CliRunner().invoke(main, ["mission", "--scenario", str(_demo_file()), "--out", str(out)])
    assert res.exit_code == 0, res.output
    log = run_mission(load_scenario(_demo_file()))
    return res.stdout, json.loads((out / "summary.json").read_text()), log, out


def test_piped_summary_lines_fit_100_columns_and_wrap_indented(demo):
    """Piped output (a log file) keeps wide tables, but the summary's prose fits 100 columns,
    each wrapped line indented under its first; only lines with paths may be longer."""
    output, _, _, out = demo
    lines = [ln for ln in output.splitlines() if ln.strip() and str(out) not in ln]
    assert len(lines) > 20
    assert max(len(ln) for ln in lines) <= 100, max(lines, key=len)
    assert lines[0].startswith("demo-mission: 9 drones")
    assert [ln for ln in lines[1:] if not ln.startswith("  ")] == []
    assert [ln for ln in lines if ln != ln.rstrip()] == []


def test_demo_summary_reports_every_wrong_partition_step_it_contains(demo):
    output, summary, log, _ = demo
    by_hand = _wrong_steps_by_hand(log)
    assert summary["wrong_partition_step_count"] == len(by_hand)
    assert [w["step"] for w in summary["wrong_partition_steps"]] == by_hand
    said = " ".join(output.split())  # as read, whatever the line breaks
    assert f"in {len(by_hand)} committed steps" in said
    for w in summary["wrong_partition_steps"][:12]:  # the printed list; the rest are in the JSON
        assert f"t = {w['t']:.1f} s:" in said
        for d in w["honest_flagged"]:
            assert not log.spoofed[w["step"], d - 1] and log.faulty[w["step"], d - 1]


def test_the_demo_swarm_is_better_than_its_raw_gnss_and_rarely_partitioned_wrongly(demo):
    # the demo's claim; an alarm record carried on as the next step's prior once locked the
    # wrong partition in for 11 s after one lost report (118 steps, honest drones at 5.2 m)
    _, summary, _, _ = demo
    assert summary["honest_error_swarmraft_m"] < 0.8 * summary["honest_error_gnss_m"]
    assert summary["wrong_partition_step_count"] <= 10


def test_demo_steps_csv_marks_the_same_wrong_partition_steps(demo):
    _, summary, _, out = demo
    lines = (out / "steps.csv").read_text().splitlines()
    cols = lines[0].split(",")
    step, wrong = cols.index("step"), cols.index("wrong_partition")
    marked = sorted({int(r.split(",")[step]) for r in lines[1:] if r.split(",")[wrong] == "1"})
    assert marked == [w["step"] for w in summary["wrong_partition_steps"]]


def test_a_spoofed_majority_is_warned_about_and_its_wrong_partitions_listed():
    # 3 of 5 drones moved together by 40 m: they agree with each other, so the honest pair is
    # the minority; whatever the detector does, flags and spoofed set cannot match every step
    sc = Scenario(
        drones=5,
        duration_s=4,
        seed=3,
        spoof=[{"kind": "area", "drones": [2, 3, 4], "start_s": 1, "magnitude": 40}],
    )
    log = run_mission(sc)
    s = summarize(log, error_series(log))
    assert any("more than (n-1)//2 = 2" in w for w in s["warnings"])
    assert s["wrong_partition_step_count"] == len(_wrong_steps_by_hand(log)) > 0
    assert s["wrong_partition_time_ranges_s"][0][0] >= 1.0


def test_no_warning_when_the_honest_drones_are_a_majority(demo):
    _, summary, _, _ = demo
    assert summary["warnings"] == []


@pytest.fixture(scope="module")
def small():
    sc = Scenario(
        drones=7,
        duration_s=8,
        seed=5,
        spoof=[{"kind": "jump", "drones": [3], "start_s": 1, "magnitude": 30}],
        outage=[{"drones": [5], "start_s": 2, "end_s": 6}],
        fault=[{"kind": "crash", "at_s": 4, "drone": 6}],
    )
    return run_mission(sc)


def test_first_and_sustained_detection_follow_the_flags(small):
    log = small
    # rewrite drone 3's flags: flagged at 0.2 s after the start, missed at 0.5 s, then
    # flagged throughout from 0.8 s; every step committed so that all steps are judged
    log.committed[:] = True
    log.missing[:] = False
    log.faulty[:, 2] = False
    k0 = 10
    log.faulty[k0 + 2 : k0 + 5, 2] = True
    log.faulty[k0 + 8 :, 2] = True
    (d,) = summarize(log, error_series(log))["detections"]
    assert d["time_to_first_detection_s"] == pytest.approx(0.2)
    assert d["time_to_sustained_detection_s"] == pytest.approx(0.8)
    judged = int(log.alive[k0:, 2].sum())
    assert d["judged_steps"] == judged
    assert d["flagged_fraction"] == pytest.approx(round((3 + judged - 8) / judged, 4))
    # a gap inside the sustain window moves the sustained detection past it
    hold = int(round(SUSTAIN_S / log.scenario.dt_s))
    log.faulty[k0 + 8 + hold - 1, 2] = False
    (d,) = summarize(log, error_series(log))["detections"]
    assert d["time_to_sustained_detection_s"] == pytest.approx((8 + hold) / 10)


def test_worst_error_is_the_largest_error_during_the_spoof(small):
    log = small
    errors = error_series(log)
    (d,) = summarize(log, errors)["detections"]
    during = errors["swarmraft"][10:, 2]
    assert d["worst_error_m"] == pytest.approx(np.nanmax(during), abs=1e-3)
    assert d["worst_error_m"] >= d["mean_error_m"]


def test_ins_baseline_is_aligned_at_the_outage_start(small):
    log = small
    errors = error_series(log)
    k0, k1 = 20, 60
    assert np.isnan(errors["ins_aligned"][:k0, 4]).all() and np.isnan(errors["ins_aligned"][k1:, 4]).all()
    assert errors["ins_aligned"][k0, 4] == 0.0  # aligned to the truth at the start
    assert np.isfinite(errors["ins_aligned"][k0:k1, 4]).all()
    assert np.isnan(errors["ins_aligned"][:, [0, 1, 2, 3, 5, 6]]).all()
    (o,) = summarize(log, errors)["outages"]
    # the never-reset INS has already drifted when the outage starts; the aligned one has not
    assert o["ins_alone_error_at_start_m"] > 0.0
    assert o["mean_error_ins_aligned_m"] < o["mean_error_ins_alone_m"]


def test_honest_error_is_reported_after_each_fault(small):
    log = small
    errors = error_series(log)
    (a,) = summarize(log, errors)["after_faults"]
    assert a["event"] == "drone 6 crashed" and a["from_s"] == 4.0
    honest = [0, 1, 3, 4, 6]  # drone 6 is honest but dead after the crash: not counted
    rows = slice(40, len(log.t))
    sw, gn = errors["swarmraft"][rows][:, honest], errors["gnss"][rows][:, honest]
    # both means over the same cells: alive, committed, with a position and a fix (drone 5's
    # outage until 6 s has no raw GNSS to compare with)
    both = log.alive[rows][:, honest] & log.committed[rows][:, None] & np.isfinite(sw) & np.isfinite(gn)
    assert 0 < both.sum() < log.alive[rows][:, honest].sum()
    assert a["honest_error_swarmraft_m"] == pytest.approx(sw[both].mean(), abs=1e-3)
    assert a["honest_error_gnss_m"] == pytest.approx(gn[both].mean(), abs=1e-3)


def test_every_skipped_step_is_put_down_to_a_cause(small):
    """Skipped steps before the first record (the first election), within 2 s after a fault
    event (here drone 6's crash at 4 s), and the rest: unexplained, listed by time. In a
    networked run the step before the event too (its record was on its way when it came);
    in the simulator a fault cannot reach back."""
    log = copy.deepcopy(small)
    log.committed[:] = True
    log.committed[[0, 1, 39, 41, 75]] = False  # 0 and 0.1 s; 3.9 s; 4.1 s; 7.5 s
    assert log.events == [(4.0, "drone 6 crashed")] and log.in_flight_s == 0
    s = summarize(log, error_series(log))
    assert s["skipped_steps"] == 5
    assert s["skipped_causes"] == {
        "no_record": 0,
        "before_first_record": 2,
        "after_fault": 1,
        "unexplained": 2,
        "unexplained_times_s": [3.9, 7.5],
    }
    log.in_flight_s = 0.1  # as `net.results.launch_log` sets it: one step
    c = summarize(log, error_series(log))["skipped_causes"]
    assert c["after_fault"] == 2 and c["unexplained_times_s"] == [7.5]
    log.committed[39] = True
    log.committed[38] = False  # two steps before the crash: not its doing
    c = summarize(log, error_series(log))["skipped_causes"]
    assert c["after_fault"] == 1 and c["unexplained_times_s"] == [3.8, 7.5]


def test_the_demo_skips_no_step_without_a_cause(demo):
    out, summary, _, _ = demo
    c = summary["skipped_causes"]
    assert summary["skipped_steps"] > 0  # the first election and the leader's crash
    assert c["before_first_record"] + c["after_fault"] == summary["skipped_steps"]
    assert c["unexplained"] == 0 and c["unexplained_times_s"] == []
    assert "0 unexplained" in " ".join(out.split())


def mission_of(tmp_path, scenario: str, *args: str):  # noqa: ANN201 (click's Result)
    """`swarmraft mission` on the scenario file text ``scenario`` (written to tmp_path), its
    output in tmp_path/o; it must succeed."""
    f = tmp_path / "s.toml"
    f.write_text(scenario)
    res = CliRunner().invoke(main, ["mission", "--scenario", str(f), "--out", str(tmp_path / "o"), *args])
    assert res.exit_code == 0, res.output
    return res


def test_mission_json_is_the_summary_and_nothing_else(tmp_path):
    res = mission_of(
        tmp_path,
        'name = "tiny"\ndrones = 5\nduration_s = 2\nseed = 2\n'
        '[[spoof]]\nkind = "jump"\ndrones = [2]\nstart_s = 1\n',
        "--json",
    )
    printed = json.loads(res.stdout)
    assert printed == json.loads((tmp_path / "o" / "summary.json").read_text())
    assert "wrote" in res.stderr and "wrote" not in res.stdout


def test_the_printed_summary_warns_of_a_spoofed_majority(tmp_path):
    res = mission_of(
        tmp_path,
        'name = "majority"\ndrones = 5\nduration_s = 2\nseed = 3\n'
        '[[spoof]]\nkind = "area"\ndrones = [2, 3, 4]\nstart_s = 1\nmagnitude = 40\n',
    )
    assert "warning: up to 3 of 5 drones spoofed at once" in " ".join(res.stdout.split())


def test_mission_records_carry_protection_levels_that_bound_the_error(tmp_path):
    from swarmraft.experiments.mission import load_scenario, misleading_information, run_and_write

    sc = load_scenario("leader-crash-under-attack", duration_s=25.0)
    result = run_and_write(sc, tmp_path)
    log = result.log
    ok = log.committed & (log.status == "ok")
    assert ok.sum() > 100
    levels = log.hpl[ok]
    assert np.isfinite(levels).mean() > 0.95  # nan: drones re-estimated after the detector
    assert (levels[np.isfinite(levels)] > 0).all()
    assert not misleading_information(log).any()
    assert result.summary["integrity"]["misleading_drone_steps"] == 0
    header = (tmp_path / "steps.csv").read_text().splitlines()[0].split(",")
    assert {"hpl", "vpl", "misleading"} <= set(header)


def test_a_mission_whose_records_have_no_protection_levels_does_not_claim_none_misleading(tmp_path):
    """`paper` records carry no levels: the summary's misleading count is None (not judged),
    where 0 read as "every ok record within its protection levels"."""
    from swarmraft.experiments.mission import load_scenario, run_and_write

    sc = load_scenario("paper-recovery-6-2", duration_s=3.0)
    assert sc.protocol.detector == "paper"
    result = run_and_write(sc, tmp_path)
    assert result.summary["integrity"]["ok_steps"] > 0
    assert result.summary["integrity"]["misleading_drone_steps"] is None
    res = CliRunner().invoke(
        main, ["mission", "--scenario", "paper-recovery-6-2", "--out", str(tmp_path / "o")]
    )
    assert res.exit_code == 0, res.output
    assert "misleading information: not judged (no ok record has a protection level)" in " ".join(
        res.output.split()
    )


def test_a_log_cut_to_its_first_steps_keeps_only_what_they_hold(small):
    """An interrupted launch is summarised over the steps it reached: every per-step array
    and the events up to the last of them (the steps after it were not skipped: they never
    came)."""
    k = 30  # to 2.9 s: before drone 6's crash at 4 s
    cut = small.first_steps(k)
    assert len(cut.t) == k and cut.t[-1] == small.t[k - 1]
    for name in ("truth", "verified", "committed", "alive", "status", "latency_ms"):
        np.testing.assert_array_equal(getattr(cut, name), getattr(small, name)[:k])
    assert cut.events == [(t, e) for t, e in small.events if t <= small.t[k - 1]]
    assert len(small.t) > k and cut.events == [] and small.events == [(4.0, "drone 6 crashed")]
    s = summarize(cut, error_series(cut))
    assert s["committed_steps"] + s["skipped_steps"] == k
    assert [d["drone"] for d in s["detections"]] == [3]  # its spoof began at 1 s
    # cut before the spoof began: not a spoof missed, none at all
    assert summarize(small.first_steps(8), error_series(small.first_steps(8)))["detections"] == []
