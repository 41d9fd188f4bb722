"""Integrity of a joint estimate: whether it may be used, and how far it can be trusted.

The statistical detectors (`clique`, `fde`, `joint`) each decide a trusted set; this module
turns that set into a verdict a user can rely on, the way GNSS receivers do with RAIM/ARAIM:

1. `robust.robust_estimate`: the joint estimate with that trusted set, by Levenberg-Marquardt
   with step acceptance from several starts (closed-form multilateration, the reports, the
   prior, any start the detector brings, the best reflected, and a per-drone mix); the lowest
   converged cost wins. Converged starts that fit equally well but place a drone apart
   (a mirror of near-coplanar anchors) leave that drone undetermined.
2. `assess`: the statuses and protection levels.
3. `finish` then repairs a set that fails its tests with a passing swap and checks an `ok`
   verdict against rival sets (`rivals.rival_sets`).

   - ``alarm``: the fit fails its own chi-square tests at ``p_fa`` (`joint.tests_pass`), the
     solver did not converge, or a solution-separation test fails.
   - ``degenerate``: the geometry does not fix some drone's position: fewer than 4 anchors
     (3 with a prior), or near-coplanar or near-collinear anchors whose mirror image of the
     estimate fits the ranges within the chi-square 1-dof quantile at ``p_fa``
     (`mirror_ambiguous`), or two starts converge to equally good minima apart, or the
     drone's 3x3 block of the inverse Fisher information is ill-conditioned (largest over
     smallest eigenvalue above ``max_condition``). Also when excluding one trusted drone
     would leave a drone's position unfixed: its fault could not be detected, so no
     protection level exists. That drone's position becomes its prior if it
     has one, else nan, and its protection levels are inf.
   - last (`_verdicts`), the alert limits: in a verdict that is not an ``alarm``, a drone
     whose horizontal or vertical protection level is above ``alert_limit_h`` or
     ``alert_limit_v`` (aviation's "unavailable") is ``degenerate``, withheld the same way;
     so is an untrusted drone without a prior whose fault could not be detected (placed only
     by ranges to trusted drones, one of which could be faulty unseen; a trusted one, or one
     with a prior, keeps its estimate).
   - ``ok`` otherwise. (``unidentifiable`` comes from the detectors themselves.)

   Protection levels are ARAIM solution separation (Blanch et al.) on the model linearised at
   the estimate: the all-in-view covariance P0 and, for every hypothesis "trusted drone j is
   faulty" (its GNSS report and the ranges it measured excluded), the subset covariance Pj
   and the separation dj = xj - x0 (one Gauss-Newton step from x0, exact for the linearised
   model), whose covariance is Pj - P0. Per drone and axis: the test
   |dj| <= K_fa sqrt(Pj - P0) (else ``alarm``) and the level
   PL = max(K_md sigma0, max_j K_fa sigma_ss,j + K_md sigma_j). K_fa splits ``p_fa`` over
   every test (hypotheses x drones x axes); K_md splits ``integrity_risk`` over the three axes
   and the fault-free plus single-fault hypotheses. HPL = sqrt(PL_E^2 + PL_N^2), VPL = PL_U.
   A GNSS error common to all drones (``gnss_common``) cancels in ranges and separations and
   is added to every drone's covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from pydantic import Field
from scipy.special import ndtri

from swarmraft.estimation.joint import (
    chi2_quantile,
    initial_positions,
    residual_statistics,
    tests_pass,
    weighted_gauss_newton,
)
from swarmraft.estimation.levels import blocks_kernel, eigenvalues_kernel, levels_kernel
from swarmraft.estimation.mirror import mirror_ambiguous
from swarmraft.estimation.noise import NoiseModel, NoiseParams, gnss_information, prior_held
from swarmraft.estimation.registrations import Candidates, candidates, distinct_explanations
from swarmraft.estimation.rivals import Rivals, rival_sets
from swarmraft.estimation.robust import Estimate, robust_estimate
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch, merged_rows
from swarmraft.estimation.woodbury import hypotheses_kernel, without_each

STATUS_ORDER = ("ok", "degenerate", "unidentifiable", "alarm")  # mildest first
_RANK = {name: k for k, name in enumerate(STATUS_ORDER)}
_MEMORY_FLOATS = 4_000_000  # per batch of hypothesis matrices (32 MB)


DETECTION = {"detection": True}  # a field the rival search uses: not the estimator given a set


class IntegrityParams(NoiseParams):
    """What every statistical detector shares: the residual test, the tolerated number of
    attackers, and the integrity budget."""

    p_fa: float = Field(1e-3, gt=0, lt=1, description="false-alarm probability of the residual tests")
    f_max: int | None = Field(None, ge=0, description="attackers to tolerate; None: (n - 1) // 2")
    integrity_risk: float = Field(
        1e-3, gt=0, lt=1, description="probability of an error above the protection level without alarm"
    )
    exact_below: int = Field(
        11,
        ge=0,
        description="re-solve each fault hypothesis (instead of linearising it) when at most this "
        "many drones are trusted",
    )
    full_rivals_below: int = Field(
        8,
        ge=0,
        description="search every rival trusted set (each trusted drone swapped for each flagged one, "
        "and left out) when at most this many drones are trusted; above, swap the 2 worst-fitting",
        json_schema_extra=DETECTION,
    )
    rival_drop_margin: float = Field(
        3.0,
        ge=0,
        description="a rival that leaves one more trusted drone out counts when it fits the data it uses "
        "better than the chosen estimate by more than this (chi-square; 3: what leaving out an honest "
        "drone's 3-dof report gains on average)",
        json_schema_extra=DETECTION,
    )
    max_condition: float = Field(
        1e6, gt=1, description="degenerate above this ratio of a drone's largest to smallest variance"
    )
    alert_limit_h: float | None = Field(
        70.0,
        gt=0,
        description="horizontal alert limit (m): a drone whose horizontal protection level is above it is "
        "degenerate, its position withheld (its prior, else nan); 70 m each way keeps the 3-D level within "
        "99 m, so a usable position 100 m off is beyond a level (misleading information); with either "
        "limit set, an untrusted drone whose fault could not be detected (level inf) is withheld too; "
        "None: no limit",
    )
    alert_limit_v: float | None = Field(
        70.0,
        gt=0,
        description="vertical alert limit (m), as alert_limit_h for the vertical protection level",
    )
    better_fit_margin: float | None = Field(
        None,
        ge=0,
        description="a would-be ok verdict takes a rival swap (as many drones left out, as many degrees "
        "of freedom) that passes the tests and fits with a chi-square lower by more than this (the "
        "likelier set), where its own verdict is ok; None: off",
        json_schema_extra=DETECTION,
    )
    registration_rivals: bool = Field(
        False,
        description="the rival check also tries the inlier sets of the rigid registrations of the "
        "range-fixed shape to the reports (the shape detector's candidates): a verdict with such a "
        "rival, leaving at most f_max drones out, passing its tests and placing some drone beyond "
        "the verdict's levels, is unidentifiable (colluders moved rigidly about honest pivots)",
        json_schema_extra=DETECTION,
    )


def given_set_fields() -> frozenset[str]:
    """The `IntegrityParams` an estimate with a given trusted set uses (`given_set`): all but
    the rival search's (marked ``DETECTION``)."""
    fields = IntegrityParams.model_fields.items()
    return frozenset(name for name, f in fields if not (f.json_schema_extra or {}).get("detection"))


def resolve_f_max(p: IntegrityParams, n: int, detector: str) -> int:
    """``f_max`` for a swarm of n drones; more than n - 1 is a one-line ValueError."""
    if p.f_max is None:
        return (n - 1) // 2
    if p.f_max > n - 1:
        raise ValueError(f"{detector}.f_max: {p.f_max} attackers cannot be tolerated among n = {n} drones")
    return p.f_max


def status_rank(status: np.ndarray) -> np.ndarray:
    """How serious each status is: ok 0, degenerate 1, unidentifiable 2, alarm 3 (0 for
    anything else)."""
    status = np.asarray(status)
    if status.size <= 64:  # a step's few: a dictionary (numpy's string calls cost more)
        ranks = [
            _RANK.get(v.decode() if isinstance(v, bytes) else str(v), 0) for v in status.ravel().tolist()
        ]
        return np.array(ranks, dtype=int).reshape(status.shape)
    status = status.astype(str)
    rank = np.zeros(status.shape, dtype=int)
    for k, name in enumerate(STATUS_ORDER):
        rank[status == name] = k
    return rank


def worst_status(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Elementwise the more serious of two status arrays (alarm > unidentifiable > degenerate > ok)."""
    return np.asarray(STATUS_ORDER, dtype=object)[np.maximum(status_rank(a), status_rank(b))]


@dataclass(frozen=True)
class Terms:
    """Hypothesis j's information as measurements: its GNSS report with information ``G``
    (3, 3) where ``gnss`` (T, n) is 1, and its range to each k along the unit vector
    ``u`` (T, j, k, 3) with weight ``w`` (T, j, k) (0: not measured or not used). So
    A_j = gnss_j E_j G E_j' + sum_k w_jk (e_j - e_k)(e_j - e_k)' (x) u_jk u_jk'."""

    gnss: np.ndarray
    G: np.ndarray
    u: np.ndarray
    w: np.ndarray


def _without_each(P0: np.ndarray, b: np.ndarray, t: Terms) -> tuple[np.ndarray, np.ndarray]:
    """For every hypothesis j, the 3x3 diagonal blocks (T, j, n, 3, 3) of P_j = (J - A_j)^-1
    and the step P_j b_j (T, j, n, 3), from P0 = J^-1 by the Woodbury identity
    (`woodbury.without_each`)."""
    return without_each(P0, b, t.gnss, t.G, t.u, t.w)


def _hypothesis_information(
    x: np.ndarray,
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    noise: NoiseModel,
    keep: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, Terms]:
    """Per drone j (as one fault hypothesis), the information of its GNSS report (if
    trusted) and of the ranges it measured (if trusted) to drones in ``keep`` (T, n), as
    measurement terms (`Terms`), and their gradient b (T, n, 3n) at x; also the trusted
    set's information J (T, 3n, 3n), the sum over j of each hypothesis' information A_j.
    Drones outside ``keep`` (undetermined) take no part: an estimate that is still crawling
    along a direction the geometry does not fix would spoil the others'.

    J is built from the terms, not from the A_j (n matrices of 3n x 3n: 1.2 GB at n = 256);
    `_hypothesis_matrix` builds one A_j where it is needed. J equals summing the A_j over j
    in order bit for bit: an off-diagonal block gets two terms, a diagonal one is summed in
    the same order of j. One compiled kernel (`woodbury.hypotheses_kernel`, the numpy
    expressions' order of operations: tests/test_estimation_kernels.py keeps them as its
    reference), where numpy's calls on 17-drone arrays cost 0.15 ms a step."""
    T, n, _ = x.shape
    G = gnss_information(noise.gnss_cov)  # memoised: the same inverse, bit for bit
    J, b = np.empty((T, 3 * n, 3 * n)), np.empty((T, n, 3 * n))
    gnss, u, w = np.empty((T, n)), np.empty((T, n, n, 3)), np.empty((T, n, n))
    hypotheses_kernel(
        np.ascontiguousarray(x, float),
        np.ascontiguousarray(reported, float),
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(trusted, np.bool_),
        np.ascontiguousarray(keep, np.bool_),
        G,
        1.0 / noise.range_sigma**2,
        J,
        b,
        gnss,
        u,
        w,
    )
    return J, b, Terms(gnss, G, u, w)


def _hypothesis_matrix(t: Terms, a: int, j: int) -> np.ndarray:
    """Hypothesis j's information A_j (3n, 3n) in trial a, from its terms (see `Terms`)."""
    n = t.w.shape[1]
    uu = np.einsum("k,ka,kb->kab", t.w[a, j], t.u[a, j], t.u[a, j])  # (k, 3, 3)
    A = np.zeros((n, 3, n, 3))
    idx = np.arange(n)
    A[idx, :, idx, :] = uu
    A[j, :, j, :] = t.gnss[a, j] * t.G + uu.sum(axis=0)
    A[j, :, :, :] -= uu.transpose(1, 0, 2)
    A[:, :, j, :] -= uu
    return A.reshape(3 * n, 3 * n)


def too_few_without_one(
    ranges: np.ndarray, trusted: np.ndarray, prior: np.ndarray | None = None, prior_sigma: float | None = None
) -> np.ndarray:
    """Drones (T, n) whose position one faulty trusted drone could move unseen: a trusted
    drone with fewer than 4 other trusted drones ranging with it (without its own report,
    3 ranges leave a circle of positions its fault can slide along), or an untrusted one that
    would keep fewer than 4 anchors (3 with a prior) if one of them were left out. Detecting a
    fault among the trusted needs that redundancy; without it no protection level exists."""
    out = np.empty(trusted.shape, dtype=bool)
    held = prior_held(prior, prior_sigma, trusted.shape)
    _too_few_kernel(np.ascontiguousarray(ranges, float), np.ascontiguousarray(trusted, np.bool_), held, out)
    return out


@njit(cache=True)
def _too_few_kernel(ranges, trusted, held, out):  # pragma: no cover - compiled
    """`too_few_without_one` in place on out (T, n): each drone's anchors are the trusted
    drones k != i whose range to it (d_ki) was measured."""
    T, n = trusted.shape
    for t in range(T):
        for i in range(n):
            cnt = 0
            for k in range(n):
                if k != i and trusted[t, k] and not np.isnan(ranges[t, k, i]):
                    cnt += 1
            if trusted[t, i]:
                out[t, i] = cnt < 4
            else:
                need = 3 if held[t, i] else 4
                out[t, i] = cnt - 1 < need and cnt > 0


def subset_separations(
    x: np.ndarray,
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    noise: NoiseModel,
    at_most: int,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
    skip: np.ndarray | None = None,
    again: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact solution separations (T, j, n, 3): for trials with at most ``at_most`` trusted
    drones, each hypothesis "trusted drone j is faulty" re-solved from x (Levenberg-Marquardt
    without j's report and the ranges it measured) minus x; nan elsewhere, and in the trials
    ``skip`` (T,) marks. Few trusted drones are where a fault bends the problem most and the
    linearised separation misses it. Also returns which trials (T,) have a hypothesis whose
    re-solve did not converge; with ``again``, such a hypothesis is solved from closed-form
    multilateration too, and the lower cost kept (`assess`)."""
    T, n, _ = x.shape
    out = np.full((T, n, n, 3), np.nan)
    unconverged = np.zeros(T, dtype=bool)
    small = trusted.sum(axis=1) <= at_most
    rows = np.flatnonzero(small if skip is None else small & ~skip)
    t_idx, j_idx = np.nonzero(trusted[rows])
    if not t_idx.size:
        return out, unconverged
    t_idx = rows[t_idx]
    keep = trusted[t_idx].copy()
    keep[np.arange(t_idx.size), j_idx] = False
    has_prior = prior is not None and prior_sigma
    pr = np.where(keep[..., None], np.nan, prior[t_idx]) if has_prior else None

    def solve(x0: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The hypotheses ``k`` (indices) re-solved from x0."""
        return weighted_gauss_newton(
            x0,
            reported[t_idx[k]],
            ranges[t_idx[k]],
            keep[k].astype(float),
            np.broadcast_to(keep[k, :, None], (k.size, n, n)).astype(float),
            noise.gnss_cov,
            noise.range_sigma,
            20,
            prior=None if pr is None else pr[k],
            prior_sigma=prior_sigma if has_prior else None,
            full=True,
            reduced=True,  # a separation only feeds the separation test
        )

    xj, cost, converged = solve(x[t_idx], np.arange(t_idx.size))
    unconverged[t_idx[~converged]] = True
    if again:
        k = np.flatnonzero(~converged)
        if k.size:
            x0 = initial_positions(
                reported[t_idx[k]], ranges[t_idx[k]], keep[k], None if pr is None else pr[k]
            )
            xa, ca, _ = solve(x0, k)
            lower = ca < cost[k]
            xj[k[lower]] = xa[lower]
    out[t_idx, j_idx] = xj - x[t_idx]
    return out, unconverged


def _blocks(P: np.ndarray) -> np.ndarray:
    """3x3 diagonal blocks (..., n, 3, 3) of matrices (..., 3n, 3n) (`levels.blocks_kernel`)."""
    *lead, N, _ = P.shape
    flat = np.ascontiguousarray(P, float).reshape(-1, N, N)
    out = np.empty((flat.shape[0], N // 3, 3, 3))
    blocks_kernel(flat, out)
    return out.reshape(*lead, N // 3, 3, 3)


def _inverse(J: np.ndarray) -> np.ndarray:
    """Inverse of information matrices with a ridge far below any real information, so an
    unobservable direction shows up as a huge variance instead of an exception."""
    N = J.shape[-1]
    scale = np.maximum(np.abs(np.diagonal(J, axis1=-2, axis2=-1)).max(axis=-1), 1e-300)
    return np.linalg.inv(J + (1e-10 * scale)[..., None, None] * np.eye(N))


def _eigenvalues(C: np.ndarray) -> np.ndarray:
    """Ascending eigenvalues of symmetric 3x3 blocks (..., 3, 3) (their lower triangle); 0,
    inf, inf where a block is not finite (`levels.eigenvalues_kernel`)."""
    flat = np.ascontiguousarray(C, float).reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 3))
    eigenvalues_kernel(flat, out)
    return out.reshape(*C.shape[:-1])


@dataclass(frozen=True)
class Assessment:
    """status (T,), per-drone status (T, n), hpl and vpl (T, n) in m, positions (T, n, 3)
    with undetermined drones at their prior or nan, and sigma (T, n, 3): the per-axis
    standard deviation of the all-in-view solution; alarm_cause (T,) why an alarm was raised."""

    status: np.ndarray
    drone_status: np.ndarray
    hpl: np.ndarray
    vpl: np.ndarray
    positions: np.ndarray
    sigma: np.ndarray
    alarm_cause: np.ndarray  # (T,) "", "residual test", "separation test" or "not converged"
    gnss_q: np.ndarray  # (T, n) each trusted drone's whitened GNSS residual^2 (0 if untrusted)
    unverifiable: np.ndarray  # (T, n) placed, but a fault of some trusted drone could not be detected


def beyond_alert_limit(hpl: np.ndarray, vpl: np.ndarray, p: IntegrityParams) -> np.ndarray:
    """Drones whose horizontal or vertical protection level is above its alert limit (finite
    levels only: an infinite one already marks a drone that is not protected at all)."""
    out = np.zeros(hpl.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        if p.alert_limit_h is not None:
            out |= np.isfinite(hpl) & (hpl > p.alert_limit_h)
        if p.alert_limit_v is not None:
            out |= np.isfinite(vpl) & (vpl > p.alert_limit_v)
    return out


def assess(
    est: Estimate,
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    noise: NoiseModel,
    p: IntegrityParams,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
    again: bool = False,
) -> Assessment:
    """Statuses and protection levels of a joint estimate (see the module docstring).

    An ``ok`` verdict whose exact separations (`subset_separations`) include a re-solve that
    did not converge is assessed again with those hypotheses also solved from closed-form
    multilateration, the lower cost kept: from x the solver can crawl along a valley the
    hypothesis opens toward a minimum tens of metres away. In a flat layer at (7, 3), trial
    539 of seed 2025, `clique` trusted drone 3, spoofed 44 m, which tilted the layer and put
    flagged drone 0 48 m up; the other trusted drones lie near a line, so without drone 3 the
    tilt is nearly free: the re-solve from x moved drone 0 1.4 m in its 20 steps (8.5 m in
    200, where it stopped), from the closed form 27 m, at a lower cost. The separation test
    missed the fault and the verdict said ``ok``, 48 m off vertically with a vertical level
    of 14.6 m; assessed again (``again``) it is an ``alarm``. Only would-be ``ok`` verdicts
    are: the others are not used either way."""
    x = est.x
    T, n, _ = x.shape
    _, gq, total, dof = residual_statistics(x, reported, ranges, trusted, noise)
    alarm = ~tests_pass(gq, total, dof, trusted, p.p_fa)
    cause = np.where(alarm, "residual test", "").astype(object)
    common = np.zeros(3) if noise.common_var is None else noise.common_var
    hpl, vpl = np.full((T, n), np.inf), np.full((T, n), np.inf)
    sigma = np.full((T, n, 3), np.inf)
    threshold = float(chi2_quantile(1 - p.p_fa, 1))
    undetermined = est.ambiguous | mirror_ambiguous(x, ranges, trusted, noise, threshold, prior, prior_sigma)
    unverifiable = too_few_without_one(ranges, trusted, prior, prior_sigma) & ~undetermined
    n_h = np.maximum(trusted.sum(axis=1), 1)
    k_fa = -ndtri(p.p_fa / (2 * 3 * n * n_h))  # (T,)
    k_md = -ndtri(p.integrity_risk / (2 * 3 * (n_h + 1)))
    prior_info = np.zeros((T, n, 3))
    if prior is not None and prior_sigma:
        prior_info = np.where(~trusted[..., None] & np.isfinite(prior), 1.0 / prior_sigma**2, 0.0)
    # the separations only decide the separation test: a trial whose residual test already
    # failed is an alarm whatever they are, so its hypotheses are not re-solved
    exact, unconverged = subset_separations(
        est.x, reported, ranges, trusted, noise, p.exact_below, prior, prior_sigma, skip=alarm, again=again
    )
    step = max(1, _MEMORY_FLOATS // (n * (3 * n) ** 2))
    for lo in range(0, T, step):
        s = slice(lo, min(T, lo + step))
        J, b, terms = _hypothesis_information(
            x[s], reported[s], ranges[s], trusted[s], noise, ~undetermined[s]
        )
        tr = trusted[s]
        J[:, np.arange(3 * n), np.arange(3 * n)] += prior_info[s].reshape(-1, 3 * n)
        P0 = _inverse(J)
        C0 = _blocks(P0)  # (t, n, 3, 3)
        ev = _eigenvalues(C0)
        undetermined[s] |= ev[..., 2] > p.max_condition * np.maximum(ev[..., 0], 1e-300)
        # P_j = (J - A_j)^-1 per hypothesis j, by the Woodbury identity from P0; one
        # Gauss-Newton step of the subset problem from x0, where the full gradient is zero:
        # the separation is P_j times the gradient b_j of what hypothesis j leaves out
        Cj, dj = _without_each(P0, b, terms)  # (t, j, n, 3, 3), (t, j, n, 3)
        # where the identity is not precise (a hypothesis that unfixes something: variances
        # growing 1000-fold or more, or not positive), the hypothesis is inverted directly
        vj = np.diagonal(Cj, axis1=-2, axis2=-1)
        v0 = np.diagonal(C0, axis1=-2, axis2=-1)[:, None]
        redo = tr & ~(np.isfinite(vj) & (vj > 0) & (vj <= 1e3 * v0)).all(axis=(2, 3))
        for a, j in zip(*np.nonzero(redo), strict=True):
            Pa = _inverse(J[a] - _hypothesis_matrix(terms, a, j))
            Cj[a, j] = _blocks(Pa)
            # an inverse that is not finite (the hypothesis leaves something unfixed) gives
            # nan separations (inf * 0), never taken below; `levels.unfixed_block` calls its blocks unfixed
            with np.errstate(invalid="ignore"):
                dj[a, j] = (Pa @ b[a, j]).reshape(n, 3)
        # the rest in one compiled pass (`levels.levels_kernel`): per axis, the fault-free
        # level k_md sqrt(var0) and each trusted hypothesis' separation threshold
        # k_fa sqrt(var_j - var0) and level threshold + k_md sqrt(var_j); the separation test
        # |dj| > threshold on fixed drones (dj re-solved, ``exact``, where the set is small);
        # drones a hypothesis leaves unfixed (`levels.unfixed_block`: ill-conditioned, or the variance
        # inflated a millionfold: no other measurement of it at all)
        t_s = tr.shape[0]
        sep, ill = np.empty(t_s, dtype=bool), np.empty((t_s, n), dtype=bool)
        levels_kernel(
            np.ascontiguousarray(C0),
            np.ascontiguousarray(Cj),
            np.ascontiguousarray(dj),
            np.ascontiguousarray(exact[s]),
            np.ascontiguousarray(tr),
            np.ascontiguousarray(undetermined[s]),
            np.ascontiguousarray(ev[..., 2]),
            np.asarray(common, float),
            np.ascontiguousarray(k_fa[s], float),
            np.ascontiguousarray(k_md[s], float),
            float(p.max_condition),
            sigma[s],
            hpl[s],
            vpl[s],
            sep,
            ill,
        )
        unverifiable[s] |= ill & ~undetermined[s]
        cause[s] = np.where(~alarm[s] & sep, "separation test", cause[s])
        alarm[s] |= sep
    # a solver that has not converged is an alarm, unless it crawls along a direction the
    # geometry does not fix (then the drones concerned are degenerate)
    crawl = ~est.converged & ~undetermined.any(axis=1)
    cause = np.where(~alarm & crawl, "not converged", cause)
    alarm |= crawl
    positions = x.copy()
    fill = np.full((T, n, 3), np.nan) if prior is None else prior
    positions[undetermined] = fill[undetermined]
    weak = undetermined | unverifiable
    hpl[weak] = np.inf
    vpl[weak] = np.inf
    status = np.where(alarm, "alarm", np.where(weak.any(axis=1), "degenerate", "ok")).astype(object)
    drone_status = np.where(alarm[:, None], "alarm", np.where(weak, "degenerate", "ok")).astype(object)
    a = Assessment(
        status, drone_status, hpl, vpl, positions, sigma, cause.astype(str), gq, unverifiable & ~undetermined
    )
    rows = np.flatnonzero((status == "ok") & unconverged) if not again else np.zeros(0, int)
    if not rows.size:
        return a
    sub = Estimate(*(getattr(est, k)[rows] for k in Estimate.__dataclass_fields__))
    pr = None if prior is None else prior[rows]
    b = assess(sub, reported[rows], ranges[rows], trusted[rows], noise, p, pr, prior_sigma, again=True)
    return _merged(est, a, rows, sub, b)[1]


def finish(
    batch: SnapshotBatch,
    p: IntegrityParams,
    noise: NoiseModel,
    trusted: np.ndarray,
    starts: tuple[np.ndarray, ...] = (),
    status: np.ndarray | None = None,
    faulty: np.ndarray | None = None,
    diagnostics: dict[str, np.ndarray] | None = None,
    keep_unverified: bool = False,
) -> VerdictBatch:
    """The verdict of a decided trusted set (T, n): robust estimate, statuses and protection
    levels; ``status`` (T,) carries what the detector already knows (``unidentifiable``),
    which the assessment can only make more serious. The flagged drones are ``faulty``
    (default: those outside the trusted set).

    Two checks use the swaps of `rivals.rival_sets` (a flagged drone trusted instead of one
    of the trusted drones that fit worst, or of any where at most ``full_rivals_below`` are
    trusted):

    - repair: a set that fails its residual tests (exclusion could not undo a wrong
      exclusion) is replaced by its best passing swap, if one passes;
    - rivals: a verdict that would be ``ok`` has a rival if a swap (or, where the search is
      full and fewer than ``f_max`` drones are flagged, the set with one trusted drone left
      out) also passes the tests and places some drone beyond its protection level: the data
      do not decide between them.
      The verdict becomes ``unidentifiable``, estimated from the drones both sets trust,
      with only the drones outside both flagged."""
    prob = _Problem.of(batch, noise, p, starts)
    T = prob.reported.shape[0]
    faulty = ~trusted if faulty is None else faulty.copy()
    status = np.full(T, "ok", dtype=object) if status is None else np.asarray(status, dtype=object).copy()
    trusted = trusted.copy()
    est, a = prob.judge(np.arange(T), trusted)
    repaired = _repaired_rows(prob, est, a, status, trusted)
    if repaired is not None:
        rows, sets = repaired
        trusted[rows] = sets
        faulty[rows] = ~sets
        est, a = _rejudged(prob, est, a, rows, trusted)
    final = worst_status(a.status, status)
    known = None  # swaps already searched, for trials whose judgement has not changed since
    if p.better_fit_margin is not None:
        better, known = _better_fit_rows(prob, est, a, final, trusted)
        if better is not None:
            rows, sets = better
            candidate = trusted.copy()
            candidate[rows] = sets
            e, b = prob.judge(rows, candidate)
            take = b.status == "ok"  # the likelier set, where its own verdict is ok
            trusted[rows[take]] = sets[take]
            faulty[rows[take]] = ~sets[take]
            est, a = _merged(est, a, rows[take], e, b, take)
            final = worst_status(a.status, status)
            known = _forget(known, rows[take])
    # the registrations' candidates (a trial's own, whatever its verdict: computed once);
    # an alarm that one of them explains after all; then the rival check, as any verdict
    reg = None
    if p.registration_rivals:
        f_max = resolve_f_max(p, trusted.shape[1], "integrity")
        # (an alarm's candidates are all solved, for `_explained_alarms`)
        verdict = (trusted, final != "alarm")
        reg = candidates(prob.reported, prob.ranges, prob.noise, f_max, p.p_fa, verdict=verdict)
        explained = _explained_alarms(reg, final)
        if explained is not None:
            rows, sets, flags, decided = explained
            trusted[rows], faulty[rows], status[rows] = sets, flags, decided
            est, a = _rejudged(prob, est, a, rows, trusted)
            final = worst_status(a.status, status)
            known = _forget(known, rows)  # their swaps were searched for the sets they had
    rival = _rival_rows(prob, est, a, final, trusted, known, reg)
    if rival is not None:
        rows, common, anywhere = rival
        status[rows] = "unidentifiable"
        faulty[rows] = ~trusted[rows] & ~anywhere
        trusted[rows] &= common
        est, a = _rejudged(prob, est, a, rows, trusted)
        final = worst_status(a.status, status)
    return _verdicts(a, trusted, faulty, status, final, diagnostics, prob, keep_unverified)


def given_set(
    batch: SnapshotBatch, p: IntegrityParams, trusted: np.ndarray, keep_unverified: bool = False
) -> VerdictBatch:
    """The verdicts of a batch whose trusted set (T, n) is given, not detected: the robust
    estimate and the assessment every statistical detector ends with (statuses, protection
    levels, undetermined drones at nan), without the repair and the rival search (the set is
    not in question). With the true honest set, what the estimator achieves when detection is
    perfect: `swarmraft sweep --known-set`. With ``keep_unverified`` an untrusted drone whose
    fault could not be detected keeps its estimate whatever the alert limits (`_verdicts`):
    the set search compares what each set places."""
    prob = _Problem.of(batch, NoiseModel.of(batch, p, "known set"), p)
    trusted = np.asarray(trusted, bool).copy()
    _, a = prob.judge(np.arange(trusted.shape[0]), trusted)
    status = np.full(trusted.shape[0], "ok", dtype=object)
    return _verdicts(a, trusted, ~trusted, status, a.status, None, prob, keep_unverified)


def _verdicts(
    a: Assessment,
    trusted: np.ndarray,
    faulty: np.ndarray,
    status: np.ndarray,
    final: np.ndarray,
    diagnostics: dict[str, np.ndarray] | None,
    prob: _Problem,
    keep_unverified: bool = False,
) -> VerdictBatch:
    """The `VerdictBatch` of an assessment: ``status`` (T,) what the detector decided before
    it (``alarm`` when exclusion was exhausted), ``final`` the verdict's status.

    Then the alert limits, the last word on a verdict that is not an alarm (an alarm's
    positions are estimates for diagnosis, its levels computed as for ok): a drone whose level
    is above them is withheld, its position its prior (else nan), its levels inf, its status
    ``degenerate``, and an ``ok`` verdict with such a drone is ``degenerate``. So is, with
    either limit set, an untrusted drone without a prior whose fault could not be detected
    (`assess`: its level is infinite, beyond any limit), its position nan (a prior given
    without ``prior_sigma`` is not used, and not given either): it is placed only by its ranges to
    the trusted drones, any of which could be faulty unseen, and so few anchors can fit a
    second minimum far off ((9, 4), realistic, trial 15,650: 35-187 m off from 4 anchors). A
    drone with a prior keeps its estimate: the prior (the previous record's position) ties it
    to where the drone was, resolving the mirror of 3 anchors, and withheld it would become
    that prior (in a mission one step old, then nan: `protocol.records.carried_positions`).
    A trusted drone keeps its
    estimate: its own report is in the fit (``keep_unverified``: the untrusted one too).
    Only the label: every decision (repair, rivals, the set search, which reads
    ``diagnostics["status_without_limits"]`` and sees every set's placements through
    `given_set`'s ``keep_unverified``) is the same with or without the limits."""
    drone_status = worst_status(a.drone_status, status[:, None])
    cause = np.where(status == "alarm", "exclusion exhausted", a.alarm_cause)
    live = (final != "alarm")[:, None]
    beyond = beyond_alert_limit(a.hpl, a.vpl, prob.p) & live
    limited = prob.p.alert_limit_h is not None or prob.p.alert_limit_v is not None
    has_prior = prior_held(prob.prior, prob.prior_sigma, trusted.shape)
    unverified = a.unverifiable & ~trusted & ~has_prior & live & (limited and not keep_unverified)
    withheld = beyond | unverified
    unlimited = final.astype(str)
    positions, hpl, vpl = a.positions, a.hpl, a.vpl
    if withheld.any():
        fill = np.full(positions.shape, np.nan) if prob.prior is None else prob.prior
        positions, hpl, vpl = positions.copy(), hpl.copy(), vpl.copy()
        positions[beyond] = fill[beyond]
        positions[unverified] = np.nan  # no prior used (else it would not be withheld): never the prior
        hpl[beyond] = vpl[beyond] = np.inf
        drone_status = worst_status(drone_status, np.where(beyond, "degenerate", "ok"))
        final = worst_status(final, np.where(beyond.any(axis=1), "degenerate", "ok"))
    diag = {
        "sigma": a.sigma,
        "trusted": trusted,
        "alarm_cause": cause,
        "beyond_alert_limit": beyond,
        "unverified": unverified,
        "withheld": withheld,
        "status_without_limits": unlimited,
        **(diagnostics or {}),
    }
    return VerdictBatch(
        positions=positions,
        faulty=faulty,
        status=final.astype(str),
        diagnostics=diag,
        drone_status=drone_status.astype(str),
        hpl=hpl,
        vpl=vpl,
    )


@dataclass(frozen=True)
class _Problem:
    """What every step of `finish` shares: the data, the noise model, the parameters, the
    priors and the detector's starts (all per trial)."""

    reported: np.ndarray
    ranges: np.ndarray
    noise: NoiseModel
    p: IntegrityParams
    prior: np.ndarray | None
    prior_sigma: float | None
    starts: tuple[np.ndarray, ...]

    @classmethod
    def of(
        cls, batch: SnapshotBatch, noise: NoiseModel, p: IntegrityParams, starts: tuple[np.ndarray, ...] = ()
    ) -> _Problem:
        prior = None if batch.prior is None else np.asarray(batch.prior, float)
        reported, ranges = np.asarray(batch.reported, float), np.asarray(batch.ranges, float)
        return cls(reported, ranges, noise, p, prior, batch.prior_sigma, starts)

    def judge(self, rows: np.ndarray, trusted: np.ndarray) -> tuple[Estimate, Assessment]:
        """Robust estimate and assessment of the trials ``rows`` with their trusted sets."""
        pr = None if self.prior is None else self.prior[rows]
        rep, rng, tr = self.reported[rows], self.ranges[rows], trusted[rows]
        window = float(chi2_quantile(1 - self.p.p_fa, 1))
        starts = tuple(s[rows] for s in self.starts)
        est = robust_estimate(rep, rng, tr, self.noise, pr, self.prior_sigma, starts, window=window)
        return est, assess(est, rep, rng, tr, self.noise, self.p, pr, self.prior_sigma)

    def swaps(
        self, est: Estimate, a: Assessment, trusted: np.ndarray, rows: np.ndarray, full: bool = False
    ) -> Rivals:
        """Every flagged drone of the trials ``rows`` swapped in (`rivals.rival_sets`), ranked
        by the GNSS residuals ``a`` already holds for ``est``. With ``full`` (the rival check,
        not the repair: a repair takes the best passing swap, and more swaps only offer it
        more wrong sets) the full search where at most ``full_rivals_below`` drones are
        trusted, with every trusted drone also left out there where fewer than ``f_max`` are
        flagged."""
        full_rows = (trusted.sum(axis=1) <= self.p.full_rivals_below) & full
        room = (~trusted).sum(axis=1) < resolve_f_max(self.p, trusted.shape[1], "integrity")
        return rival_sets(
            est.x,
            self.reported,
            self.ranges,
            trusted,
            self.noise,
            self.p.p_fa,
            rows,
            self.prior,
            self.prior_sigma,
            gnss_q=a.gnss_q,
            full=full_rows,
            drops=room,
            drop_margin=self.p.rival_drop_margin,
        )


def _rejudged(
    prob: _Problem, est: Estimate, a: Assessment, rows: np.ndarray, trusted: np.ndarray
) -> tuple[Estimate, Assessment]:
    """``est`` and ``a`` with the trials ``rows`` judged again with their new trusted sets."""
    e, b = prob.judge(rows, trusted)
    return _merged(est, a, rows, e, b)


def _merged(
    est: Estimate, a: Assessment, rows: np.ndarray, e: Estimate, b: Assessment, take: np.ndarray | None = None
) -> tuple[Estimate, Assessment]:
    """``est`` and ``a`` with the trials ``rows`` replaced by the judgement ``e``, ``b`` (of
    those rows, or of more rows of which ``take`` (bool) picks them)."""

    def part(x: np.ndarray) -> np.ndarray:
        return x if take is None else x[take]

    return (
        Estimate(
            *(merged_rows(getattr(est, k), rows, part(getattr(e, k))) for k in Estimate.__dataclass_fields__)
        ),
        Assessment(
            *(merged_rows(getattr(a, k), rows, part(getattr(b, k))) for k in Assessment.__dataclass_fields__)
        ),
    )


def _repaired_rows(
    prob: _Problem, est: Estimate, a: Assessment, status: np.ndarray, trusted: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """Trials (indices) whose trusted set fails its residual test while a swap passes, and
    the passing swap of lowest chi-square for each (len(rows), n); None if there are none."""
    rows = np.flatnonzero((a.alarm_cause == "residual test") & (status != "alarm") & (~trusted).any(axis=1))
    if not rows.size:
        return None
    r = prob.swaps(est, a, trusted, rows)
    return _cheapest(r, np.where(r.passed, r.cost, np.inf))


def _cheapest(r: Rivals, cost: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Per trial, the rival of lowest finite ``cost`` (B,): the trials (indices) and those
    rivals' sets (len(rows), n); None where no rival has a finite cost."""
    order = np.lexsort((cost, r.owner))  # by trial, then cost
    owners, first = np.unique(r.owner[order], return_index=True)
    best = order[first]
    good = np.isfinite(cost[best])
    if not good.any():
        return None
    return owners[good], r.trusted[best[good]]


def _better_fit_rows(
    prob: _Problem, est: Estimate, a: Assessment, status: np.ndarray, trusted: np.ndarray
) -> tuple[tuple[np.ndarray, np.ndarray] | None, tuple[np.ndarray, Rivals] | None]:
    """Trials (indices) whose would-be ``ok`` verdict has a rival swap (`rivals.rival_sets`,
    the full search where it runs) that passes the tests, leaves out as many drones and has
    as many degrees of freedom, and fits with a lower chi-square: the likelier of two sets
    that explain the data. Returns those trials and their best such swap (len(rows), n), or
    None if there are none; and the trials searched with their swaps (the rival check's
    own, which it need not search again), or None. ``p.better_fit_margin``: by how much
    lower. At (9, 4) (realistic, 3,000 trials with ``set_search``) 26 `ok` verdicts accused
    an honest drone and trusted a spoofed one of 10-15 m; the true set, one swap away,
    fitted better in 20 (chi-square 19 against 36 in trial 16), and a swap fitted better than
    a true set by up to 8.1 by chance (an honest drone's 3-dof report left out)."""
    rows = np.flatnonzero((status == "ok") & (~trusted).any(axis=1))
    if not rows.size:
        return None, None
    r = prob.swaps(est, a, trusted, rows, full=True)
    _, _, chosen, dof = residual_statistics(
        est.x[r.owner], prob.reported[r.owner], prob.ranges[r.owner], trusted[r.owner], prob.noise
    )
    _, _, _, rival_dof = residual_statistics(
        r.x, prob.reported[r.owner], prob.ranges[r.owner], r.trusted, prob.noise
    )
    same = (r.trusted.sum(axis=1) == trusted[r.owner].sum(axis=1)) & (rival_dof == dof)
    likelier = r.passed & same & (r.cost < chosen - prob.p.better_fit_margin)
    return _cheapest(r, np.where(likelier, r.cost, np.inf)), (rows, r)


def _rival_rows(
    prob: _Problem,
    est: Estimate,
    a: Assessment,
    status: np.ndarray,
    trusted: np.ndarray,
    known: tuple[np.ndarray, Rivals] | None = None,
    reg: Candidates | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Trials (indices) whose ``ok`` verdict, or ``degenerate`` verdict with some drone ``ok``,
    has a rival trusted set placing some drone beyond its protection level (an ``ok`` drone:
    the others' levels are inf), and that rival (len(rows), n) twice (what the rivals all
    trust, and what any of them trusts: `_with_registrations` counts several); None if there
    are none. A
    `degenerate` verdict's ``ok`` drones are protected as an ``ok`` verdict's are: at (9, 4)
    (realistic, trial 9,331) `joint` trusted a spoofer, left out an honest drone and placed 3
    drones `ok` 42-118 m off (levels 15-35 m) on the mirror side of a near-plane, one drone
    `degenerate`; the true set, one swap away, was a rival never tried. ``known``: trials
    already searched (with these sets, estimate and assessment) and their swaps; ``reg``: the
    registrations' candidates of every trial, rivals too where given (`_with_registrations`)."""
    # a verdict with nothing flagged has rivals only by leaving a trusted drone out (full search)
    small = trusted.sum(axis=1) <= prob.p.full_rivals_below
    some_ok = (status == "ok") | ((status == "degenerate") & (a.drone_status == "ok").any(axis=1))
    rows = np.flatnonzero(some_ok & ((~trusted).any(axis=1) | small))
    # with registration rivals: every verdict with an `ok` drone, something flagged or not
    # (the colluders' registration can be the set the detector trusted, or one it never
    # tried), and every `degenerate` or `unidentifiable` one that accuses
    accuses = np.isin(status, ("degenerate", "unidentifiable")) & (~trusted).any(axis=1)
    every = np.flatnonzero(some_ok | accuses) if reg is not None else np.zeros(0, int)
    if not rows.size and not every.size:
        return None
    if not rows.size:
        r = Rivals.none(trusted.shape[1])
    elif known is None:
        r = prob.swaps(est, a, trusted, rows, full=True)
    else:
        searched, r = known
        r = r.of_trials(rows)
        fresh = np.setdiff1d(rows, searched)
        if fresh.size:
            r = r.and_(prob.swaps(est, a, trusted, fresh, full=True))
    real = r.passed & _beyond_levels(r.x, a, r.owner).any(axis=1)
    if every.size:
        return _with_registrations(prob, a, trusted, some_ok, r, real, reg.rivals(every))
    if not real.any():
        return None
    # per trial, the first rival found (a trial's own rivals come in the same order whatever
    # other trials are searched with it)
    owners, first = np.unique(r.owner[real], return_index=True)
    other = r.trusted[np.flatnonzero(real)[first]]
    return owners, other, other


def _beyond_levels(x: np.ndarray, a: Assessment, owner: np.ndarray) -> np.ndarray:
    """Which drones of each rival's estimate x (B, n, 3) lie beyond the protection levels of
    the verdict of its trial ``owner`` (B,) (B, n; never where either position is nan)."""
    d = x - a.positions[owner]
    with np.errstate(invalid="ignore"):
        return (np.hypot(d[..., 0], d[..., 1]) > a.hpl[owner]) | (np.abs(d[..., 2]) > a.vpl[owner])


def _with_registrations(
    prob: _Problem,
    a: Assessment,
    trusted: np.ndarray,
    some_ok: np.ndarray,
    r: Rivals,
    real: np.ndarray,
    g: Rivals,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """`_rival_rows` with the registrations' candidates ``g`` as rivals too
    (`registrations.Candidates.rivals`; the swaps ``r``, of which ``real`` count). A
    candidate counts where it passes its tests and places some `ok` drone beyond its levels,
    or, for a verdict without an `ok` drone (``degenerate`` or ``unidentifiable``, accusing),
    where it trusts a drone the verdict accuses (at (7, 3) under colluders rotated about one
    honest pivot `joint` trusted the 3 colluders and the pivot, 4 anchors: every drone
    `degenerate`, and accused 3 honest drones, whose registration with the pivot passed as
    well), and where the verdict's estimate does not fit the candidate's data (below). Every
    rival that counts counts (not only the first): the trials, what all their sets and the
    verdict's trust (len(rows), n), and the drones any of them trusts."""
    g = g.of_rows(np.flatnonzero((g.trusted != trusted[g.owner]).any(axis=1)))  # other sets only
    beyond = _beyond_levels(g.x, a, g.owner)
    trusts_accused = (g.trusted & ~trusted[g.owner]).any(axis=1)
    counts = g.passed & (beyond.any(axis=1) | (~some_ok[g.owner] & trusts_accused))
    # a candidate counts only where the verdict's estimate does not fit the data it uses: a
    # registration refitted to fewer reports gains up to a rigid motion's 6 dof on them by
    # chance (at (7, 1) under plain jumps, counted with only a margin of rival_drop_margin
    # per drone left out, sets of 4 of the 7 drones made 53 % of 2,000 verdicts
    # unidentifiable); colluders' reports are tens of metres from where the verdict places
    # them. Where the verdict places no drone (nan) nothing is known: it counts
    _, _, chosen, _ = residual_statistics(
        a.positions[g.owner], prob.reported[g.owner], prob.ranges[g.owner], g.trusted, prob.noise
    )
    with np.errstate(invalid="ignore"):
        counts &= ~(g.cost >= chosen - chi2_quantile(1 - prob.p.p_fa, 6))
    owner = np.concatenate([r.owner[real], g.owner[counts]])
    sets = np.concatenate([r.trusted[real], g.trusted[counts]])
    if not owner.size:
        return None
    owners = np.unique(owner)
    common = np.ones((owners.size, trusted.shape[1]), dtype=bool)
    anywhere = np.zeros_like(common)
    at = np.searchsorted(owners, owner)
    np.logical_and.at(common, at, sets)
    np.logical_or.at(anywhere, at, sets)
    return owners, common, anywhere


def _explained_alarms(
    c: Candidates, final: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """With registration rivals (every trial's candidates ``c``): the ``alarm`` verdicts
    (indices) that some registration's candidate set explains after all (it passes its
    tests), and what each becomes: one explanation (`registrations.distinct_explanations`:
    a passing set inside a larger one placing every drone alike is the same one) is
    trusted, its status ``ok`` (the assessment may say worse); several are
    ``unidentifiable``, trusting what all of them trust and flagging only what none does.
    Returns the trials, their trusted sets and flags (len(rows), n) and statuses; None
    where there are none. At (7, 3) under colluders rotated about one honest pivot `joint`
    alone raised `alarm`s accusing honest drones while both the honest registration and
    the colluders' passed."""
    rows = np.flatnonzero(final == "alarm")
    out: list[tuple[int, np.ndarray, np.ndarray, str]] = []
    for t in rows:
        ks = np.flatnonzero((c.owner == t) & c.passed)
        if not ks.size:
            continue
        ks = ks[distinct_explanations(c.masks[ks], c.x[ks], c.Winv, c.threshold)]
        sets = c.masks[ks]
        decided = "ok" if ks.size == 1 else "unidentifiable"
        out.append((t, sets.all(axis=0), ~sets.any(axis=0), decided))
    if not out:
        return None
    return (
        np.array([o[0] for o in out]),
        np.array([o[1] for o in out]),
        np.array([o[2] for o in out]),
        np.array([o[3] for o in out], dtype=object),
    )


def _forget(known: tuple[np.ndarray, Rivals] | None, rows: np.ndarray) -> tuple[np.ndarray, Rivals] | None:
    """The swaps already searched, ``known``, without those of the trials ``rows`` (their
    trusted sets changed since)."""
    if known is None:
        return None
    kept = np.setdiff1d(known[0], rows)
    return kept, known[1].of_trials(kept)
