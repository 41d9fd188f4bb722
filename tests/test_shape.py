"""The `shape` detector: rigid registrations of the range-fixed shape to the reports, and
rigid collusion under realistic noise."""

import math
from itertools import combinations

import numpy as np
import pytest

from swarmraft.estimation import Snapshot, SnapshotBatch, verify, verify_batch
from swarmraft.estimation.registrations import (
    covering_triples,
    procrustes_fit,
    registration_sets,
    rival_seeds,
    shape_ranges,
    triples,
    turan_triples,
)
from swarmraft.experiments import build_config
from swarmraft.experiments.trials import draw, integrity_metrics, snapshot_batch
from swarmraft.world.geometry import true_distances


def collusion(n, f, k, trials, seed=1, min_move=30.0):
    """Realistic noise (GNSS 1.5/3 m, UWB 0.10 m), attackers moved rigidly about k pivots,
    every one at least ``min_move`` m."""
    cfg = build_config(
        "realistic", n=(n,), f=(f,), trials=trials, attack={"name": f"collusion-{k}", "min_move": min_move}
    )
    d = draw(cfg, np.random.default_rng(seed), trials, n, f)
    return d, snapshot_batch(cfg, d)


@pytest.mark.parametrize("k", [1, 2])
def test_rigid_collusion_at_2f_plus_4_is_identified_exactly(k):
    d, b = collusion(12, 4, k, 60, seed=k)
    v = verify_batch(b, "shape", f_max=4)
    exact = (v.faulty == d.attackers).all(axis=1)
    assert exact.mean() >= 0.9, exact.mean()
    assert not (v.faulty & ~d.attackers).any()  # no honest drone accused
    err = np.linalg.norm(v.positions - d.truth, axis=2)
    ok = v.status == "ok"
    assert ok.mean() >= 0.9
    assert err[ok].max() < 20.0  # the colluders are put back where they are, not where they say


@pytest.mark.parametrize("k", [1, 2, 3])
def test_at_2f_plus_1_two_registrations_are_unidentifiable(k):
    """At n = 2f+1 the colluders and their pivots (f + k drones) leave at most f drones out:
    a second explanation within f_max. The answer is unidentifiable, never the wrong set."""
    d, b = collusion(9, 4, k, 40, seed=10 + k)
    v = verify_batch(b, "shape")
    unid = v.status == "unidentifiable"
    exact = (v.faulty == d.attackers).all(axis=1)
    assert (unid | exact).mean() >= 0.95
    assert unid.mean() >= 0.9  # the test is not passed by exact answers alone
    assert (v.faulty & ~d.attackers).any(axis=1).mean() <= 0.025  # at most 1 of 40
    # what every explanation trusts (the pivots, honest drones near the axis, or nothing
    # where three explanations share no drone): never a colluder
    trusted = v.diagnostics["trusted"]
    assert not (trusted[unid] & d.attackers[unid]).any()


def test_reflection_about_three_pivots_identified_with_f_max_f():
    d, b = collusion(14, 5, 3, 40, seed=5)
    v = verify_batch(b, "shape", f_max=5)
    exact = (v.faulty == d.attackers).all(axis=1)
    unid = v.status == "unidentifiable"
    assert exact.mean() >= 0.5
    assert (exact | unid).mean() >= 0.95
    # at most 1 of 40: the honest set may fail its own chi-square test by chance (p_fa), and
    # then the colluders' set is the only explanation left (an alarm here)
    assert (v.faulty & ~d.attackers).any(axis=1).sum() <= 1


def test_default_f_max_counts_an_honest_drone_near_the_axis_as_a_second_explanation():
    """n = 2f + 4 with f_max = f + 1 (the default): the colluders, their 2 pivots and one
    honest drone that the rotation barely moves leave f + 1 drones out: a second trusted set
    within f_max. Where that happens the answer is unidentifiable, and no honest drone is
    flagged; with f_max = f the same trials are identified."""
    d, b = collusion(12, 4, 2, 60, seed=3)
    v = verify_batch(b, "shape")
    unid = v.status == "unidentifiable"
    assert unid.any()
    support = v.diagnostics["explanations"]
    # in those trials some honest drone is trusted by both explanations beside the pivots
    assert ((support[unid] == 2) & ~d.attackers[unid]).sum(axis=1).min() >= 3
    assert not (v.faulty & ~d.attackers).any()
    w = verify_batch(b.subset(unid), "shape", f_max=4)
    assert (w.faulty == d.attackers[unid]).all(axis=1).mean() >= 0.6


def test_plain_jumps_realistic_flags_attackers_not_honest():
    cfg = build_config("realistic", n=(13,), f=(4,), trials=60)
    d = draw(cfg, np.random.default_rng(4), 60, 13, 4)
    v = verify_batch(snapshot_batch(cfg, d), "shape")
    assert v.faulty[d.attackers].mean() > 0.85
    assert v.faulty[~d.attackers].mean() < 0.02
    err = np.linalg.norm(v.positions - d.truth, axis=2)
    raw = np.linalg.norm(d.reported - d.truth, axis=2)
    assert np.nanmean(err[~d.attackers]) < raw[~d.attackers].mean()


def test_same_input_same_verdict_alone_or_in_a_batch():
    d, b = collusion(10, 3, 1, 12, seed=8)
    whole = verify_batch(b, "shape")
    again = verify_batch(b, "shape")
    for name in ("positions", "hpl", "vpl"):
        assert np.array_equal(getattr(whole, name), getattr(again, name), equal_nan=True)
    for name in ("faulty", "status", "drone_status"):
        assert np.array_equal(getattr(whole, name), getattr(again, name))
    for t in (0, 5, 11):
        one = verify_batch(b.subset(np.array([t])), "shape")
        assert np.array_equal(one.positions[0], whole.positions[t], equal_nan=True)
        assert np.array_equal(one.faulty[0], whole.faulty[t])
        assert one.status[0] == whole.status[t]


def test_procrustes_recovers_a_rigid_motion_and_its_handedness():
    rng = np.random.default_rng(2)
    y = rng.uniform(0, 100, (8, 3))
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    for R in (q * np.sign(np.linalg.det(q)), -q * np.sign(np.linalg.det(q))):  # proper, improper
        z = y @ R.T + [5.0, -3.0, 40.0]
        hand = float(np.sign(np.linalg.det(R)))
        R_hat, t_hat = procrustes_fit(y, z, np.ones(8), hand)
        assert np.allclose(R_hat, R, atol=1e-9) and np.allclose(t_hat, [5.0, -3.0, 40.0], atol=1e-7)
        R_bad, t_bad = procrustes_fit(y, z, np.ones(8), -hand)  # the other handedness cannot fit
        assert np.abs(y @ R_bad.T + t_bad - z).max() > 1.0


def test_triples_all_when_few_else_a_fixed_distinct_choice():
    assert len(triples(6, 100)) == 20
    many = triples(40, 500)
    assert many.shape == (500, 3) and len(np.unique(many, axis=0)) == 500
    assert (many[:, 0] < many[:, 1]).all() and (many[:, 1] < many[:, 2]).all()
    assert np.array_equal(many, triples(40, 500))
    assert set(np.unique(many)) == set(range(40))  # every drone seeds some registration


def test_a_drone_tampering_with_its_ranges_is_placed_by_the_others():
    rng = np.random.default_rng(3)
    truth = rng.uniform(0, 100, (1, 9, 3))
    ranges = true_distances(truth) + rng.normal(0, 0.1, (1, 9, 9))
    ranges[0, 4, :] += 20.0  # drone 4's own ranges, all 20 m long
    ranges[0, 4, 4] = 0.0
    use = shape_ranges(ranges, 0.1, 5.0)
    assert not use[0, 4].any()  # its own ranges dropped
    assert use[0, :, 4].sum() == 8  # the others' ranges to it kept
    ranges[0, 2, 7] += 3.0  # one direction of one link disagrees: that link is dropped both ways
    use = shape_ranges(ranges, 0.1, 5.0)
    assert not use[0, 2, 7] and not use[0, 7, 2] and use[0, 2, 6]


def test_bad_parameter_is_one_line_naming_it():
    snap = Snapshot(
        reported=np.zeros((5, 3)), ranges=np.zeros((5, 5)), gnss_sigma=(1.5, 3.0), range_sigma=0.1
    )
    with pytest.raises(ValueError, match=r"^shape\.max_triples: ") as exc:
        verify(snap, "shape", max_triples=0)
    assert "\n" not in str(exc.value)
    with pytest.raises(ValueError, match=r"^shape\.f_max: "):
        verify(snap, "shape", f_max=9)


def test_no_ranges_is_not_ok():
    rep = np.random.default_rng(1).uniform(0, 100, (9, 3))
    b = SnapshotBatch(rep[None], np.full((1, 9, 9), np.nan), (1.5, 3.0), 0.1)
    assert verify_batch(b, "shape").status[0] in ("alarm", "degenerate")


def test_the_documented_collusion_config_reads_into_a_sweep():
    from pathlib import Path

    from swarmraft.cli.options import sweep_config

    path = Path(__file__).parents[1] / "docs/examples/collusion-30m.toml"
    cfg = sweep_config("realistic", path, "12", "4", False, 10, None, {})
    cfg = cfg.model_copy(update={"attack": cfg.attack.model_copy(update={"name": "collusion-2"})})
    assert cfg.attack.min_move == 30.0 and cfg.detector_params == {"f_max": 4}
    d = draw(cfg, np.random.default_rng(0), 10, 12, 4)
    assert (np.linalg.norm(d.reported - d.truth, axis=2)[d.attackers] >= 30.0).all()


def test_a_reflection_that_every_drone_fits_is_not_ok():
    """Colluders reflected in the plane of 3 pivots while the only other honest drone lies in
    that plane: every report fits the reflected shape (no attacker at all), and the 4 honest
    ones fit the truth (3 attackers). Two explanations that place the colluders 30+ m
    apart: unidentifiable, never ok with the reflection."""
    rng = np.random.default_rng(6)
    hits = 0
    for _ in range(10):
        p = rng.uniform(0, 100, (3, 3))
        nrm = np.cross(p[1] - p[0], p[2] - p[0])
        nrm /= np.linalg.norm(nrm)
        inplane = p.mean(axis=0) + 0.6 * (p[1] - p[0]) - 0.3 * (p[2] - p[0])
        sides = rng.uniform(0, 100, (3, 3))
        sides += (20.0 + np.abs((sides - p[0]) @ nrm))[:, None] * nrm * np.sign((sides - p[0]) @ nrm)[:, None]
        truth = np.vstack([p, inplane, sides])[None]  # drones 4-6 at least 20 m off the plane
        rep = truth + rng.standard_normal((1, 7, 3)) * [1.5, 1.5, 3.0]
        reflected = truth[0, 4:] - 2 * ((truth[0, 4:] - p[0]) @ nrm)[:, None] * nrm
        rep[0, 4:] = reflected
        ranges = true_distances(truth) + rng.normal(0, 0.1, (1, 7, 7))
        v = verify_batch(SnapshotBatch(rep, ranges, (1.5, 3.0), 0.1), "shape")
        assert v.status[0] != "ok", v.faulty[0]
        assert not v.faulty[0, :4].any()
        hits += v.status[0] == "unidentifiable"
    assert hits >= 9


@pytest.mark.parametrize(("n", "f", "k"), [(7, 3, 1), (9, 4, 2)])
def test_registration_rivals_make_joint_unidentifiable_where_colluders_register_too(n, f, k):
    """At n = 2f+1 the colluders and their pivots are a second registration within f_max:
    `joint` alone trusts it in a large share of the trials and accuses honest drones (at
    (7, 3) with every drone `degenerate`: 4 anchors); with the registrations' candidates as
    rivals it says unidentifiable and accuses no honest drone."""
    d, b = collusion(n, f, k, 40, seed=20 + k)
    plain = verify_batch(b, "joint", registration_rivals=False)
    assert (plain.faulty & ~d.attackers).any(axis=1).mean() >= 0.2  # what the rivals are for
    v = verify_batch(b, "joint")  # on by default
    unid = v.status == "unidentifiable"
    exact = (v.faulty == d.attackers).all(axis=1)
    assert (unid | exact).mean() >= 0.95
    assert (v.faulty & ~d.attackers).any(axis=1).sum() <= 1  # at most 1 of 40


def test_registration_rivals_refuse_joints_guess_about_three_pivots():
    """Colluders reflected about 3 pivots at n = 2f+4 with f_max = f: an honest drone near the
    pivots' plane makes the colluders' registration a second explanation; `joint` alone
    picks one and is wrong in a sixth of the trials."""
    d, b = collusion(12, 4, 3, 60, seed=3)
    plain = verify_batch(b, "joint", f_max=4, registration_rivals=False)
    assert (plain.faulty & ~d.attackers).any(axis=1).sum() >= 4
    v = verify_batch(b, "joint", f_max=4)
    assert (v.faulty & ~d.attackers).any(axis=1).sum() <= 1
    exact = (v.faulty == d.attackers).all(axis=1)
    assert (exact | (v.status == "unidentifiable")).mean() >= 0.95
    assert exact.mean() >= 0.5  # not unidentifiable everywhere


def test_registration_rivals_on_plain_jumps_change_verdicts_only_to_unidentifiable():
    """Plain jumps at (13, 3): every verdict the registrations change becomes
    `unidentifiable` (with f_max = 6 a rotation of the shape about near-collinear honest
    drones can carry a spoofed report into place: a second explanation) and accuses no
    honest drone; with f_max = f nothing changes."""
    cfg = build_config("realistic", n=(13,), f=(3,), trials=60)
    d = draw(cfg, np.random.default_rng(8), 60, 13, 3)
    b = snapshot_batch(cfg, d)
    plain = verify_batch(b, "joint", registration_rivals=False)
    v = verify_batch(b, "joint")
    changed = (v.status != plain.status) | (v.faulty != plain.faulty).any(axis=1)
    assert (v.status[changed] == "unidentifiable").all()
    assert changed.sum() <= 4  # 6 without the check that the verdict does not fit the candidate's data
    assert not (v.faulty & ~d.attackers)[changed].any()
    told = verify_batch(b, "joint", f_max=3, registration_rivals=False)
    w = verify_batch(b, "joint", f_max=3)
    assert (w.status == told.status).all() and (w.faulty == told.faulty).all()


def test_registration_rivals_turn_an_alarm_two_registrations_explain_into_unidentifiable():
    """`joint` alone can end in an `alarm` that accuses honest drones while both the honest
    registration and the colluders' pass their tests (n = 2f+1): exclusion was not
    exhausted, and the answer is the explanations', accusing no honest drone. (`joint`'s set
    search, on by default at n = 7, answers the same there: both are checked, the rivals with
    the search off.)"""
    d, b = collusion(7, 3, 1, 80, seed=21)
    plain = verify_batch(b, "joint", set_search=0, registration_rivals=False)
    rows = np.flatnonzero((plain.status == "alarm") & (plain.faulty & ~d.attackers).any(axis=1))
    assert rows.size  # the case exists in these trials
    v = verify_batch(b.subset(rows), "joint", registration_rivals=True, set_search=0)
    assert (v.status == "unidentifiable").all()
    assert not (v.faulty & ~d.attackers[rows]).any()
    searched = verify_batch(b.subset(rows), "joint", registration_rivals=False)
    assert (searched.status == "unidentifiable").all()
    assert not (searched.faulty & ~d.attackers[rows]).any()


def test_registration_rivals_need_more_than_a_refit_of_fewer_reports():
    """(7, 1) under plain jumps: a set of 4 of the 7 drones refitted to their reports gains up
    to a rigid motion's 6 dof by chance, which makes it no rival (counted with only a margin
    per drone left out, 46 % of 2,000 verdicts were `ok`; with the refit test 83 %, against
    `joint`'s 97 %)."""
    cfg = build_config("realistic", n=(7,), f=(1,), trials=100)
    d = draw(cfg, np.random.default_rng(12), 100, 7, 1)
    b = snapshot_batch(cfg, d)
    v = verify_batch(b, "joint")
    assert (v.status == "ok").mean() >= 0.7
    assert (v.faulty & ~d.attackers).any(axis=1).sum() <= 1


def misleading(v, d):
    """Trials (T,) whose `ok` verdict places a drone beyond max(20 m, its level), horizontally
    or vertically: misleading information, as the sweeps count it."""
    return integrity_metrics(d, v)["ok_over_20m_hv"] > 0


@pytest.mark.parametrize(("n", "f", "k"), [(9, 4, 1), (9, 4, 2), (11, 5, 3)])
def test_joint_by_default_is_never_ok_and_far_off_under_colluders_at_2f_plus_1(n, f, k):
    """The colluders and their pivots are a majority at n = 2f+1: `joint` without the
    registrations' rivals trusts them and calls drones `ok` 30-200 m off, beyond their
    levels, in a third of the trials or more; by default (the rivals on) never."""
    d, b = collusion(n, f, k, 40, seed=30 + k)
    assert misleading(verify_batch(b, "joint", registration_rivals=False), d).sum() >= 8  # the failure exists
    v = verify_batch(b, "joint")
    assert not misleading(v, d).any()
    assert (v.faulty & ~d.attackers).any(axis=1).sum() <= 1


@pytest.mark.parametrize(("n", "m"), [(35, 18), (65, 33), (65, 49), (129, 65), (256, 128)])
def test_covering_triples_seed_every_large_set(n, m):
    """Above the cap (every triple would be more than 6,000) the rival check's seeds are a
    covering: every set of m drones holds one of them from each of the 3 splits (so at
    least one, and nearly always 3), far fewer than the cap's sample."""
    t = covering_triples(n, m, 6000)
    assert len(t) < 1000
    rng = np.random.default_rng(n + m)
    member = np.zeros(n, dtype=bool)
    held = []
    for _ in range(300):
        member[:] = False
        member[rng.choice(n, m, replace=False)] = True
        held.append(member[t].all(axis=1).sum())
    assert min(held) >= 1
    assert np.mean(np.array(held) >= 3) >= 0.9


@pytest.mark.parametrize(("n", "m"), [(11, 6), (12, 5), (13, 7), (14, 8), (16, 9), (14, 11)])
def test_turan_triples_hold_a_seed_in_every_set_of_m(n, m):
    """Every one of the C(n, m) sets, checked: each holds a seed (with g groups of a split
    and m > 2 g, some group has 3 of its drones)."""
    t = turan_triples(n, m, 3)
    assert len(t) < math.comb(n, 3)
    sets = np.zeros((math.comb(n, m), n), dtype=bool)
    for row, c in enumerate(combinations(range(n), m)):
        sets[row, list(c)] = True
    held = sets[:, t].all(axis=2).sum(axis=1)
    assert held.min() >= 1


def test_the_rival_seeds_mirror_inside_a_found_set_only_the_turan_triples():
    """Below the cap every triple seeds; the ones also tried mirrored inside a set found with
    the other handedness are exactly the Turan triples (all of them at n = 7, where there are
    none), so every set of n - f_max drones keeps such a seed."""
    for n, m in [(7, 4), (9, 5), (13, 7), (17, 9)]:
        tri, inside = rival_seeds(n, m, 6000)
        assert np.array_equal(tri, triples(n, 6000))
        turan = turan_triples(n, m, 3)
        if not len(turan):
            assert inside.all()
            continue
        assert {tuple(t) for t in tri[inside].tolist()} == {tuple(t) for t in turan.tolist()}
    tri, inside = rival_seeds(65, 33, 6000)
    assert inside.all() and np.array_equal(tri, covering_triples(65, 33, 6000))


def test_the_rival_search_finds_a_mirrored_set_inside_the_honest_one():
    """Five of nine honest drones in one plane: reflected through it they fit their reports
    as well (a second registration, inside the honest one, of the other handedness). The
    rival check's search, which tries seeds mirrored inside a found set only where they are
    Turan triples, finds it as the full search does (without those seeds, or with the other
    seeds instead, it is lost)."""
    rng = np.random.default_rng(3)
    x = np.zeros((9, 3))
    x[:5, :2] = rng.uniform(0, 100, (5, 2))  # drones 0-4 in the plane z = 0
    x[5:] = rng.uniform(0, 100, (4, 3)) + [0, 0, 20]  # 5-8 above it
    args = (
        x[None],
        x[None],
        np.ones((1, 9), bool),
        np.ones((1, 9, 9), bool),
        np.eye(3),
        16.0,
        6000,
        5,
        32,
        5,
    )

    def found(covering):
        sets, hands, _ = registration_sets(*args, covering)
        return {(tuple(np.flatnonzero(m).tolist()), float(h)) for m, h in zip(sets[0], hands[0], strict=True)}

    rival = found(True)
    assert ((0, 1, 2, 3, 4), -1.0) in rival and ((0, 1, 2, 3, 4, 5, 6, 7, 8), 1.0) in rival
    assert rival == found(False)


def test_covering_triples_are_every_triple_below_the_cap():
    for n, m in [(7, 4), (13, 7), (17, 9), (34, 18)]:
        assert np.array_equal(covering_triples(n, m, 6000), triples(n, 6000))


def test_joint_takes_back_an_honest_drone_its_verdict_left_out_beside_colluders(monkeypatch):
    """Colluders rotated about one honest pivot at n = 2f+4: GNC's flags lead the re-inclusion
    rounds to sets the repair and the rivals then change, and `joint` was `ok` accusing an
    honest drone beside the colluders (its report within 1-4 sigma of where the others place
    it: 7 of these 60 trials). The last re-inclusion (`gnc._taken_back`) trusts it again."""
    import swarmraft.estimation.gnc as gnc

    d, b = collusion(10, 3, 1, 60, seed=31)
    v = verify_batch(b, "joint")
    assert not (v.faulty & ~d.attackers).any()
    assert (v.faulty == d.attackers).all(axis=1).sum() >= 58
    assert (v.status[(v.faulty == d.attackers).all(axis=1)] == "ok").all()
    monkeypatch.setattr(gnc, "_taken_back", lambda batch, p, noise, v, gnss_w: v)
    without = verify_batch(b, "joint")
    assert (without.faulty & ~d.attackers).any(axis=1).sum() >= 5  # what it is for
