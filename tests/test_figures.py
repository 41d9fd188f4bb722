"""Figures a reviewer would accept: what is drawn, read back from the matplotlib objects."""

import itertools

import numpy as np
import pytest
from click.testing import CliRunner

from swarmraft import viz
from swarmraft.cli import main
from swarmraft.experiments.compare import cell_sems
from swarmraft.experiments.curves import CURVE_COLUMNS, CurvePoint
from swarmraft.experiments.metrics import efficiency_interval
from swarmraft.experiments.published import PUBLISHED
from swarmraft.viz import figures as vf
from swarmraft.viz import mission as vm


@pytest.fixture
def drawn(monkeypatch):
    """The figures drawn, kept open instead of written and closed."""
    figs = []

    def keep(fig, path):
        figs.append(fig)
        return path

    monkeypatch.setattr(vf, "_save", keep)
    monkeypatch.setattr(vm, "_save", keep)
    yield figs
    vf.plt.close("all")


def _table(cells, detectors, attack="jump", preset="realistic", trials=200):
    rows = [
        {"n": n, "f": f, "detector": d, "attack": attack, "preset": preset, "trials": trials}
        for (n, f), d in itertools.product(cells, detectors)
    ]
    t = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    rng = np.random.default_rng(0)
    t["recovered_mean"] = rng.uniform(1, 5, len(rows))
    t["recovered_sem"] = rng.uniform(0.05, 0.3, len(rows))
    return t


def test_compare_draws_dots_with_95_percent_intervals_and_no_line_between_cells(drawn):
    t = _table([(9, 3), (13, 3), (17, 8)], ["paper", "joint"])
    viz.compare(t, "recovered_mean", "mean error, m", True, "x.png")
    (fig,) = drawn
    ax = fig.axes[0]
    dots = [ln for ln in ax.lines if ln.get_marker() == "o"]
    assert len(dots) == 2
    for ln in dots:
        assert ln.get_linestyle() == "None"  # nothing joins the (n, f) cells
    # the interval of each dot is 1.96 standard errors either side
    caps = [ln for ln in ax.lines if ln.get_marker() == "_"]
    tops = np.sort(np.concatenate([ln.get_ydata() for ln in caps]))
    want = np.sort(
        np.concatenate(
            [t["recovered_mean"] - 1.96 * t["recovered_sem"], t["recovered_mean"] + 1.96 * t["recovered_sem"]]
        )
    )
    np.testing.assert_allclose(tops, want)
    assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0
    title = fig._suptitle.get_text()
    assert "preset realistic" in title and "200 trials" in title and "(13, 3)" in title


def test_compare_uses_a_log_axis_only_without_bars_over_many_decades(drawn):
    t = _table([(9, 4)], ["paper", "joint"], preset="reference")
    t["recovered_mean"] = np.array([1.3, 1e-14])
    viz.compare(t, "recovered_mean", "mean error, m", True, "x.png")
    ax = drawn[0].axes[0]
    assert ax.get_yscale() == "log"
    assert not ax.patches  # no bars


def test_roc_points_are_sorted_by_false_alarm_and_the_threshold_is_named(drawn):
    # thresholds in an order whose false-alarm rates are not monotone
    pts = [
        CurvePoint("fde", "roc", "p_fa", th, 10.0, fa, pd)
        for th, fa, pd in [(1e-6, 0.02, 0.5), (1e-4, 0.0, 0.3), (1e-2, 0.3, 0.9), (1e-1, 0.1, 0.4)]
    ]
    viz.roc(pts, "x.png")
    ax = drawn[0].axes[0]
    (curve,) = [ln for ln in ax.lines if ln.get_marker() == "o"]
    assert list(curve.get_xdata()) == [0.0, 0.02, 0.1, 0.3]
    assert "p_fa" in ax.get_xlabel()
    assert "parameter" in CURVE_COLUMNS and CURVE_COLUMNS.index("parameter") < CURVE_COLUMNS.index(
        "threshold"
    )


def _scaling_cells(n, f, preset, detector, baseline, recovered, sem) -> dict:
    """A sweep's cells as `viz.scaling` reads them: (n, f) cells of 100 jump trials each."""
    k = len(n)
    return {
        "n": np.asarray(n),
        "f": np.asarray(f),
        "trials": np.full(k, 100),
        "preset": np.array([preset] * k),
        "detector": np.array([detector] * k),
        "attack": np.array(["jump"] * k),
        "baseline_mean": np.full(k, baseline),
        "baseline_sem": np.full(k, 0.1),
        "recovered_mean": np.array(recovered, float),
        "recovered_sem": np.broadcast_to(np.asarray(sem, float), (k,)).copy(),
    }


def test_reference_scaling_shows_the_published_means(drawn):
    n = np.array([3, 5, 7])
    cells = _scaling_cells(n, (n - 1) // 2, "reference", "paper", 28.8, [19.0, 5.0, 2.0], 0.1)
    viz.scaling(cells, "x.png")
    ax = drawn[0].axes[0]
    (pub,) = [ln for ln in ax.lines if ln.get_label().startswith("published, verified")]
    assert list(pub.get_ydata()) == [PUBLISHED[k][1] for k in (3, 5, 7)]
    cells["preset"] = np.array(["realistic"] * 3)
    viz.scaling(cells, "y.png")
    assert not [ln for ln in drawn[1].axes[0].lines if ln.get_label().startswith("published")]


def _errors(S, n):
    z = np.zeros((S, n))
    return {
        "gnss": z + 3.0,
        "ins_alone": z + 1.0,
        "ins_aligned": np.full((S, n), np.nan),
        "swarmraft": z.copy(),  # exact: 0 m
        "snapshot_bound": np.full((S, n), np.nan),
    }


def test_error_over_time_draws_zero_at_zero_and_no_fault_lines_without_faults(drawn):
    S, n = 20, 4
    t = np.arange(S) * 0.1
    no = np.zeros((S, n), bool)
    vm.error_over_time(t, _errors(S, n), no, no, [], "x.png")
    fig = drawn[0]
    ax = fig.axes[0]
    (sr,) = [ln for ln in ax.lines if ln.get_label() == "SwarmRaft"]
    assert (np.asarray(sr.get_ydata()) == 0).all()
    assert ax.get_ylim()[0] < 0 < ax.get_ylim()[1]  # zero inside the axes, not at a floor
    assert not [ln for ln in ax.lines if ln.get_label() == "fault"]
    assert "fault" not in fig._suptitle.get_text()


def test_error_over_time_labels_faults_and_marks_wrong_partition_steps(drawn):
    S, n = 30, 4
    t = np.arange(S) * 0.1
    no = np.zeros((S, n), bool)
    alive = np.ones((S, n), bool)
    alive[15:, 1] = False
    wrong = no.copy()
    wrong[[7, 22], 2] = True
    vm.error_over_time(
        t, _errors(S, n), no, no, [(1.5, "leader 2 crashed")], "x.png", alive=alive, wrong=wrong
    )
    fig = drawn[0]
    ax0 = fig.axes[0]
    assert "leader 2 crashed" in [x.get_text() for x in ax0.texts]
    (ticks,) = [ln for ln in ax0.lines if ln.get_label() == "wrong-partition step"]
    assert list(ticks.get_xdata()) == pytest.approx([0.7, 2.2])
    (mine,) = [ln for ln in fig.axes[2].lines if ln.get_label() == "this drone on the wrong side"]
    assert list(mine.get_xdata()) == pytest.approx([0.7, 2.2])
    assert not [ln for ln in fig.axes[0].lines if ln.get_label() == "this drone on the wrong side"]
    assert [p for p in fig.axes[1].patches if p.get_label() == "crashed (not reporting)"]
    assert fig.axes[1].get_title() == "drone 2 (crashed at 1.5 s)" and fig.axes[0].get_title() == "drone 1"
    assert "wrong partition in 2 steps" in fig._suptitle.get_text()


def test_error_over_time_of_a_large_swarm_draws_every_faulty_drone_and_summarises_the_rest(drawn):
    # 64 panels would take seconds and say nothing: the drones with something to see get a
    # panel each, the others one panel of median and maximum; none is silently dropped
    S, n = 30, 64
    t = np.arange(S) * 0.1
    no = np.zeros((S, n), bool)
    spoofed, outage, alive, wrong = no.copy(), no.copy(), np.ones((S, n), bool), no.copy()
    spoofed[10:, [4, 40]] = True
    outage[5:20, 50] = True
    alive[12:, 63] = False
    wrong[[7, 8], 21] = True  # an honest drone flagged
    errors = _errors(S, n)
    errors["swarmraft"][:, 30] = 9.0  # the worst of the others: their maximum
    vm.error_over_time(t, errors, spoofed, outage, [], "x.png", alive=alive, wrong=wrong)
    fig = drawn[0]
    titles = [ax.get_title() for ax in fig.axes if ax.axison]
    assert titles[:5] == ["drone 5", "drone 22", "drone 41", "drone 51", "drone 64 (crashed at 1.2 s)"]
    assert titles[5] == "the other 59 drones: median (solid), maximum (thin)" and len(titles) == 6
    rest = [ax for ax in fig.axes if ax.get_title().startswith("the other")][0]
    sr = [np.asarray(ln.get_ydata()) for ln in rest.lines if ln.get_color() == "tab:blue"]
    assert sorted(float(y.max()) for y in sr) == [0.0, 9.0]  # median 0 m, maximum 9 m
    assert "5 of 64 drones drawn one by one" in fig._suptitle.get_text()


def test_swarm_maps_tie_spoofed_reports_to_their_drones_and_labels_do_not_overlap(drawn):
    rng = np.random.default_rng(3)
    n = 9
    truth = np.repeat(rng.uniform(0, 20, (1, n, 3)), 2, axis=0)  # crowded: 9 drones in 20 m
    rep = truth + rng.normal(0, 1.0, truth.shape)
    spoofed = np.zeros((2, n), bool)
    spoofed[:, [1, 4]] = True
    rep[:, [1, 4]] += [25.0, -10.0, 0.0]
    alive = np.ones((2, n), bool)
    alive[:, 6] = False
    rep[:, 6] = np.nan
    outage = np.zeros((2, n), bool)
    outage[:, 8] = True
    vm.swarm_maps(
        truth, rep, truth, spoofed, [1], np.arange(2.0), "x.png", spoofed=spoofed, outage=outage, alive=alive
    )
    fig = drawn[0]
    ax = fig.axes[0]
    ties = [ln for ln in ax.lines if ln.get_label() == "spoofed report - its drone"]
    ends = sorted(tuple(np.round(ln.get_xydata()[1], 6)) for ln in ties)
    assert ends == sorted(tuple(np.round(rep[1, i, :2], 6)) for i in (1, 4))
    labels = dict(zip(*ax.get_legend_handles_labels()[::-1], strict=True))
    assert "crashed (no report)" in labels and "jammed (reports its INS)" in labels
    fig.canvas.draw()
    boxes = [x.get_window_extent() for x in ax.texts]
    assert len(boxes) == n + 2  # every drone, and the two spoofed reports (n')
    for a, b in itertools.combinations(boxes, 2):
        assert not a.overlaps(b)


def test_recovery_rings_failed_recoveries(drawn):
    truth = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0], [0, 0, 50], [50, 50, 50], [25, 25, 25.0]])
    att = np.array([1, 1, 0, 0, 0, 0], bool)
    rep = truth + att[:, None] * 30.0
    ver = truth.copy()
    ver[1] += [40.0, 0, 0]  # drone 2 recovered 40 m off
    case = {"truth": truth, "reported": rep, "verified": ver, "attackers": att, "faulty": att}
    vf.recovery([case], "x.png")
    ax = drawn[0].axes[0]
    (ring,) = [c for c in ax.collections if c.get_label().startswith("failed recovery")]
    np.testing.assert_allclose(ring.get_offsets(), [ver[1, :2]])
    assert "40 m" in " ".join(x.get_text() for x in ax.texts)
    assert "1 of 2" in ax.get_title()


def test_recovery_counts_an_attacked_drone_not_placed_as_failed(drawn):
    """Neither attacked drone placed (verified nan): the title said "verified nan m; failed
    recoveries: 0 of 2" (a review); a drone not placed is a failed recovery."""
    truth = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0], [0, 0, 50], [50, 50, 50], [25, 25, 25.0]])
    att = np.array([1, 1, 0, 0, 0, 0], bool)
    ver = truth.copy()
    ver[:2] = np.nan
    case = {"truth": truth, "reported": truth + att[:, None] * 30.0, "verified": ver, "attackers": att}
    vf.recovery([case], "x.png")
    title = drawn[0].axes[0].get_title()
    assert "failed recoveries: 2 of 2 (2 not placed)" in title and "none placed" in title, title


@pytest.fixture(scope="module")
def reference_sweep(tmp_path_factory):
    """A small finished reference sweep (n = 6, f = 2, 10 trials)."""
    out = tmp_path_factory.mktemp("sweep") / "r"
    args = ["sweep", "--preset", "reference", "--n", "6", "--f", "2", "--trials", "10", "--workers", "1"]
    run = CliRunner().invoke(main, [*args, "--out", str(out)])
    assert run.exit_code == 0, run.output
    return out


def test_recovery_3d_is_its_own_file(reference_sweep):
    out = reference_sweep
    assert CliRunner().invoke(main, ["figure", "recovery", str(out)]).exit_code == 0
    flat = (out / "figures" / "recovery.png").read_bytes()
    res = CliRunner().invoke(main, ["figure", "recovery", str(out), "--view", "3d"])
    assert res.exit_code == 0, res.output
    assert (out / "figures" / "recovery_3d.png").exists()
    assert (out / "figures" / "recovery.png").read_bytes() == flat


def test_sweep_figure_titles_name_preset_detector_and_trials(reference_sweep, drawn):
    from swarmraft.cli.sweeps import draw_figures

    draw_figures("all", reference_sweep)
    scaling, distribution, recovery = drawn
    labels = "preset reference, detector paper, attack jump"
    assert labels in scaling.axes[0].get_title()
    assert labels in distribution.axes[0].get_title()
    assert "10 trials per cell" in distribution.axes[0].get_title()
    title = recovery._suptitle.get_text()
    assert labels in title and "one trial per (n, f)" in title and "seed 2025" in title


def test_distribution_counts_the_trials_it_draws(drawn):
    trials = {
        "n": np.array([5] * 4 + [7] * 6),
        "f": np.array([2] * 4 + [3] * 6),
        "baseline": np.full(10, 30.0),
        "recovered": np.full(10, 1.0),
    }
    vf.distribution(trials, "x.png", "preset realistic, detector joint, attack jump")
    title = drawn[0].axes[0].get_title()
    assert "4-6 trials per cell" in title and "preset realistic, detector joint" in title


def test_distribution_counts_undetermined_trials_instead_of_drawing_nothing(drawn):
    trials = {
        "n": np.array([5] * 4 + [7] * 4),
        "f": np.array([2] * 4 + [3] * 4),
        "baseline": np.full(8, 30.0),
        "recovered": np.array([np.nan] * 4 + [1.0, np.nan, 2.0, 3.0]),
    }
    vf.distribution(trials, "x.png")
    ticks = [t.get_text() for t in drawn[0].axes[0].get_xticklabels()]
    assert ticks == ["(5,2)\n4 of 4\nundetermined", "(7,3)\n1 of 4\nundetermined"]


@pytest.mark.parametrize("draw", ["latency", "messages"])
def test_mission_timelines_mark_faults_the_same_way(drawn, draw):
    t = np.arange(30) * 0.1
    events = [(1.5, "leader 2 crashed")]
    if draw == "latency":
        vm.consensus_latency(t, np.full(30, 7.0), events, "x.png")
    else:
        vm.messages_per_step(t, np.full(30, 60), np.full(30, 9), 9, "x.png", events)
    ax = drawn[0].axes[0]
    (line,) = [ln for ln in ax.lines if ln.get_label() == "fault"]
    assert list(line.get_xdata()) == [1.5, 1.5]
    assert [x.get_text() for x in ax.texts] == ["leader 2 crashed"]


def test_efficiency_interval_covers_the_true_efficiency_as_often_as_it_says():
    rng = np.random.default_rng(1)

    def sample(size):
        bound = rng.uniform(1.0, 3.0, size)
        return bound * rng.chisquare(3, size) / 3 * 2.0, bound  # squared error ~ 2 x bound

    covered = 0
    for k in range(200):
        sq, b = sample(200)
        lo, hi = efficiency_interval(sq, b, np.random.default_rng(k), resamples=400)
        covered += lo <= np.sqrt(2.0) <= hi
    assert 0.90 <= covered / 200 <= 0.99  # a 95 % interval


def test_efficiency_interval_stays_above_the_trials_without_their_heavy_tail():
    # 249 trials at the bound and one far off (a spoof missed by tens of metres): the
    # delta method's symmetric interval reached below 1; the bootstrap's cannot go below the
    # efficiency of the trials without the tail
    sq = np.concatenate([np.full(249, 1.0), [2000.0]])
    bound = np.ones(250)
    eff = np.sqrt(sq.mean())
    lo, hi = efficiency_interval(sq, bound, np.random.default_rng(0))
    assert 1.0 <= lo < eff < hi
    ratio = np.mean(sq) / np.mean(bound)
    delta = (sq - ratio * bound).std(ddof=1) / np.sqrt(250) / bound.mean() / (2 * eff)
    assert eff - 1.96 * delta < 1.0  # what the delta method drew


def test_efficiency_interval_is_reproducible_and_says_nan_without_trials():
    sq, bound = np.array([1.0, 2.0, 3.0, np.nan]), np.array([1.0, 1.0, np.nan, 1.0])
    a = efficiency_interval(sq, bound, np.random.default_rng(5))
    assert a == efficiency_interval(sq, bound, np.random.default_rng(5))
    assert np.isnan(efficiency_interval(sq[:1], bound[:1], np.random.default_rng(5))).all()
    # only the trials with both an error and a bound (1 and 2): within their range
    assert np.sqrt(1.0) <= a[0] <= a[1] <= np.sqrt(2.0)


def test_compare_table_standard_errors_come_from_the_cells_trials():
    trials = {
        "n": np.array([9, 9, 9, 13]),
        "f": np.array([3, 3, 3, 3]),
        "honest": np.array([1.0, 2.0, 4.0, 100.0]),
        "detection_rate": np.array([1.0, 0.0, 1.0, 0.0]),
        "false_positive_rate": np.zeros(4),
        "identified": np.array([1, 0, 1, 0]),
        "attacked_sq": np.array([1.0, 2.0, 3.0, 9.0]),
        "attacked_bound": np.array([1.0, 1.0, 1.0, 1.0]),
    }
    s = cell_sems(trials, 9, 3, seed=7)
    assert s["honest_sem"] == pytest.approx(np.std([1.0, 2.0, 4.0], ddof=1) / np.sqrt(3))
    assert s["identification_rate_sem"] == pytest.approx(np.std([1, 0, 1], ddof=1) / np.sqrt(3))
    # the efficiency's interval from the cell's own trials (not (13, 3)'s 9), seeded by
    # (seed, n, f)
    want = efficiency_interval(np.array([1.0, 2.0, 3.0]), np.ones(3), np.random.default_rng([7, 9, 3]))
    assert (s["attacked_efficiency_lo"], s["attacked_efficiency_hi"]) == want
    assert 1.0 <= want[0] < want[1] <= np.sqrt(3.0)


def test_compare_draws_the_efficiency_interval_from_its_bounds(drawn):
    t = _table([(9, 3), (13, 3)], ["joint"])
    t["attacked_efficiency"] = np.array([2.99, 1.2])
    t["attacked_efficiency_lo"] = np.array([1.3, 1.1])
    t["attacked_efficiency_hi"] = np.array([5.0, 1.4])
    viz.compare(t, "attacked_efficiency", "efficiency", True, "x.png", reference=1.0)
    (fig,) = drawn
    caps = [ln for ln in fig.axes[0].lines if ln.get_marker() == "_"]
    ends = np.sort(np.concatenate([ln.get_ydata() for ln in caps]))
    np.testing.assert_allclose(ends, [1.1, 1.3, 1.4, 5.0])
    assert "bootstrap" in fig._suptitle.get_text()


def test_curve_points_name_their_threshold_parameter():
    p = CurvePoint("paper", "roc", "tau", 1.0, 10.0, 0.0, 0.5)
    assert [getattr(p, c) for c in CURVE_COLUMNS][:4] == ["paper", "roc", "tau", 1.0]


def test_scaling_draws_tiny_means_where_they_are_not_at_a_floor(drawn):
    n = np.array([7, 9])
    cells = _scaling_cells(n, (n - 1) // 2, "realistic", "paper", 28.8, [6.8e-15, 0.0], 1e-16)
    viz.scaling(cells, "x.png")
    ax = drawn[0].axes[0]
    (rec,) = [c for c in ax.containers if c.get_label().startswith("verified")]
    assert rec.lines[0].get_ydata()[0] == 6.8e-15
    assert "(9,4): mean 0 m" in [x.get_text() for x in ax.texts]


def test_scaling_with_several_f_per_n_draws_each_fs_interval_beside_the_others(drawn):
    n, f = np.array([9, 9, 13, 13]), np.array([2, 4, 2, 4])
    cells = _scaling_cells(n, f, "realistic", "joint", 55.0, [1.9, 2.9, 1.4, 1.6], [0.1, 0.4, 0.05, 0.1])
    viz.scaling(cells, "x.png")
    ax = drawn[0].axes[0]
    bars = {c.get_label(): c for c in ax.containers if c.get_label().startswith("verified")}
    assert sorted(bars) == ["verified, f = 2", "verified, f = 4"]
    x2, x4 = (bars[k].lines[0].get_xdata() for k in sorted(bars))
    assert (x2 < x4).all() and np.allclose(x4 - x2, 0.12)  # apart, not on top of each other
    seg = bars["verified, f = 4"].lines[2][0].get_segments()[0]  # the first point's bar
    assert np.allclose([seg[0][1], seg[1][1]], [2.9 - 1.96 * 0.4, 2.9 + 1.96 * 0.4])
    assert ax.get_legend().get_bbox_to_anchor().x0 >= ax.get_window_extent().x1 - 1  # beside the axes


def test_the_stanford_diagram_marks_the_alert_limit_and_the_axis_reaches_it():
    """With an alert limit (70 m) the panel draws it (dashed, the region beyond shaded:
    unavailable) and its axis reaches it even when every level is far below; without one,
    nothing is drawn there."""
    import matplotlib.pyplot as plt

    from swarmraft.viz.integrity import _panel

    err, pl = np.array([0.05, 0.1, 0.2]), np.array([0.5, 0.8, 1.2])
    fig, (a, b) = plt.subplots(1, 2)
    _panel(a, err, pl, "horizontal", 70.0)
    _panel(b, err, pl, "horizontal", None)
    vertical = [ln for ln in a.get_lines() if np.allclose(ln.get_xdata(), 70.0)]
    assert len(vertical) == 1 and a.get_xlim()[1] >= 70.0
    assert any("alert limit 70 m" in t.get_text() for t in a.texts)
    assert not any("alert limit" in t.get_text() for t in b.texts) and b.get_xlim()[1] < 70.0
    plt.close(fig)
