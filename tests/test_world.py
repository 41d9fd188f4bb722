"""Each sensor and attack model produces the statistics of its parameters."""

import numpy as np
import pytest

from swarmraft.experiments import build_config
from swarmraft.experiments.trials import draw
from swarmraft.world import (
    AreaSpoof,
    Attack,
    ExactRanging,
    GaussMarkov,
    GNSSModel,
    Jump,
    RangeTamper,
    RigidCollusion,
    RSSIRanging,
    UWBRanging,
    choose_attackers,
    formation,
    true_distances,
    uniform_cube,
)


def off_diagonal(a):
    n = a.shape[-1]
    return a[..., ~np.eye(n, dtype=bool)]


def test_uniform_cube_bounds_and_moments(rng):
    p = uniform_cube(rng, 4000, 5, 100.0)
    assert p.shape == (4000, 5, 3) and p.min() >= 0 and p.max() <= 100
    assert p.mean() == pytest.approx(50, abs=0.5)
    assert p.std() == pytest.approx(100 / np.sqrt(12), rel=0.01)


def test_formation_spacing(rng):
    p = formation(rng, 3, 9, spacing=20.0, layers=1)
    d = off_diagonal(true_distances(p))
    assert d.min() == pytest.approx(20.0)
    assert np.allclose(p[..., 2], 50.0)


def test_gnss_white_sigmas_per_axis(rng):
    e = GNSSModel(1.5, 3.0).errors(rng, 20000, 4)
    np.testing.assert_allclose(e.reshape(-1, 3).std(axis=0), [1.5, 1.5, 3.0], rtol=0.01)
    np.testing.assert_allclose(e.reshape(-1, 3).mean(axis=0), 0, atol=0.03)


def test_gnss_common_component_is_shared(rng):
    e = GNSSModel(1.0, 1.0, common_h=2.0, common_v=2.0).errors(rng, 20000, 2)
    c = np.corrcoef(e[:, 0, 0], e[:, 1, 0])[0, 1]
    assert c == pytest.approx(4 / 5, abs=0.02)  # common var / total var
    assert e[:, 0, 0].std() == pytest.approx(np.sqrt(5), rel=0.02)


def test_gauss_markov_variance_and_correlation(rng):
    gm = GaussMarkov(sigma_h=2.0, sigma_v=4.0, tau=10.0, dt=1.0)
    e = gm.sequence(rng, 4000, 50)
    np.testing.assert_allclose(e.reshape(-1, 3).std(axis=0), [2, 2, 4], rtol=0.03)
    x = e[:, :, 0]
    lag1 = np.mean(x[1:] * x[:-1]) / np.mean(x * x)
    assert lag1 == pytest.approx(np.exp(-0.1), abs=0.01)


@pytest.mark.parametrize("mode", ["link", "direction"])
def test_uwb_nlos_per_link_shares_the_bias_in_both_directions(rng, mode):
    """Per link, d_ij and d_ji carry the same NLOS bias (the path is shared); per direction,
    each carries its own, so about half the biased links are biased one way only."""
    p = uniform_cube(rng, 500, 7)
    true = true_distances(p)
    bias = UWBRanging(sigma=0.0, nlos_prob=0.3, nlos_mode=mode).measure(rng, p) - true
    back = np.swapaxes(bias, 1, 2)
    hit = bias > 0
    assert np.mean(off_diagonal(hit)) == pytest.approx(0.3, abs=0.01)
    one_way = off_diagonal(hit ^ (back > 0)).mean()
    if mode == "link":
        np.testing.assert_allclose(bias, back, atol=1e-9)
        assert one_way == 0
    else:
        assert one_way == pytest.approx(2 * 0.3 * 0.7, abs=0.02)
        assert np.abs(bias - back).max() > 0.1


@pytest.mark.parametrize(
    "model",
    [
        UWBRanging(0.1),
        UWBRanging(0.1, max_range=60.0, symmetric=True),
        UWBRanging(0.1, nlos_prob=0.3),
        UWBRanging(0.1, nlos_prob=0.3, nlos_mode="direction"),
    ],
)
def test_uwb_many_steps_at_once_are_the_steps_one_by_one(model, monkeypatch):
    """`measure_steps` (a mission's world, built in chunks of steps) must give exactly what
    measuring step by step gives, and leave the generator where step by step leaves it."""
    from swarmraft.world import ranging

    monkeypatch.setattr(ranging, "_CHUNK_FLOATS", 3 * 7 * 7 * 4)  # chunks of 4 steps: 23 = 5 x 4 + 3
    pos = np.random.default_rng(0).uniform(0, 80, (23, 7, 3))
    one, many = np.random.default_rng(1), np.random.default_rng(1)
    want = np.stack([model.measure(one, p[None])[0] for p in pos])
    got = model.measure_steps(many, pos)
    assert np.array_equal(got, want, equal_nan=True)
    assert one.random() == many.random()


def test_uwb_nlos_mode_is_validated():
    with pytest.raises(ValueError, match="nlos_mode"):
        UWBRanging(nlos_prob=0.1, nlos_mode="path")


def test_exact_ranging_is_true_and_symmetric(rng):
    p = uniform_cube(rng, 10, 6)
    r = ExactRanging().measure(rng, p)
    np.testing.assert_array_equal(r, true_distances(p))


def test_uwb_noise_nlos_and_max_range(rng):
    p = uniform_cube(rng, 2000, 6)
    true = off_diagonal(true_distances(p))
    err = off_diagonal(UWBRanging(sigma=0.1).measure(rng, p)) - true
    assert err.mean() == pytest.approx(0, abs=0.003)
    assert err.std() == pytest.approx(0.1, rel=0.02)
    nl = off_diagonal(UWBRanging(sigma=0.0, nlos_prob=0.25, nlos_bias=(0.3, 1.0)).measure(rng, p)) - true
    assert np.mean(nl > 0) == pytest.approx(0.25, abs=0.01)
    assert nl[nl > 0].mean() == pytest.approx(0.65, abs=0.01)
    cut = UWBRanging(max_range=60.0).measure(rng, p)
    assert np.isnan(off_diagonal(cut)).mean() == pytest.approx(np.mean(true > 60), abs=1e-12)


def test_uwb_symmetric_option(rng):
    p = uniform_cube(rng, 5, 5)
    r = UWBRanging(sigma=0.1, symmetric=True).measure(rng, p)
    np.testing.assert_array_equal(r, np.swapaxes(r, 1, 2))
    r2 = UWBRanging(sigma=0.1).measure(rng, p)
    assert not np.allclose(r2, np.swapaxes(r2, 1, 2))


def test_rssi_lognormal_shadowing(rng):
    p = uniform_cube(rng, 3000, 5)
    m = RSSIRanging(shadowing_db=6.0, exponent=3.0)
    ratio = off_diagonal(m.measure(rng, p)) / off_diagonal(true_distances(p))
    x_db = 10 * 3.0 * np.log10(ratio)
    assert x_db.mean() == pytest.approx(0, abs=0.1)
    assert x_db.std() == pytest.approx(6.0, rel=0.02)


def test_choose_attackers_exact_count_uniform(rng):
    a = choose_attackers(rng, 20000, 7, 3)
    assert (a.sum(axis=1) == 3).all()
    np.testing.assert_allclose(a.mean(axis=0), 3 / 7, atol=0.015)


def test_box_jump_statistics(rng):
    off = Jump("box", half_width=30).offsets(rng, 50000)
    assert np.abs(off).max() <= 30
    assert np.abs(off).mean() == pytest.approx(15, rel=0.01)
    assert np.linalg.norm(off, axis=1).mean() == pytest.approx(28.8, abs=0.15)  # FACTS.md


def test_shell_jump_statistics(rng):
    off = Jump("shell", low=10, high=100).offsets(rng, 50000)
    mag = np.linalg.norm(off, axis=1)
    assert mag.min() >= 10 and mag.max() <= 100
    assert mag.mean() == pytest.approx(55, rel=0.01)
    np.testing.assert_allclose((off / mag[:, None]).mean(axis=0), 0, atol=0.01)  # isotropic


@pytest.mark.parametrize("k", [1, 2, 3])
def test_rigid_collusion_keeps_ranges_to_pivots_and_among_attackers(rng, k):
    T, n, f = 200, 9, 4
    truth = uniform_cube(rng, T, n)
    att = choose_attackers(rng, T, n, f)
    rep = RigidCollusion(pivots=k).reports(rng, truth, truth.copy(), att)
    D_true, D_rep = true_distances(truth), true_distances(rep)
    # attackers moved, honest did not
    assert (np.linalg.norm(rep - truth, axis=2)[att] > 1e-6).mean() > 0.95
    np.testing.assert_array_equal(rep[~att], truth[~att])
    # distances among attackers are preserved
    pair_att = att[:, :, None] & att[:, None, :]
    np.testing.assert_allclose(D_rep[pair_att], D_true[pair_att], atol=1e-9)
    # exactly k honest drones keep every range to the attackers (the pivots)
    consistent = np.isclose(D_rep, D_true, atol=1e-9) | ~att[:, :, None]
    pivots = (~att) & consistent.all(axis=1)
    assert (pivots.sum(axis=1) >= k).all()
    assert np.mean(pivots.sum(axis=1) == k) > 0.95


@pytest.mark.parametrize("k", [1, 2, 3])
def test_rigid_collusion_min_move_moves_every_attacker_that_far(k):
    T, n, f = 300, 12, 4
    rng = np.random.default_rng(k)
    truth = uniform_cube(rng, T, n)
    att = choose_attackers(rng, T, n, f)
    plain = RigidCollusion(pivots=k).reports(np.random.default_rng(9), truth, truth.copy(), att)
    assert (np.linalg.norm(plain - truth, axis=2)[att] < 30).any(axis=0).any()  # without: some do not
    same = RigidCollusion(pivots=k, min_move=0.0).reports(np.random.default_rng(9), truth, truth.copy(), att)
    np.testing.assert_array_equal(same, plain)  # 0: the draws of before, bit for bit
    attack = {"name": f"collusion-{k}", "min_move": 30.0}
    cfg = build_config("realistic", n=(n,), f=(f,), trials=T, attack=attack)
    d = draw(cfg, np.random.default_rng(k), T, n, f)
    moved = np.linalg.norm(d.reported - d.truth, axis=2)
    assert (moved[d.attackers] >= 30.0).all()
    # still a rigid motion about k honest pivots: distances among attackers kept
    pair = d.attackers[:, :, None] & d.attackers[:, None, :]
    np.testing.assert_allclose(true_distances(d.reported)[pair], true_distances(d.truth)[pair], atol=1e-9)


def test_rigid_collusion_min_move_out_of_reach_is_one_line_naming_it():
    attack = {"name": "collusion-3", "min_move": 500.0}
    cfg = build_config("realistic", n=(7,), f=(3,), trials=5, attack=attack)
    with pytest.raises(ValueError, match=r"^attack\.min_move: ") as exc:
        draw(cfg, np.random.default_rng(0), 5, 7, 3)
    assert "\n" not in str(exc.value)


def test_area_spoof_all_victims_report_one_point(rng):
    truth = uniform_cube(rng, 50, 8)
    att = choose_attackers(rng, 50, 8, 3)
    rep = AreaSpoof().reports(rng, truth, truth.copy(), att)
    for t in range(50):
        pts = rep[t][att[t]]
        assert np.allclose(pts, pts[0])
    np.testing.assert_array_equal(rep[~att], truth[~att])


def test_range_tampering_consistent_and_bias(rng):
    truth = uniform_cube(rng, 20, 7)
    att = choose_attackers(rng, 20, 7, 2)
    ranges = ExactRanging().measure(rng, truth)
    rep, r = Attack(Jump(), RangeTamper("consistent")).apply(rng, truth, truth.copy(), ranges, att)
    fake = true_distances(rep)
    rows = att[:, :, None] & ~np.eye(7, dtype=bool)
    np.testing.assert_allclose(r[rows], fake[rows])
    np.testing.assert_array_equal(r[~rows], ranges[~rows])
    b = RangeTamper("bias", bias=2.5).ranges(rep, ranges, att)
    np.testing.assert_allclose((b - ranges)[rows], 2.5)
    pair = RangeTamper("bias", bias=1.0, pairs=((0, 1),)).ranges(rep, ranges, att)
    assert np.allclose(pair[:, 0, 1] - ranges[:, 0, 1], 1.0)
    assert np.count_nonzero(pair - ranges) == 20


def test_bad_model_parameters(rng):
    with pytest.raises(ValueError, match="sigma"):
        GNSSModel(-1.0, 1.0)
    with pytest.raises(ValueError, match="nlos_prob"):
        UWBRanging(nlos_prob=2)
    with pytest.raises(ValueError, match="f must be"):
        choose_attackers(rng, 1, 3, 4)
    with pytest.raises(ValueError, match="pivots"):
        RigidCollusion(pivots=4)
