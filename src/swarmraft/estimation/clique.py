"""The `clique` detector: the largest set of mutually consistent drones.

Two drones are consistent when the distance between their reports agrees with the range
between them within ``k`` sigma, where sigma combines both GNSS errors along the line of
sight and the range noise, and (when both directions are measured) their two ranges d_ij and
d_ji agree within ``k`` sigma: a drone that tampers with its own ranges disagrees with the
honest drone's measurement of the same distance. The honest drones form a clique of this
consistency graph; the detector takes the maximum clique (networkx) as trusted and estimates
every position jointly from it (`joint_estimate`).

The pairwise test is weak against GNSS noise on both ends (a spoof of a few sigma can be
consistent with most honest drones), so the cliques are candidates, each checked by the
residual tests of a joint estimate that trusts it (`passes_residual_tests`): a spoofed report
inside a candidate shows up as a large GNSS residual there.

Identifiability (docs/models.md): f colluding attackers moving rigidly about up to 3 honest pivot
drones form a consistent clique of f + 3 in 3-D, so the honest clique is the unique maximum
only when n >= 2f + 4. The candidates are the maximal cliques that leave at most ``f_max``
drones out (the number of attackers the swarm is meant to tolerate; by default an honest
majority, (n - 1) // 2). If two or more candidates pass the residual tests the status is
``unidentifiable``: only the drones outside every plausible candidate are flagged, and the
positions are estimated from the drones inside all of them. If none passes, the largest
candidate with the smallest residual is taken (its tests fail, so the status is ``alarm``);
if there is no candidate, the status is ``alarm`` too (more than ``f_max`` drones are
inconsistent). The chosen set goes through `integrity.finish` (robust estimate from several
starts including the candidate's own, statuses, protection levels). With ``f_max`` = f, n >= 2f + 4
identifies f colluders exactly; with the default a reflection about three pivots (which
needs one more honest drone to rule out) is reported unidentifiable rather than guessed.

Large swarms (docs/detectors.md): the maximal cliques are enumerated up to ``max_cliques``;
a snapshot with more gets no ``ok`` verdict (``unidentifiable`` when a clique seen passes,
since one not seen might too; ``alarm`` when none does). On a sparse range graph a pair
without a range is consistent, so an attacker ranged by a few drones can agree with all of
them; where no maximal clique passes there, the largest go through fault exclusion.
"""

from __future__ import annotations

from itertools import islice

import networkx as nx
import numpy as np
from pydantic import Field

from swarmraft.estimation.integrity import IntegrityParams, finish, resolve_f_max
from swarmraft.estimation.joint import joint_estimate, residual_statistics, tests_pass
from swarmraft.estimation.links import SPARSE_SHARE, linked_share
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.pairwise import consistency_graph
from swarmraft.estimation.registry import register
from swarmraft.estimation.rivals import larger_rivals
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch

_CANDIDATE_FLOATS = 4_000_000  # ranges of the candidates tested at once (32 MB)


class CliqueParams(IntegrityParams):
    k: float = Field(4.0, gt=0, description="consistency threshold, sigmas")
    tol: float = Field(0.01, ge=0, description="absolute floor on the threshold, m")
    max_cliques: int = Field(
        1000,
        ge=1,
        description="maximal cliques enumerated per snapshot at most; beyond: unidentifiable (or "
        "alarm if none seen passes), never a guess",
    )


def candidate_sets(adj: np.ndarray, f_max: int, cap: int | None = None) -> tuple[list[frozenset[int]], bool]:
    """The sets that could be the honest drones of one graph: the maximal cliques that leave
    at most ``f_max`` drones out, largest first; and whether the enumeration stopped at
    ``cap`` maximal cliques (networkx's order; the graph has more than ``cap``), in which
    case the list holds the candidates among the first ``cap`` only."""
    n = adj.shape[0]
    # the graph as nx.from_numpy_array builds it (nodes 0..n-1, then the edges row by row;
    # find_cliques ignores the diagonal), a quarter of its cost at n = 17
    g = nx.Graph()
    g.add_nodes_from(range(n))
    a = np.asarray(adj) != 0  # any nonzero entry an edge, as nx reads a matrix
    i, j = np.nonzero(np.triu(a | a.T, 1))  # an edge either way, as nx makes it
    g.add_edges_from(zip(i.tolist(), j.tolist(), strict=True))
    found = list(nx.find_cliques(g) if cap is None else islice(nx.find_cliques(g), cap + 1))
    capped = cap is not None and len(found) > cap
    cliques = sorted((frozenset(c) for c in found[:cap]), key=len, reverse=True)
    return [c for c in cliques if n - len(c) <= f_max], capped


def excluded_sets(
    reported: np.ndarray, ranges: np.ndarray, masks: np.ndarray, noise: NoiseModel, f_max: int, p_fa: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For candidates (B, n) that fail the residual tests, the drone with the largest
    whitened GNSS residual left out, again and again, until the tests pass or ``f_max``
    drones are out (fault exclusion inside the clique, as `fde` does). On a sparse range
    graph an attacker ranged by few drones can agree with all of them, so the honest drones
    are a clique but not a maximal one: the maximal clique holds them and that attacker.
    Returns the final sets (B, n), whether each passes (B,) and its estimate (B, n, 3)."""
    masks = masks.copy()
    passed = np.zeros(len(masks), dtype=bool)
    x = np.zeros(masks.shape + (3,))
    active = np.arange(len(masks))
    while active.size:
        m = masks[active]
        xa = joint_estimate(reported[active], ranges[active], m, noise.gnss_cov, noise.range_sigma)
        _, gq, total, dof = residual_statistics(xa, reported[active], ranges[active], m, noise)
        ok = tests_pass(gq, total, dof, m, p_fa)
        x[active], passed[active] = xa, ok
        go = ~ok & ((~m).sum(axis=1) < f_max)
        worst = np.argmax(np.where(m, gq, -np.inf), axis=1)
        masks[active[go], worst[go]] = False
        active = active[go]
    return masks, passed, x


@register("clique", CliqueParams, "maximum clique of the pairwise consistency graph + joint estimate")
def clique_detector(batch: SnapshotBatch, p: CliqueParams) -> VerdictBatch:
    reported = np.asarray(batch.reported, float)
    ranges = np.asarray(batch.ranges, float)
    T, n, _ = reported.shape
    noise = NoiseModel.of(batch, p, "clique")
    adj = consistency_graph(reported, ranges, noise, p.k, p.tol)
    f_max = resolve_f_max(p, n, "clique")
    found = [candidate_sets(adj[t], f_max, p.max_cliques) for t in range(T)]
    cands = [cs for cs, _ in found]
    capped = np.array([c for _, c in found], dtype=bool)
    # Test every candidate at once: does a joint estimate trusting it explain the data?
    owner = np.array([t for t, cs in enumerate(cands) for _ in cs], dtype=int)
    masks = np.zeros((owner.size, n), dtype=bool)
    for k, c in enumerate(c for cs in cands for c in cs):
        masks[k, list(c)] = True
    passed, total = np.zeros(owner.size, dtype=bool), np.zeros(owner.size)
    worst = np.zeros(owner.size, dtype=int)  # each candidate's worst-fitting GNSS report
    x = np.zeros((owner.size, n, 3))
    # in groups of at most _CANDIDATE_FLOATS of ranges (each verdict is its own snapshot's,
    # so the grouping changes nothing): 1000 candidates of 256 drones would copy 0.5 GB of
    # ranges, and the residuals several times that
    step = max(1, _CANDIDATE_FLOATS // (n * n))
    for lo in range(0, owner.size, step):
        g = slice(lo, lo + step)
        rep, rng = reported[owner[g]], ranges[owner[g]]
        x[g] = joint_estimate(rep, rng, masks[g], noise.gnss_cov, noise.range_sigma)
        _, gnss_q, total[g], dof = residual_statistics(x[g], rep, rng, masks[g], noise)
        passed[g] = tests_pass(gnss_q, total[g], dof, masks[g], p.p_fa)
        worst[g] = np.argmax(np.where(masks[g], gnss_q, -np.inf), axis=1)
    found_before = owner.size
    owner, masks, passed, total, x = larger_rivals(
        reported, ranges, noise, p.p_fa, f_max, owner, masks, passed, total, x, worst
    )
    if owner.size > found_before:  # the candidates, rivals added, in their new order
        cands = [[frozenset(np.flatnonzero(masks[k])) for k in np.flatnonzero(owner == t)] for t in range(T)]
    # On a sparse range graph (at most SPARSE_SHARE of the pairs ranged: drones out of each
    # other's range), where no candidate passes: exclusion inside the largest candidates
    # (`excluded_sets`). A dense graph keeps the maximal cliques as they are, also where the
    # screening dropped some links (NLOS): its verdicts do not change.
    sparse = linked_share(ranges) <= SPARSE_SHARE
    retry = []
    for t, cs in enumerate(cands):
        ks = np.flatnonzero(owner == t)
        if sparse[t] and not capped[t] and cs and not passed[ks].any():
            retry.append(ks[masks[ks].sum(axis=1) == len(cs[0])])
    if retry:
        ks = np.concatenate(retry)
        sets, ok, xs = excluded_sets(reported[owner[ks]], ranges[owner[ks]], masks[ks], noise, f_max, p.p_fa)
        ks, sets, xs = ks[ok], sets[ok], xs[ok]  # a set that still fails stays as it was
        masks[ks], passed[ks], x[ks] = sets, True, xs
    trusted = np.ones((T, n), dtype=bool)
    suspects = np.zeros((T, n), dtype=bool)
    start = np.full((T, n, 3), np.nan)
    status = np.full(T, "ok", dtype=object)
    k = 0
    for t, cs in enumerate(cands):
        ks = np.arange(k, k + len(cs))
        k += len(cs)
        plausible = [j for j in ks if passed[j]]
        # exclusion can make two candidates the same set: count it once, where it first comes
        # (a dict keeps that order; np.unique by rows took 60-120 us, 2 % of a step at n = 17)
        first: dict[bytes, int] = {}
        for j in plausible:
            first.setdefault(masks[j].tobytes(), j)
        plausible = list(first.values())
        if not cs or (capped[t] and not plausible):
            # more than f_max drones outside every clique (nothing to exclude), or the
            # enumeration stopped at max_cliques with no passing candidate among those seen
            status[t] = "alarm"
            continue
        if len(plausible) >= 2 or capped[t]:
            # two explanations, or the enumeration stopped before it saw every clique: some
            # unseen one may explain the data as well, so this one cannot be called unique
            status[t] = "unidentifiable"
            trusted[t] = np.logical_and.reduce(masks[plausible])  # what every explanation trusts
            suspects[t] = ~np.logical_or.reduce(masks[plausible])  # what none trusts
            continue
        top = [j for j in ks if masks[j].sum() == len(cs[0])]
        pick = plausible[0] if plausible else min(top, key=lambda j: total[j])
        trusted[t] = masks[pick]
        suspects[t] = ~masks[pick]
        start[t] = x[pick]
    return finish(
        batch,
        p,
        noise,
        trusted,
        (start,),
        status,
        suspects,
        diagnostics={"degree": adj.sum(axis=2), "capped": capped},
    )
