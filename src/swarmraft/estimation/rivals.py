"""Rival explanations: another trusted set that explains the data as well as the chosen one.

A detector picks one trusted set; its tests show that set is consistent, not that it is the
only consistent one. With few honest drones to spare (n near 2f + 1), a spoofed report can
fit the honest ones once an honest drone is left out: the ranges fix the swarm's shape, and
a rotation of that shape about the remaining honest drones carries the spoofed drone to its
report. Both partitions then pass every test, with about the same cost, and their positions
differ by tens of metres (seen at n = 9, f = 4, realistic noise). No protection level of
either covers the other, so the verdict must not say ``ok``.

`rival_sets` looks for such a set around every flagged drone e: the chosen set with e
trusted instead of one of the few trusted drones whose GNSS reports fit the chosen estimate
worst (where a hidden spoofed report shows). A rival leaves out as many drones as the chosen
set: an explanation that needs more faulty drones is less plausible, and with enough drones
left out some rotation always fits. Each rival is solved from closed-form multilateration and
put through the same residual tests; `integrity.finish` then asks whether a rival that passes
places some drone beyond its protection level. This is a search, not an enumeration of every
partition: it costs one solve per flagged drone and swap (at n = 17, f = 8: 16 small solves).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarmraft.estimation.joint import joint_estimate, residual_statistics, tests_pass
from swarmraft.estimation.noise import NoiseModel


@dataclass(frozen=True)
class Rivals:
    """For each rival searched (a flagged drone swapped in for a trusted one): its trial
    ``owner`` (B,), trusted set ``trusted`` (B, n), whether it passes the tests ``passed``
    (B,), and its joint estimate ``x`` (B, n, 3)."""

    owner: np.ndarray
    trusted: np.ndarray
    passed: np.ndarray
    x: np.ndarray
    cost: np.ndarray  # (B,) the chi-square of each rival's fit


def rival_sets(
    x: np.ndarray,
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    noise: NoiseModel,
    p_fa: float,
    rows: np.ndarray,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
    swaps: int = 2,
    iters: int = 10,
    gnss_q: np.ndarray | None = None,
) -> Rivals:
    """The rivals of every drone e flagged in the trials ``rows`` (indices): the chosen set
    with e trusted instead of one of the ``swaps`` trusted drones whose GNSS reports fit the
    chosen estimate x (T, n, 3) worst; see the module docstring. ``gnss_q`` (T, n): those
    fits (`joint.residual_statistics` at x), if the caller has them."""
    if gnss_q is None:
        _, gnss_q, _, _ = residual_statistics(x, reported, ranges, trusted, noise)
    rows = np.asarray(rows, dtype=int)
    # per trial, up to ``swaps`` of its own trusted drones (not the batch's fewest)
    k = np.minimum(swaps, trusted[rows].sum(axis=1))  # (len(rows),)
    worst = np.argsort(np.where(trusted, -gnss_q, np.inf), axis=1)[:, :swaps]  # (T, <= swaps)
    t_idx, e_idx = np.nonzero(~trusted[rows])
    owner = np.repeat(rows[t_idx], k[t_idx])
    e_idx = np.repeat(e_idx, k[t_idx])
    rank = np.arange(owner.size) - np.repeat(np.cumsum(k[t_idx]) - k[t_idx], k[t_idx])
    out = worst[owner, rank]
    B = owner.size
    sets = trusted[owner].copy()
    sets[np.arange(B), out] = False
    sets[np.arange(B), e_idx] = True
    rep, rng_ = reported[owner], ranges[owner]
    # from closed-form multilateration (trusted drones at their reports), not from x: a rival
    # is a rotation of tens of metres away, beyond a few local steps from the chosen estimate
    xs = joint_estimate(
        rep,
        rng_,
        sets,
        noise.gnss_cov,
        noise.range_sigma,
        iters=iters,
        prior=None if prior is None or not prior_sigma else prior[owner],
        prior_sigma=prior_sigma,
        reduced=True,  # a rival only feeds the tests and the comparison with the levels
    )
    _, gnss_q, total, dof = residual_statistics(xs, rep, rng_, sets, noise)
    return Rivals(owner, sets, tests_pass(gnss_q, total, dof, sets, p_fa), xs, total)
