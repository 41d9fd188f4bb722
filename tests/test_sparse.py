"""Large swarms on a sparse range graph (each drone ranges only the drones within
``max_range``): `clique`'s enumeration cap, the range shape's start, the statuses of drones
the ranges do not fix, and the integrity of every `ok` drone at n = 65."""

from __future__ import annotations

import numpy as np
import pytest

from swarmraft.estimation import Snapshot, SnapshotBatch, verify, verify_batch
from swarmraft.estimation.clique import candidate_sets
from swarmraft.estimation.links import screen, sparse_graph
from swarmraft.experiments import build_config
from swarmraft.experiments.trials import draw

GNSS = (1.5, 3.0)


def _sparse_draw(n: int, f: int, trials: int, seed: int):
    """The benchmark's world: realistic preset, a 30 m grid (a 150 m formation at n = 65),
    no range beyond 60 m."""
    config = build_config(
        "realistic",
        n=(n,),
        f=(f,),
        trials=trials,
        ranging={"max_range": 60.0},
        geometry="formation",
        spacing=30.0,
    )
    return draw(config, np.random.default_rng(seed), trials, n, f)


def _batch(d) -> SnapshotBatch:
    return SnapshotBatch(d.reported, d.ranges, gnss_sigma=GNSS, range_sigma=0.1)


def test_candidate_sets_stop_at_the_cap():
    # the complement of k disjoint triangles has 3^k maximal cliques (Moon-Moser)
    k = 5
    n = 3 * k
    adj = ~np.kron(np.eye(k, dtype=bool), np.ones((3, 3), dtype=bool))
    full, capped = candidate_sets(adj, n - 1)
    assert len(full) == 3**k and not capped
    some, capped = candidate_sets(adj, n - 1, cap=10)
    assert capped and len(some) == 10
    exact, capped = candidate_sets(adj, n - 1, cap=3**k)
    assert not capped and len(exact) == 3**k


def test_clique_cap_gives_no_guess():
    """With the enumeration stopped at 1 maximal clique (every one of these snapshots has
    more), no verdict is `ok`: `unidentifiable` when the clique seen passes (an unseen one
    could explain the data as well), `alarm` when it does not."""
    config = build_config("realistic", n=(9,), f=(2,), trials=20)
    d = draw(config, np.random.default_rng(3), 20, 9, 2)
    b = _batch(d)
    free = verify_batch(b, "clique")
    capped = verify_batch(b, "clique", max_cliques=1)
    assert (free.status == "ok").sum() >= 15
    assert not free.diagnostics["capped"].any()
    assert capped.diagnostics["capped"].all()
    assert not (capped.status == "ok").any()
    assert {"unidentifiable", "alarm"} <= set(capped.status)
    # unidentifiable verdicts flag only what the clique seen leaves out
    unid = capped.status == "unidentifiable"
    assert (capped.faulty[unid].sum(axis=1) <= 4).all()


def test_clique_max_cliques_is_validated():
    snap = Snapshot(reported=np.zeros((4, 3)), ranges=np.zeros((4, 4)), gnss_sigma=GNSS, range_sigma=0.1)
    with pytest.raises(ValueError, match=r"^clique\.max_cliques: "):
        verify(snap, "clique", max_cliques=0)


def test_sparse_graph_ignores_drones_without_ranges():
    d = _sparse_draw(65, 1, 1, 0)
    assert sparse_graph(d.ranges).all()
    dense = np.full((1, 5, 5), 10.0)
    dense[0, 4, :] = dense[0, :, 4] = np.nan  # a drone outside the swarm: no range at all
    assert not sparse_graph(dense).any()


def test_screen_keeps_honest_links_of_a_sparse_swarm():
    """Clean ranges of a 65-drone formation (no NLOS, no enlargement): the screening's
    shape fit must converge to the true shape and drop nothing. Its old start (MDS of the
    few drones that all range each other, the rest by multilateration) folded the shape in
    3 of these 6 snapshots, and the fold made 8-89 honest links read long and dropped."""
    d = _sparse_draw(65, 1, 6, 7)
    s = screen(d.ranges, 0.1)
    assert s.dropped.sum() == 0
    assert not s.enlarged.any()


def test_a_drone_with_too_few_neighbours_is_degenerate():
    """A drone ranged by 3 drones only (out of range of the rest) cannot be fixed with its
    fault detectable: `degenerate`, protection level inf, never `ok` with a number."""
    d = _sparse_draw(17, 1, 1, 5)
    truth = d.truth[0].copy()
    ranges = d.ranges[0].copy()
    reported = d.reported[0].copy()
    far = 16
    ranges[far, :] = ranges[:, far] = np.nan
    ranges[far, far] = 0.0
    near = [0, 1, 2]
    for j in near:
        dist = np.linalg.norm(truth[far] - truth[j])
        ranges[far, j] = ranges[j, far] = dist
    reported[d.attackers[0]] = truth[d.attackers[0]]  # no attack: only the geometry matters
    snap = Snapshot(reported=reported, ranges=ranges, gnss_sigma=GNSS, range_sigma=0.1)
    for det in ("joint", "fde", "clique", "shape"):
        v = verify(snap, det)
        assert v.drone_status[far] == "degenerate", det
        assert v.hpl[far] == np.inf and v.vpl[far] == np.inf, det
        assert v.status != "ok", det


@pytest.mark.parametrize("det", ["joint", "fde", "clique", "shape"])
def test_sparse_65_ok_drones_within_their_levels(det):
    """n = 65, f = 16, max range 60 m in a 150 m formation, 10-100 m jumps: every drone of
    an `ok` verdict is within max(20 m, its 3-D protection level) of the truth, over seeded
    trials; most verdicts are not refusals, and most `ok` ones name the attackers exactly."""
    trials = 6 if det in ("clique", "shape") else 12
    d = _sparse_draw(65, 16, trials, 21)
    v = verify_batch(_batch(d), det)
    ok = v.status == "ok"
    err = np.linalg.norm(v.positions - d.truth, axis=2)
    pl = np.hypot(v.hpl, v.vpl)
    assert np.isfinite(err[ok]).all()
    assert (err[ok] <= np.fmax(20.0, pl[ok])).all()
    if det == "clique":
        # at n = 65 its enumeration often stops at max_cliques (no verdict then); an alarm
        # with every clique seen is what the exclusion inside the largest cliques prevents
        # (without it every one of these verdicts was an alarm)
        capped = v.diagnostics["capped"]
        assert not (capped & ok).any()
        assert capped[v.status == "alarm"].all()
        assert (v.status != "alarm").sum() >= trials // 2
    else:
        assert ok.sum() >= trials // 2
    # most ok verdicts name the attackers exactly (a small jump may go unflagged, within
    # its level; an honest drone may be flagged, as on a dense graph)
    assert not ok.any() or (v.faulty[ok] == d.attackers[ok]).all(axis=1).mean() >= 0.5


def test_clique_excludes_inside_a_clique_on_a_sparse_graph():
    """With the pairwise test made blind (k = 50 sigmas) every drone agrees with every other,
    so the one maximal clique holds the attackers too and fails its residual tests, as a
    clique does on a sparse graph when an attacker is ranged by few drones that all agree with
    it. Exclusion inside the clique finds them; without it every verdict is an alarm."""
    d = _sparse_draw(65, 3, 4, 5)
    v = verify_batch(_batch(d), "clique", k=50.0)
    assert not v.diagnostics["capped"].any()
    assert (v.status == "ok").all()
    assert (v.faulty == d.attackers).all(axis=1).sum() >= 3
    err = np.linalg.norm(v.positions - d.truth, axis=2)
    assert (err <= np.fmax(20.0, np.hypot(v.hpl, v.vpl))).all()


def test_screen_keeps_the_links_of_two_clusters_out_of_range():
    """Two 12-drone clusters 500 m apart (no range between them; one drone of the first with
    no range at all): each cluster's shape is fitted on its own, nothing reads long. With both
    clusters' starts on top of each other the fit pulled them together and 110 honest links
    were dropped."""
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 40, (1, 12, 3))
    truth = np.concatenate([a, a + [500.0, 0.0, 0.0]], axis=1)
    n = truth.shape[1]
    true = np.linalg.norm(truth[:, :, None] - truth[:, None], axis=3)
    ranges = np.where(true > 100, np.nan, true + 0.1 * rng.standard_normal((1, n, n)))
    ranges[0, 5, :] = ranges[0, :, 5] = np.nan
    ranges[:, np.arange(n), np.arange(n)] = 0.0
    s = screen(ranges, 0.1)
    assert s.dropped.sum() == 0 and not s.enlarged.any()


def test_the_snapshot_bound_counts_only_the_ranges_the_radios_reach():
    """A mission's snapshot bound (its error reference) counts a range only between drones
    within ``max_range``: with no drone in reach of another it is each drone's GNSS alone
    (it counted every pair as ranged: 1.6 m against GNSS's 3.7 m)."""
    from swarmraft.experiments.mission import error_series
    from swarmraft.sim.mission import Mission
    from swarmraft.sim.scenario import Scenario

    gnss_only = np.sqrt(2 * 1.5**2 + 3.0**2)
    out_of_reach = Scenario(drones=9, duration_s=0.5, seed=1, ranging={"max_range": 1.0})
    alone = error_series(Mission(out_of_reach).run())
    np.testing.assert_allclose(alone["snapshot_bound"], gnss_only, rtol=1e-9)
    ranged = error_series(Mission(Scenario(drones=9, duration_s=0.5, seed=1)).run())
    assert (ranged["snapshot_bound"] < 0.6 * gnss_only).all()


def test_joint_rejudges_range_tampering_where_gnc_folded_a_cluster():
    """Snapshots 15, 19 and 21 of the benchmark's 65-drone world: GNC settled with a cluster
    of drones (honest 8 and 23 with spoofed 9 and 22 in snapshot 19) placed 38-66 m off and
    its links to the rest down-weighted, so the honest drones' own ranges looked tampered and
    the re-inclusion test never asked about them; re-estimated with the flagged drones
    distrusted, their ranges and reports agree (placed 0.2-1 m from the truth), a few drones
    a round. No honest drone is flagged."""
    d = _sparse_draw(65, 16, 40, seed=7)
    rows = np.array([15, 19, 21])
    batch = SnapshotBatch(d.reported[rows], d.ranges[rows], gnss_sigma=GNSS, range_sigma=0.1)
    v = verify_batch(batch, "joint")
    assert not (v.faulty & ~d.attackers[rows]).any()
    assert (v.faulty == d.attackers[rows]).all()


def test_candidate_sets_are_those_of_the_graph_networkx_builds_from_the_matrix():
    """`clique.candidate_sets` builds its graph edge by edge (a quarter of
    nx.from_numpy_array's cost): the same maximal cliques in the same order, so the same
    candidates and the same cap, on bool, 0/1 float and asymmetric matrices, self-loops too."""
    from itertools import islice

    import networkx as nx

    from swarmraft.estimation.clique import candidate_sets

    rng = np.random.default_rng(3)
    for k in range(150):
        n = int(rng.integers(3, 18))
        adj = rng.random((n, n)) < rng.random()
        if k % 3:
            adj = adj | adj.T
        np.fill_diagonal(adj, rng.random() < 0.5)
        given = adj.astype(float) if k % 5 == 0 else adj
        cap = int(rng.integers(1, 6)) if k % 4 == 0 else None
        found = nx.find_cliques(nx.from_numpy_array(adj.astype(np.int8)))
        found = list(found if cap is None else islice(found, cap + 1))
        want = sorted((frozenset(c) for c in found[:cap]), key=len, reverse=True)
        f_max = n // 2
        assert candidate_sets(given, f_max, cap) == (
            [c for c in want if n - len(c) <= f_max],
            cap is not None and len(found) > cap,
        ), k


def _random_range_graph(rng: np.random.Generator, n: int, ties: bool) -> np.ndarray:
    """Symmetric two-way ranges (n, n) of a flattish swarm, nan beyond a random range (some
    graphs split into components); rounded to whole metres where ``ties`` (equal paths)."""
    p = rng.uniform(3, 60, (n, 3)) * [1.0, 1.0, 0.3]
    d = np.linalg.norm(p[:, None] - p[None], axis=2) + rng.normal(0, 0.1, (n, n))
    d = (d + d.T) / 2
    d[d > rng.uniform(5, 40)] = np.nan
    if ties:
        d = np.maximum(np.round(d), 1.0)  # equal paths (no zero-length link: see below)
    np.fill_diagonal(d, 0.0)
    return d


def test_geodesic_and_components_are_scipys_bit_for_bit():
    """`links._geodesic`'s compiled Dijkstra gives scipy's shortest paths bit for bit (equal
    paths too: whole-metre ranges), and `_components_mds` numbers the components as scipy's
    connected_components does (the component's offset along x depends on it)."""
    from scipy.sparse.csgraph import connected_components, shortest_path

    from swarmraft.estimation.links import _geodesic, components

    rng = np.random.default_rng(11)
    split = 0
    for k in range(400):
        d = _random_range_graph(rng, int(rng.integers(2, 70)), ties=k % 4 == 0)
        g = shortest_path(np.where(np.isnan(d), 0.0, d), method="D", directed=False)
        want = np.where(np.isnan(d), np.where(np.isfinite(g), g, np.nan), d)
        got = _geodesic(d)
        assert np.array_equal(got, want, equal_nan=True), k
        m, label = connected_components(np.isfinite(want) & ~np.eye(len(d), dtype=bool), directed=False)
        assert np.array_equal(components(got), label), k
        split += m > 1
    assert split > 50  # the graphs split into components often enough to test the numbering


def test_a_zero_length_link_joins_its_drones_in_the_shortest_paths():
    """A measured range of 0 (two drones at one place; scipy's dense input drops any link of
    1e-8 m or less) is a link: the pairs it joins get finite paths, the components are those
    of the measured links, and the screening's MDS of two clusters bridged by it runs (it
    failed on the gap before, `LinAlgError`)."""
    from scipy.sparse.csgraph import connected_components

    from swarmraft.estimation.links import _geodesic, components

    rng = np.random.default_rng(2)
    for k in range(100):
        d = _random_range_graph(rng, int(rng.integers(4, 30)), ties=False)
        i, j = rng.choice(len(d), 2, replace=False)
        d[i, j] = d[j, i] = 0.0  # the two drones at one place
        g = _geodesic(d)
        linked = ~np.isnan(d) & ~np.eye(len(d), dtype=bool)
        m, label = connected_components(linked, directed=False)
        assert np.array_equal(components(g), label), k
        assert np.array_equal(np.isfinite(g), label[:, None] == label[None, :]), k
    # two clusters 200 m apart, a zero range across them (a corrupt or co-located pair)
    p = np.concatenate([rng.uniform(0, 40, (8, 3)), rng.uniform(0, 40, (8, 3)) + [200.0, 0.0, 0.0]])
    rng_ = np.linalg.norm(p[:, None] - p[None], axis=2)
    rng_[rng_ > 60] = np.nan
    rng_[0, 8] = rng_[8, 0] = 0.0
    np.fill_diagonal(rng_, 0.0)
    out = screen(rng_[None], 0.1)
    assert out.ranges.shape == (1, 16, 16)


def test_the_screenings_shape_is_reused_only_for_equal_inputs(monkeypatch):
    """`links.fitted_shape` keeps its last answer for the same inputs, bit for bit: the
    answer then is the one computed afresh, a copy the caller may change, and an input that
    differs in one bit is fitted again."""
    from swarmraft.estimation import links

    rng = np.random.default_rng(5)
    d = _random_range_graph(rng, 20, ties=False)[None]
    w = (~np.isnan(d) & ~np.eye(20, dtype=bool)).astype(float)
    sparse = sparse_graph(d)
    fits = []
    real = links._fit
    monkeypatch.setattr(links, "_fit", lambda *a: fits.append(1) or real(*a))
    links._last_shape = None
    fresh = links.fitted_shape(d, w, 0.1, sparse)
    kept = links.fitted_shape(d, w, 0.1, sparse)
    assert len(fits) == 1  # the second answer was the kept one
    assert np.array_equal(fresh, kept) and kept is not fresh
    kept += 1.0  # the caller's copy
    assert np.array_equal(links.fitted_shape(d, w, 0.1, sparse), fresh)
    other = d.copy()
    i, j = np.argwhere(~np.isnan(d[0]) & (d[0] > 0))[0]
    other[0, i, j] = np.nextafter(other[0, i, j], np.inf)
    links._last_shape = None
    want = links.fitted_shape(other, w, 0.1, sparse)
    links.fitted_shape(d, w, 0.1, sparse)  # the last answer now d's
    fits.clear()
    assert np.array_equal(links.fitted_shape(other, w, 0.1, sparse), want)
    assert len(fits) == 1  # fitted again: one bit apart is another input
    assert not np.array_equal(want, fresh)


def test_settled_starts_put_each_untrusted_drone_in_a_minimum_of_its_own_cost():
    """`robust.settled` on the benchmark's sparse snapshots, the attackers untrusted and their
    start reflected across their anchors' plane (`robust.mirrored`, the start that crawled):
    every untrusted drone that 3 or more trusted drones range ends where its own cost
    (`robust._own_cost`) is no higher than at the start and its gradient vanishes (a
    minimum); the trusted drones, the drones with fewer anchors and a dense trial's drones
    stay bit for bit."""
    from swarmraft.estimation.robust import _own_cost, mirrored, settled

    d = _sparse_draw(65, 16, 6, seed=7)
    trusted = ~d.attackers
    x0 = mirrored(d.reported, d.ranges, trusted)
    dense = d.truth[:1, :10]  # ten drones all ranging each other
    rng_dense = np.linalg.norm(dense[:, :, None] - dense[:, None], axis=3)
    assert settled(dense, rng_dense, trusted[:1, :10], np.zeros(1, bool), 0.1) is dense
    sparse = sparse_graph(d.ranges)
    assert sparse.all()
    x = settled(x0, d.ranges, trusted, sparse, 0.1)
    before = _own_cost(x0, x0[None], d.ranges, trusted, 0.1, None, None)[0]
    after = _own_cost(x0, x[None], d.ranges, trusted, 0.1, None, None)[0]
    anchors = ((~np.isnan(d.ranges)) & trusted[:, :, None]).sum(axis=1)  # trusted drones ranging j
    moved = ~trusted & (anchors >= 3)
    np.testing.assert_array_equal(x[~moved], x0[~moved])
    assert (after[moved] <= before[moved]).all()
    assert (after[moved] < before[moved] - 1.0).sum() > 10  # the reflection was off for many
    for t, j in zip(*np.nonzero(moved), strict=True):
        k = np.flatnonzero(trusted[t] & ~np.isnan(d.ranges[t, :, j]))
        diff = x[t, j] - x[t, k]
        dist = np.linalg.norm(diff, axis=1)
        grad = 2 * ((dist - d.ranges[t, k, j]) / 0.1**2) @ (diff / dist[:, None])
        assert np.linalg.norm(grad) < 1e-2 * max(1.0, after[t, j]), (t, j)


def test_a_drone_settled_from_nan_stays_there():
    """`robust.settled` leaves a drone whose own cost at the start is not finite (its start or
    an anchor at nan) where it is, with or without a prior, instead of raising."""
    from swarmraft.estimation.robust import settled

    rng = np.random.default_rng(0)
    x = rng.uniform(-30, 30, (1, 6, 3))
    ranges = np.full((1, 6, 6), np.nan)
    ranges[0, 1:5, 0] = 10.0
    trusted = np.ones((1, 6), bool)
    trusted[0, 0] = False
    prior = np.full((1, 6, 3), np.nan)
    prior[0, 0] = 1.0
    for bad in (0, 1):  # the drone itself, one of its anchors
        for pr, ps in ((None, None), (prior, 1.0)):
            start = x.copy()
            start[0, bad] = np.nan
            out = settled(start, ranges, trusted, np.ones(1, bool), 0.1, pr, ps)
            np.testing.assert_array_equal(out, start)
    assert np.isfinite(settled(x, ranges, trusted, np.ones(1, bool), 0.1, prior, 1.0)).all()
