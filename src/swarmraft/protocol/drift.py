"""Drag-off over time: a window-limited GLRT on each drone's GNSS-minus-INS innovations and on
the swarm-wide mean of the innovations of the drones present and not caught by the temporal
gate (pooled before the snapshot detector runs: docs/protocol.md, "The drag-off test"), and
the rule for when a drone's INS track may be
re-aligned to its committed position.

Pure: a function of one step's reports and the noise model. Each report carries its drone's
innovations over its last M windows (`Report.drift`), so the test keeps no state between
steps and an auditor re-running a record gets the same answer from the record's evidence.

Noise model of one honest drone's innovation over a window of W s, per axis: the change of
its Gauss-Markov GNSS error plus the drift of its INS integrated over the window. The INS
drift over a window comes from the drone's accelerometer and gyro biases: the same in every
window (a per-drone constant, ``ins_sigma`` over the drones), so averaging windows does not
shrink it; the GNSS part of the sum of m consecutive windows is the error's change over m W,
variance 2 (1 - exp(-m W / tau)) sigma^2. The mean of the last m windows is Gaussian with

    var_m = 2 (1 - exp(-m W / tau)) sigma_gnss^2 / m^2 + sigma_ins^2        (per axis)

and for a drag that started m windows ago the generalised likelihood ratio is the chi-square
(3 dof) of that mean. The test takes the largest over m = 1..M (the unknown start) and
compares it with the chi-square quantile at ``false_alarm / M`` (Bonferroni over the M
lengths): an honest drone trips it with probability at most ``false_alarm`` per step. The
swarm-wide mean of c drones has variance var_m / c: the biases of independent INSs average
out, so a common slow drag of several drones stands out of it before any one drone's does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy.special import chdtri, ndtri

from swarmraft.protocol.records import StepRecord, settled


@dataclass(frozen=True)
class DriftModel:
    """The drag-off test's noise model and false-alarm rates. ``window_s``: the innovation
    window W; ``windows``: M, how many past windows a report carries; ``gnss_sigma`` (h, v)
    and ``gnss_tau_s``: the Gauss-Markov GNSS error (sim.scenario defaults 1.5/3 m, 120 s);
    ``ins_sigma`` (h, v): per-axis 1-sigma of an honest drone's INS drift over one window
    (its grade: world.ins); ``false_alarm``: probability per step that an honest drone (or
    the honest swarm's mean) is found dragged; ``suspect``: the same for the lower level at
    which a drone is suspect, or the swarm is being pulled (its INS tracks stop aligning)."""

    window_s: float = 5.0
    windows: int = 8
    gnss_sigma: tuple[float, float] = (1.5, 3.0)
    gnss_tau_s: float = 120.0
    ins_sigma: tuple[float, float] = (0.26, 0.26)
    false_alarm: float = 1e-6
    suspect: float = 1e-3

    def variance(self) -> np.ndarray:
        """(M, 3): per-axis variance of an honest drone's mean innovation over its last m
        windows, m = 1..M (row m - 1). Remembered per model (read only; a model with a list
        for a tuple cannot be a key, and is computed each time)."""
        try:
            return _variance(self)
        except TypeError:
            return self._variance()

    def _variance(self) -> np.ndarray:
        m = np.arange(1, self.windows + 1, dtype=float)[:, None]
        g = np.array([self.gnss_sigma[0], self.gnss_sigma[0], self.gnss_sigma[1]]) ** 2
        b = np.array([self.ins_sigma[0], self.ins_sigma[0], self.ins_sigma[1]]) ** 2
        gm = 2 * (1 - np.exp(-m * self.window_s / self.gnss_tau_s)) * g / m**2
        return np.maximum(gm + b, 1e-12)

    def threshold(self, rate: float) -> float:
        """The statistic's threshold at ``rate`` per step (chi-square 3 dof at rate / M)."""
        return _chi2_isf(rate / self.windows, 3)


@lru_cache(maxsize=64)
def _variance(model: DriftModel) -> np.ndarray:
    out = model._variance()
    out.flags.writeable = False  # shared by every caller
    return out


@lru_cache(maxsize=64)
def _chi2_isf(p: float, dof: int) -> float:
    """The chi-square quantile with upper tail ``p``, remembered: a step's test asks for the
    same two each time. scipy.special's ufunc, the one behind scipy.stats' ``chi2.isf`` (the
    same bits, edge cases included): importing scipy.stats would add about 40 MB to every
    mission's memory for two numbers."""
    return float(chdtri(dof, p))


@lru_cache(maxsize=64)
def _norm_isf(p: float) -> float:
    """The normal quantile with upper tail ``p`` (``norm.isf``'s ufunc), remembered (as
    `_chi2_isf`)."""
    return float(-ndtri(p))


class DriftVerdict(NamedTuple):
    """One step's drag-off test. ``stat`` (n,): each drone's largest chi-square over the
    window lengths (0 without innovations); ``swarm``: the same for the mean of the pooled
    drones; ``dragged`` (n,): found dragged (its own test, or the swarm's with its mean
    innovation along the swarm's beyond the one-sided ``suspect`` quantile); ``suspect``
    (n,): its own statistic above the suspect level; ``pulled``: the swarm's is."""

    stat: np.ndarray
    swarm: float
    dragged: np.ndarray
    suspect: np.ndarray
    pulled: bool


def window_innovations(reports: dict, n: int, windows: int) -> np.ndarray:
    """(n, M, 3) the reports' window innovations (`Report.drift`), nan where a drone sent
    none (or fewer windows)."""
    out = np.full((n, windows, 3), np.nan)
    for i, r in reports.items():
        if r.drift is not None:
            rows = np.asarray(r.drift, float)[:windows]
            out[i, : len(rows)] = rows
    return out


def drift_test(innov: np.ndarray, pool: np.ndarray, model: DriftModel) -> DriftVerdict:
    """The test on ``innov`` (n, M, 3) (newest window first, nan: none), the swarm-wide
    mean over the drones in ``pool`` (n,) bool. A drone's
    length-m mean counts only if its m newest windows all have innovations."""
    M = model.windows
    var = model.variance()  # (M, 3)
    finite = np.isfinite(innov).all(axis=2)  # (n, M)
    valid = np.cumprod(finite, axis=1).astype(bool)  # the m newest windows all there
    sums = np.cumsum(np.where(finite[..., None], innov, 0.0), axis=1)
    means = sums / np.arange(1, M + 1)[None, :, None]  # (n, M, 3)
    chi = np.where(valid, np.sum(means**2 / var[None], axis=2), 0.0)  # (n, M)
    stat = chi.max(axis=1)
    high = model.threshold(model.false_alarm)
    low = model.threshold(model.suspect)
    # the swarm: per length m, the mean over the pooled drones with m windows
    use = valid & pool[:, None]
    count = use.sum(axis=0)  # (M,)
    per = np.maximum(count, 1)[:, None]
    swarm_mean = np.where(use[..., None], means, 0.0).sum(axis=0) / per
    swarm_chi = np.where(count > 0, np.sum(swarm_mean**2 / (var / per), axis=1), 0.0)
    best = int(np.argmax(swarm_chi))
    swarm = float(swarm_chi[best])
    dragged = stat > high
    if swarm > high:
        u = swarm_mean[best] / np.linalg.norm(swarm_mean[best])
        along = means[:, best] @ u / np.sqrt(var[best] @ u**2)
        dragged |= valid[:, best] & (along > _norm_isf(model.suspect))
    return DriftVerdict(stat, swarm, dragged, stat > low, swarm > low)


def record_drift(reports: dict, n: int, trusted: np.ndarray, model: DriftModel) -> DriftVerdict:
    """The test on a step's reports with the swarm-wide mean over ``trusted`` (n,) bool."""
    return drift_test(window_innovations(reports, n, model.windows), trusted, model)


def realign_test(rec: StepRecord, model: DriftModel) -> DriftVerdict:
    """The drag-off test `realigns` reads: on the record's reports, the swarm-wide mean over
    the drones it trusts and has reports of."""
    return record_drift({r.drone: r for r in rec.reports}, len(rec.faulty), ~rec.faulty & ~rec.missing, model)


def realigns(
    rec: StepRecord, i: int, model: DriftModel | None, test: Callable[[], DriftVerdict] | None = None
) -> bool:
    """Whether drone i aligns its INS track to its position in the committed record ``rec``:
    only if the record trusts it (not flagged) and protects it (its level not inf), is
    settled (not alarm or unidentifiable), its own drag-off test does not find it suspect,
    and the swarm is not *being pulled*: the mean innovation of the drones the record trusts
    is not above the suspect level of the drag-off test. Otherwise its track keeps dead
    reckoning from its last alignment, so a drag that pulls the committed positions does not
    pull the tracks. A pure function of the record (its reports carry the test's input):
    every drone decides the same. ``test``: where the caller has it, `realign_test` of this
    record (the simulator runs it once per record for every drone that applies it)."""
    if rec.faulty[i] or not settled(rec) or not np.isfinite(rec.positions[i]).all():
        return False
    if rec.hpl is not None and np.isinf(rec.hpl[i]):
        # not protected: withheld for a level above the alert limits (the position is the
        # prior, the previous step's) or unchecked; nan (no levels at all, `paper`) aligns
        return False
    if model is None:
        return True
    v = test() if test is not None else realign_test(rec, model)
    return not (v.suspect[i] or v.pulled)
