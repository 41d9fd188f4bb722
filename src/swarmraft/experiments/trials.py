"""One Monte Carlo chunk: draw T snapshots of an (n, f) cell, verify them, score them.

Everything random comes from the `numpy.random.Generator` built from the chunk's
`SeedSequence`, so a chunk's result depends only on (config, seed, n, f, chunk index).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from swarmraft.estimation import SnapshotBatch, VerdictBatch, verify_batch, verify_given
from swarmraft.estimation.bounds import CHI2_3DOF_999, error_statistics, gnss_covariance, swarm_crb
from swarmraft.experiments.config import SweepConfig
from swarmraft.world import choose_attackers, flat_layer, formation, near_line, uniform_cube

TRIAL_COLUMNS = (
    *("n", "f", "trial", "baseline", "recovered", "honest_baseline", "honest", "all"),
    *("detection_rate", "false_positive_rate", "identified", "status"),
    *("attacked_sq", "attacked_bound", "attacked_nees", "attacked_catastrophic"),
    *("honest_sq", "honest_bound", "honest_nees", "honest_catastrophic"),
    *("hpe", "hpl", "vpe", "vpl", "misleading", "ok_over_20m_pl", "ok_over_20m_hv", "ok_over_100m"),
    "undetermined",
)


@dataclass(frozen=True)
class Draw:
    """T snapshots with their ground truth."""

    truth: np.ndarray  # (T, n, 3)
    reported: np.ndarray  # (T, n, 3)
    ranges: np.ndarray  # (T, n, n)
    attackers: np.ndarray  # (T, n) bool


def chunk_seed(seed: int, n: int, f: int, chunk: int) -> np.random.SeedSequence:
    """The seed of one chunk: independent of executor, worker count and the rest of the grid."""
    return np.random.SeedSequence(entropy=seed, spawn_key=(n, f, chunk))


REDRAWS = 50  # whole-trial redraws for the attack's min_move at most


def draw(config: SweepConfig, rng: np.random.Generator, trials: int, n: int, f: int) -> Draw:
    """Sample the world for T trials: truth, honest reports, ranges, then the attack. With
    the attack's ``min_move``, a trial in which some attacker's report lies closer than that
    to its truth is drawn again, whole, up to ``REDRAWS`` times (a one-line ValueError naming
    the field beyond)."""
    d = _draw_once(config, rng, trials, n, f)
    need = config.attack.min_move
    if need <= 0:
        return d
    for _ in range(REDRAWS):
        moved = np.linalg.norm(d.reported - d.truth, axis=2)
        short = np.flatnonzero((d.attackers & (moved < need)).any(axis=1))
        if not short.size:
            return d
        again = _draw_once(config, rng, short.size, n, f)
        for name in ("truth", "reported", "ranges", "attackers"):
            getattr(d, name)[short] = getattr(again, name)
    raise ValueError(
        f"attack.min_move: {REDRAWS} draws of a trial at n = {n}, f = {f} never moved every attacker "
        f"{need:g} m or more; lower it"
    )


def _draw_once(config: SweepConfig, rng: np.random.Generator, trials: int, n: int, f: int) -> Draw:
    """One draw of T trials (`draw`)."""
    if config.geometry == "cube":
        truth = uniform_cube(rng, trials, n, config.area_size)
    elif config.geometry == "flat":
        truth = flat_layer(rng, trials, n, config.area_size, config.thickness)
    elif config.geometry == "line":
        truth = near_line(rng, trials, n, config.area_size, config.line_radius)
    else:
        truth = formation(rng, trials, n, config.spacing, config.jitter)
    attackers = choose_attackers(rng, trials, n, f)
    reported = truth.copy()
    if config.gnss is not None:
        reported = reported + config.gnss.model().errors(rng, trials, n)
    ranges = config.ranging.model().measure(rng, truth)
    reported, ranges = config.attack.model().apply(rng, truth, reported, ranges, attackers)
    return Draw(truth, reported, ranges, attackers)


def snapshot_batch(config: SweepConfig, d: Draw) -> SnapshotBatch:
    gs = None if config.gnss is None else (config.gnss.sigma_h, config.gnss.sigma_v)
    return SnapshotBatch(d.reported, d.ranges, gnss_sigma=gs, range_sigma=config.ranging.sigma_for_snapshot)


def _masked_mean(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Mean over the masked drones whose value is defined (a drone whose position the
    detector left undetermined, nan, is counted in ``undetermined`` instead)."""
    mask = mask & np.isfinite(values)
    cnt = mask.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, np.where(mask, values, 0.0).sum(axis=1) / cnt, np.nan)


def bound_metrics(config: SweepConfig, d: Draw, positions: np.ndarray) -> dict[str, np.ndarray]:
    """Per trial and drone group (attacked, honest): mean squared error, mean trace of the
    swarm Cramér-Rao bound (faulty set known), mean NEES against it, and the share of drones
    with NEES above the chi-square 3-dof 0.999 quantile. NaN where the noise model has no
    Gaussian bound (exact data, RSSI ranging, a GNSS sigma of 0: a singular covariance)."""
    T = d.truth.shape[0]
    keys = [f"{g}_{m}" for g in ("attacked", "honest") for m in ("sq", "bound", "nees", "catastrophic")]
    sigma = config.ranging.sigma_for_snapshot
    if config.gnss is None or not sigma or not (config.gnss.sigma_h and config.gnss.sigma_v):
        return {k: np.full(T, np.nan) for k in keys}
    g = config.gnss
    common = gnss_covariance(g.common_h, g.common_v) if g.common_h or g.common_v else None
    symmetric = config.ranging.symmetric
    own = gnss_covariance(g.sigma_h, g.sigma_v)
    C = swarm_crb(
        d.truth, ~d.attackers, ~np.isnan(d.ranges), own, sigma, common_cov=common, symmetric=symmetric
    )
    sq, nees = error_statistics(positions - d.truth, C)
    tr = np.trace(C, axis1=2, axis2=3)
    out = {}
    for g, m in (("attacked", d.attackers), ("honest", ~d.attackers)):
        out[f"{g}_sq"] = _masked_mean(sq, m)
        out[f"{g}_bound"] = _masked_mean(tr, m)
        out[f"{g}_nees"] = _masked_mean(nees, m)
        out[f"{g}_catastrophic"] = _masked_mean((nees > CHI2_3DOF_999).astype(float), m)
    return out


def integrity_metrics(d: Draw, v: VerdictBatch) -> dict[str, np.ndarray]:
    """Per trial: the horizontal and vertical error and protection level of the drone closest
    to (or furthest beyond) its protection level (max of hpe/hpl and vpe/vpl; nan where the
    detector gives no protection level), and counts of drones in an ``ok`` verdict whose
    error exceeds its protection level (``misleading``: hpe > hpl or vpe > vpl), exceeds
    max(20 m, the 3-D protection level) (``ok_over_20m_pl``), has a horizontal error above
    max(20 m, hpl) or a vertical one above max(20 m, vpl) (``ok_over_20m_hv``: each axis
    against its own level, as misleading information is judged; the 3-D test lets a
    drone's large horizontal level cover a vertical error far beyond its vertical level),
    or exceeds 100 m, and of drones left undetermined."""
    err = v.positions - d.truth
    hpe, vpe = np.hypot(err[..., 0], err[..., 1]), np.abs(err[..., 2])
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.fmax(hpe / v.hpl, vpe / v.vpl)
    pick = np.argmax(np.nan_to_num(ratio, nan=-1.0, posinf=-1.0), axis=1)
    t = np.arange(len(pick))
    ok = (v.status == "ok")[:, None] & np.isfinite(hpe)
    e3 = np.linalg.norm(err, axis=2)
    pl3 = np.hypot(v.hpl, v.vpl)
    # a trial whose verdict gives no drone a level (nan: `paper`) is not judged for
    # misleading information: nan, not 0 (no error can exceed a level that is not there)
    levelled = ~(np.isnan(v.hpl) & np.isnan(v.vpl)).all(axis=1)
    misleading = (ok & ((hpe > v.hpl) | (vpe > v.vpl))).sum(axis=1)
    return {
        "hpe": np.where(levelled, hpe[t, pick], np.nan),
        "hpl": v.hpl[t, pick],
        "vpe": np.where(levelled, vpe[t, pick], np.nan),
        "vpl": v.vpl[t, pick],
        "misleading": np.where(levelled, misleading, np.nan),
        "ok_over_20m_pl": (ok & (e3 > np.fmax(20.0, pl3))).sum(axis=1),
        "ok_over_20m_hv": (ok & ((hpe > np.fmax(20.0, v.hpl)) | (vpe > np.fmax(20.0, v.vpl)))).sum(axis=1),
        "ok_over_100m": (ok & (e3 > 100.0)).sum(axis=1),
        "undetermined": (~np.isfinite(e3)).sum(axis=1),
    }


def score(d: Draw, positions: np.ndarray, faulty: np.ndarray) -> dict[str, np.ndarray]:
    """Per-trial metrics: the paper's (mean error over attacked drones; baseline = reports,
    recovered = verified), the same over honest and all drones, detection and false-positive
    rates, and exact identification of the attacker set."""
    rep_err = np.linalg.norm(d.reported - d.truth, axis=2)
    ver_err = np.linalg.norm(positions - d.truth, axis=2)
    att, hon = d.attackers, ~d.attackers
    return {
        "baseline": _masked_mean(rep_err, att),
        "recovered": _masked_mean(ver_err, att),
        "honest_baseline": _masked_mean(rep_err, hon),
        "honest": _masked_mean(ver_err, hon),
        "all": _masked_mean(ver_err, np.ones_like(att)),
        "detection_rate": _masked_mean(faulty.astype(float), att),
        "false_positive_rate": _masked_mean(faulty.astype(float), hon),
        "identified": (faulty == att).all(axis=1),
    }


def run_chunk(
    config: SweepConfig, n: int, f: int, chunk: int, trials: int, params: dict[str, Any]
) -> dict[str, np.ndarray]:
    """Draw, verify and score one chunk; ``params`` are the detector's parameters (with any
    calibrated thresholds already filled in). Returns columns of `TRIAL_COLUMNS`."""
    rng = np.random.default_rng(chunk_seed(config.seed, n, f, chunk))
    d = draw(config, rng, trials, n, f)
    batch = snapshot_batch(config, d)
    if config.known_set:  # the true honest set given: the estimator with perfect detection
        v = verify_given(batch, ~d.attackers, config.detector, **params)
    else:
        v = verify_batch(batch, config.detector, **params)
    out = score(d, v.positions, v.faulty) | bound_metrics(config, d, v.positions) | integrity_metrics(d, v)
    first = chunk * config.chunk_size
    out.update(
        n=np.full(trials, n),
        f=np.full(trials, f),
        trial=np.arange(first, first + trials),
        status=np.asarray(v.status),
    )
    return {k: out[k] for k in TRIAL_COLUMNS}
