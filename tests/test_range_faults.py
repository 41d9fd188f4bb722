"""Range faults by link (issue 11, items 2 and 4): distance enlargement in the world, and the
range screening every detector's ranges go through (`estimation.links`)."""

import numpy as np
import pytest

from swarmraft.estimation import verify_batch
from swarmraft.estimation.links import screen
from swarmraft.experiments import build_config
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.trials import chunk_seed, draw, snapshot_batch
from swarmraft.world import Attack, DistanceEnlargement, UWBRanging, true_distances, uniform_cube


def test_enlargement_lengthens_exactly_the_attackers_links(rng):
    truth = uniform_cube(rng, 50, 8)
    clean = UWBRanging(sigma=0.1).measure(rng, truth)
    clean[:, 2, 5] = np.nan  # an unmeasured direction stays unmeasured
    att = np.zeros((50, 8), dtype=bool)
    att[:, [1, 4]] = True
    _, ranges = Attack(None, enlargement=DistanceEnlargement(3.0, 3.0)).apply(rng, truth, truth, clean, att)
    want = np.zeros((8, 8))
    want[[1, 4], :] += 3.0
    want[:, [1, 4]] += 3.0  # a link of two enlargers: both delays
    np.fill_diagonal(want, 0.0)
    got = ranges - clean
    assert np.isnan(ranges[:, 2, 5]).all()
    got[:, 2, 5] = want[2, 5]
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), atol=1e-12)
    # drawn per attacker and trial in [low, high]
    _, r2 = Attack(None, enlargement=DistanceEnlargement(2.0, 10.0)).apply(rng, truth, truth, clean, att)
    d = (r2 - clean)[:, 1, 0]
    assert d.min() >= 2.0 and d.max() <= 10.0 and d.std() > 1.0
    with pytest.raises(ValueError, match="DistanceEnlargement"):
        DistanceEnlargement(5.0, 2.0)


def test_enlarge_attack_names_build_and_validate():
    from swarmraft.experiments.config import ConfigError

    attack = {"name": "enlarge-jump", "enlarge_low": 4, "enlarge_high": 6}
    cfg = build_config("realistic", n=(11,), attack=attack)
    a = cfg.attack.model()
    assert a.enlargement == DistanceEnlargement(4.0, 6.0) and a.position is not None
    assert build_config("realistic", attack={"name": "enlarge"}).attack.model().position is None
    with pytest.raises(ConfigError, match="enlarge_high must be >= enlarge_low"):
        build_config("realistic", attack={"name": "enlarge", "enlarge_low": 6, "enlarge_high": 2})


def _exact_shape(rng, n=12):
    truth = uniform_cube(rng, 1, n)
    return truth, true_distances(truth)


def test_screen_drops_one_nlos_link_per_link_and_per_direction(rng):
    truth, exact = _exact_shape(rng)
    noisy = exact + 0.01 * rng.standard_normal(exact.shape)
    np.fill_diagonal(noisy[0], 0.0)
    link = noisy.copy()
    link[0, 2, 7] += 0.5
    link[0, 7, 2] += 0.5  # the path's bias, in both directions
    s = screen(link, 0.01)
    assert s.dropped[0, 2, 7] and s.dropped[0, 7, 2]
    assert s.dropped.sum() == 2 and not s.enlarged.any()
    assert np.isnan(s.ranges[0, 2, 7]) and np.isnan(s.ranges[0, 7, 2])
    one = noisy.copy()
    one[0, 3, 9] += 0.5  # one direction only
    s = screen(one, 0.01)
    assert s.dropped[0, 3, 9] and s.dropped.sum() <= 2 and not s.enlarged.any()
    # a link reading short is no NLOS (a path is never shorter than the straight line): the
    # screening leaves it to the detectors
    short = noisy.copy()
    short[0, 2, 7] -= 0.5
    short[0, 7, 2] -= 0.5
    assert not screen(short, 0.01).dropped[0, 2, 7]
    # clean ranges: nothing found, nothing changed
    s = screen(noisy, 0.01)
    assert not s.changed and np.array_equal(s.ranges, noisy, equal_nan=True)


def test_screen_finds_an_enlarged_drone_and_its_delay(rng):
    truth, exact = _exact_shape(rng, 13)
    noisy = exact + 0.01 * rng.standard_normal(exact.shape)
    np.fill_diagonal(noisy[0], 0.0)
    # the drone nearest the middle: an edge drone could move outwards instead (module docstring)
    mid = int(np.argmin(np.linalg.norm(truth[0] - truth[0].mean(axis=0), axis=1)))
    delay = np.zeros((1, 13))
    delay[0, mid] = 4.0
    from swarmraft.world.attacks import enlarge

    s = screen(enlarge(noisy, delay), 0.01)
    assert s.enlarged[0].tolist() == [i == mid for i in range(13)]
    assert s.delta[0, mid] == pytest.approx(4.0, abs=0.05)
    kept = ~np.isnan(s.ranges)
    assert (~kept).sum() <= 2  # a clean range beyond 3 sigma may go, once something read long
    np.testing.assert_allclose(s.ranges[kept], noisy[kept], atol=0.05)  # corrected


def test_tampered_rows_are_left_for_the_detectors(rng):
    truth, exact = _exact_shape(rng, 10)
    r = exact.copy()
    r[0, 4, :] += rng.uniform(3, 9, 10)  # drone 4 reports its own ranges wrong
    r[0, 4, 4] = 0.0
    s = screen(r, 0.01)
    assert s.tampering[0].tolist() == [i == 4 for i in range(10)]
    assert not s.dropped[0, 4].any()


def test_a_clean_batch_gives_the_unscreened_verdict_bit_for_bit(rng):
    cfg = build_config("realistic", n=(9,), trials=30)
    d = draw(cfg, np.random.default_rng(chunk_seed(7, 9, 2, 0)), 30, 9, 2)
    b = snapshot_batch(cfg, d)
    for det in ("clique", "fde", "joint"):
        a, o = verify_batch(b, det), verify_batch(b, det, links="off")
        assert np.array_equal(a.positions, o.positions, equal_nan=True)
        assert np.array_equal(a.faulty, o.faulty) and np.array_equal(a.status, o.status)


def _flag_rates(det, n, f, trials, seed, **world):
    cfg = build_config("realistic", n=(n,), trials=trials, seed=seed, **world)
    cfg = cfg.model_copy(update={"detector": det})
    d = draw(cfg, np.random.default_rng(chunk_seed(seed, n, f, 3)), trials, n, f)
    params, _ = detector_settings(cfg, n)
    v = verify_batch(snapshot_batch(cfg, d), det, **params)
    return d, v


@pytest.mark.parametrize("mode", ["link", "direction"])
@pytest.mark.parametrize("det", ["clique", "fde", "joint"])
def test_nlos_drops_links_not_drones(det, mode):
    """NLOS on 20 % of links, no attack, n = 13: few honest drones flagged, and verdicts
    usable (before the screening: clique 34 %, fde 46 % flagged per direction; every
    verdict an alarm)."""
    ranging = {"kind": "uwb", "sigma": 0.1, "nlos_prob": 0.2, "nlos_mode": mode}
    d, v = _flag_rates(det, 13, 0, 60, 11, ranging=ranging)
    assert v.faulty.mean() <= 0.03
    assert (v.status == "ok").mean() >= 0.8
    # the same truth and GNSS with clean links (the NLOS draws come after them)
    d0, v0 = _flag_rates(det, 13, 0, 60, 11, ranging={"kind": "uwb", "sigma": 0.1})
    np.testing.assert_array_equal(d.reported, d0.reported)
    err = np.nanmean(np.linalg.norm(v.positions - d.truth, axis=2))
    assert err <= 1.3 * np.nanmean(np.linalg.norm(v0.positions - d0.truth, axis=2))


def test_distance_enlargement_is_detected():
    """f = 2 of n = 11 enlarge their distances by 2-10 m: the joint detector flags them
    (before the screening: 62 % of attackers, 42 % of trials with both)."""
    d, v = _flag_rates("joint", 11, 2, 100, 5, attack={"name": "enlarge"})
    assert v.faulty[d.attackers].mean() >= 0.85
    assert v.faulty[~d.attackers].mean() <= 0.02
    assert v.diagnostics["enlargement"][d.attackers].mean() > 2.0


def test_enlargement_in_a_mission_reaches_the_ranges():
    from swarmraft.sim.scenario import Scenario
    from swarmraft.sim.sensing import ScenarioWorld

    sc = Scenario(
        drones=6,
        duration_s=2,
        seed=1,
        spoof=[{"kind": "enlarge", "drones": [2], "start_s": 1.0, "enlarge": 5.0}],
    )
    w = ScenarioWorld.build(sc)
    ins = np.zeros((6, 3))
    before, after = w.measured_ranges(5, ins), w.measured_ranges(15, ins)
    np.testing.assert_array_equal(before, w.ranges[5])
    want = w.ranges[15].copy()
    want[1, :] += 5.0
    want[:, 1] += 5.0
    want[1, 1] = w.ranges[15][1, 1]
    np.testing.assert_allclose(after, want)
    assert w.spoofed[15, 1] and not w.spoofed[5, 1]
    honest = w.traj.positions[15, 1] + w.gnss_err[15, 1]
    np.testing.assert_allclose(w.fix[15, 1], honest)  # its GNSS stays honest
    with pytest.raises(ValueError, match="enlarge"):
        Scenario(drones=6, spoof=[{"kind": "enlarge", "drones": [2], "start_s": 1.0}])


def test_compare_and_curves_take_the_enlargement(tmp_path):
    from click.testing import CliRunner

    from swarmraft.cli import main
    from swarmraft.experiments.tables import read_table

    common = ["--n", "11", "--f", "2", "--detectors", "joint"]
    r = CliRunner().invoke(
        main,
        ["compare", "--attacks", "enlarge", "--trials", "20", "--workers", "1", "--out", str(tmp_path / "c")]
        + common,
    )
    assert r.exit_code == 0, r.output
    t = read_table(tmp_path / "c" / "compare.csv")
    assert list(t["attack"]) == ["enlarge"] and t["detection_rate"][0] >= 0.7
    r = CliRunner().invoke(
        main,
        ["curves", "--attack", "enlarge", "--trials", "10", "--offsets", "0.2,6"]
        + ["--out", str(tmp_path / "k"), *common],
    )
    assert r.exit_code == 0, r.output
    c = read_table(tmp_path / "k" / "curves.csv")
    pd = {o: p for k, o, p in zip(c["kind"], c["offset"], c["detection"], strict=True) if k == "offset"}
    assert pd[6.0] > pd[0.2]  # 6 m of enlargement is seen, 0.2 m (2 sigma) hardly


def test_screen_takes_a_nan_diagonal_and_no_ranges(rng):
    truth, exact = _exact_shape(rng, 8)
    r = exact.copy()
    r[0, np.arange(8), np.arange(8)] = np.nan  # a diagonal left unmeasured
    assert not screen(r, 0.01).changed
    none = np.full((1, 8, 8), np.nan)
    s = screen(none, 0.01)
    assert not s.changed and np.isnan(s.ranges).all()


def test_the_quiet_trials_shortcut_gives_the_full_screening(rng):
    """`screen` leaves the trials its compiled pass calls quiet (`links._quiet`) as they are
    and screens the others in numpy (`links._screen`): the same answer as screening every
    trial, field by field, on a batch of clean trials, NLOS links (both ways, one way, and
    one whose link reads just beyond k sigma in numpy's fit), a link whose two ways disagree
    though their mean fits, a tamperer, a missing pair and a drone out of range."""
    from swarmraft.estimation.links import _fit, _long_z, _mds, _quiet, _screen

    truth = uniform_cube(rng, 12, 11)
    r = true_distances(truth) + 0.01 * rng.standard_normal((12, 11, 11))
    r[:, np.arange(11), np.arange(11)] = 0.0
    r[1, 2, 7] += 0.5
    r[1, 7, 2] += 0.5  # NLOS on a link
    r[2, 3, 9] += 0.5  # one direction
    r[3, 4, :] += rng.uniform(3, 9, 11)  # a tamperer
    r[3, 4, 4] = 0.0
    r[4, 1, 5] = r[4, 5, 1] = np.nan  # a pair out of range either way
    r[5, 6, :] = r[5, :, 6] = np.nan  # a drone ranging no one
    r[7, 2, 7] += 0.04
    r[7, 7, 2] -= 0.04  # two ways 8 sigma apart, their mean (what the fit reads) right
    base = np.ones((1, 11, 11)) - np.eye(11)
    for bias in np.arange(0.02, 0.2, 0.002):  # the smallest bias numpy's fit reads beyond k = 5
        t6 = r[6:7].copy()
        t6[0, 0, 8] += bias
        t6[0, 8, 0] += bias
        z = _long_z(_fit(_mds(t6, None), t6, base, 0.01), t6, base, 0.01).max()
        if z > 5.0:
            break
    assert z < 5.5
    r[6] = t6[0]
    quiet = np.zeros(12, dtype=bool)
    _quiet(r, 0.01, 5.0, quiet)
    assert quiet[[0, 8, 9, 10, 11]].all() and not quiet[1:8].any()
    fast, full = screen(r, 0.01), _screen(r, 0.01, 5.0, 20, 2.0)
    for name in ("ranges", "dropped", "tampering", "enlarged", "delta"):
        assert np.array_equal(getattr(fast, name), getattr(full, name), equal_nan=True), name
    assert fast.dropped[1, 2, 7] and fast.dropped[6].any() and fast.dropped[7, 2, 7] and fast.tampering[3, 4]


def test_the_quiet_shortcut_leaves_flat_and_thin_swarms_to_the_numpy_screening():
    """On a near-flat or near-collinear swarm the shape's fit has more than one minimum, and
    `links._quiet`'s own fit could stop in another than `_screen`'s (a review's case, n = 4:
    `_screen` drops a link, the compiled fit read nothing long; a second review's, a
    near-collinear swarm of 7). Such swarms, and swarms of fewer than QUIET_DRONES, are never
    called quiet; `screen` equals `_screen` on 400 random
    swarms of 4 to 12 drones, flat, thin or round, most with an NLOS link of 3 to 12 sigma."""
    from swarmraft.estimation.links import _quiet, _screen

    nan = np.nan
    case = np.array(
        [
            [
                [nan, 5.452931665057847, 7.744145113622509, 9.61681709039349],
                [5.630168966746759, nan, 2.0993664384157937, 15.10405142298189],
                [7.834647032695564, 2.14498863459236, nan, 18.11900922043098],
                [9.573578200950156, 14.971933484075874, 17.887998647037744, nan],
            ]
        ]
    )
    assert screen(case, 0.1).changed and _screen(case, 0.1, 5.0, 20, 2.0).changed
    # a near-collinear swarm of 7 (a second review's case): only the shape check refuses it
    thin = np.array(
        [
            [
                [
                    nan,
                    30.678147509203974,
                    0.3005702429262779,
                    35.18530244346377,
                    21.81081719805132,
                    9.946480610801355,
                    43.31270628087024,
                ],
                [
                    30.67672368160479,
                    nan,
                    30.3790851611004,
                    4.505195693815888,
                    8.87967129472734,
                    20.733758224729648,
                    12.632942872213558,
                ],
                [
                    0.2982463160214951,
                    30.379427281869397,
                    nan,
                    34.883378392936415,
                    21.503721208851974,
                    nan,
                    43.012563238167374,
                ],
                [
                    35.184568583491526,
                    4.505186898453178,
                    34.88640575098481,
                    nan,
                    13.385253073650775,
                    25.236855903455925,
                    8.130678935021866,
                ],
                [
                    nan,
                    8.878813890284603,
                    21.503712754131623,
                    13.384140798680935,
                    nan,
                    11.853614122605215,
                    21.509102695622538,
                ],
                [
                    9.946479395993405,
                    20.734655602905363,
                    9.647516787690881,
                    25.23874842013954,
                    11.858346965774096,
                    nan,
                    33.36690388876355,
                ],
                [
                    43.310687599655694,
                    12.634123075329825,
                    43.01469067704726,
                    8.12758189120384,
                    21.509132428356605,
                    33.366221481877496,
                    nan,
                ],
            ]
        ]
    )
    sigma_thin = 0.0011749741866833344
    assert screen(thin, sigma_thin).changed and _screen(thin, sigma_thin, 5.0, 20, 2.0).changed
    rng = np.random.default_rng(11)
    quiet_seen = 0
    for _ in range(40):
        n, T = int(rng.integers(4, 13)), 10
        x = rng.normal(size=(T, n, 3)) * rng.choice([5.0, 20.0, 100.0])
        x[..., 2] *= rng.choice([1.0, 0.05, 0.002])
        if rng.random() < 0.3:
            x[..., 1] *= rng.choice([0.05, 0.002])
        sigma = float(rng.choice([0.1, 0.01]))
        r = np.linalg.norm(x[:, :, None] - x[:, None], axis=3) + sigma * rng.standard_normal((T, n, n))
        i = rng.integers(0, n, T)
        j = (i + 1 + rng.integers(0, n - 1, T)) % n
        bias = rng.uniform(3, 12, T) * sigma * (rng.random(T) < 0.6)  # 4 in 10 clean
        r[np.arange(T), i, j] += bias
        r[np.arange(T), j, i] += bias * (rng.random(T) < 0.7)
        r[:, np.arange(n), np.arange(n)] = np.nan
        quiet = np.zeros(T, dtype=bool)
        _quiet(r, sigma, 5.0, quiet)
        quiet_seen += quiet.sum()
        fast, full = screen(r, sigma), _screen(r, sigma, 5.0, 20, 2.0)
        for name in ("ranges", "dropped", "tampering", "enlarged", "delta"):
            assert np.array_equal(getattr(fast, name), getattr(full, name), equal_nan=True), name
    assert quiet_seen > 40  # the shortcut was taken, not only refused
