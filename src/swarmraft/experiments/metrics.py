"""Per-cell statistics of per-trial metrics."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from swarmraft.estimation.snapshot import STATUSES

CELL_COLUMNS = (
    "n",
    "f",
    "trials",
    "preset",
    "detector",
    "attack",
    "baseline_mean",
    "baseline_sem",
    "recovered_mean",
    "recovered_median",
    "recovered_p90",
    "recovered_p99",
    "frac_over_1m",
    "recovered_sem",
    "honest_baseline_mean",
    "honest_mean",
    "honest_median",
    "all_mean",
    "detection_rate",
    "false_positive_rate",
    "identification_rate",
    "status_ok",
    "status_alarm",
    "status_unidentifiable",
    "status_degenerate",
    "attacked_efficiency",
    "attacked_nees",
    "attacked_catastrophic",
    "attacked_bound_excluded",
    "attacked_efficiency_ok",
    "honest_efficiency",
    "honest_nees",
    "honest_catastrophic",
    "honest_bound_excluded",
    "honest_efficiency_ok",
    "misleading_rate",
    "misleading_trials",
    "ok_over_20m_pl",
    "ok_over_20m_hv",
    "ok_over_100m",
    "undetermined_rate",
)

# What a reader of cells.csv may rely on (`sweep.check_cells`): every number is >= 0; these
# are defined in every cell (f >= 1 attacked and n - f >= 2 honest drones, at least one
# trial), the others may be nan (a standard error of one trial, a bound the data lack) ...
CELL_FINITE = (
    "n",
    "f",
    "trials",
    "baseline_mean",
    "honest_baseline_mean",
    "detection_rate",
    "false_positive_rate",
    "identification_rate",
    *(f"status_{s}" for s in STATUSES),
    "attacked_bound_excluded",
    "honest_bound_excluded",
    "ok_over_20m_pl",
    "ok_over_20m_hv",
    "ok_over_100m",
    "undetermined_rate",
)
# ... these are shares, at most 1 ...
CELL_SHARES = (
    "frac_over_1m",
    "detection_rate",
    "false_positive_rate",
    "identification_rate",
    *(f"status_{s}" for s in STATUSES),
    "attacked_catastrophic",
    "honest_catastrophic",
    "misleading_rate",
    "undetermined_rate",
)
# ... and these are counts (of trials or drones).
CELL_COUNTS = (
    "trials",
    "attacked_bound_excluded",
    "honest_bound_excluded",
    "misleading_trials",
    "ok_over_20m_pl",
    "ok_over_20m_hv",
    "ok_over_100m",
)


def sem(x: np.ndarray) -> float:
    """Standard error of the mean of the finite values."""
    v = x[np.isfinite(x)]
    return float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan")


def _mean(x: np.ndarray) -> float:
    v = x[np.isfinite(x)]
    return float(v.mean()) if v.size else float("nan")


def _quantile(x: np.ndarray, q: float) -> float:
    """Quantile of the finite values (trials whose positions were all undetermined have none)."""
    v = x[np.isfinite(x)]
    return float(np.quantile(v, q)) if v.size else float("nan")


def _share_over(x: np.ndarray, limit: float) -> float:
    v = x[np.isfinite(x)]
    return float(np.mean(v > limit)) if v.size else float("nan")


def _efficiency(sq: np.ndarray, bound: np.ndarray) -> float:
    """sqrt(mean squared error / mean trace of the bound) over paired trials; nan if none."""
    b = _mean(bound)
    return float(np.sqrt(_mean(sq) / b)) if b > 0 else float("nan")


def efficiency_interval(
    sq: np.ndarray, bound: np.ndarray, rng: np.random.Generator, level: float = 0.95, resamples: int = 1000
) -> tuple[float, float]:
    """Percentile bootstrap interval (``level``) of `_efficiency` over the paired trials with
    a finite error and bound, resampled together (``resamples`` draws from ``rng``); nan, nan
    with fewer than 2 such trials. Not the delta method: a cell with a few trials tens of
    metres off has a heavy-tailed mean squared error, and a symmetric interval around it
    reached far below the bound (2.99 +- 2.41 for `fde` on jumps at 250 trials) where the
    bootstrap's stays above the trials without those errors."""
    both = np.isfinite(sq) & np.isfinite(bound)
    sq, bound = np.asarray(sq, float)[both], np.asarray(bound, float)[both]
    m = sq.size
    if m < 2 or not bound.sum() > 0:
        return float("nan"), float("nan")
    ratios = np.empty(resamples)
    chunk = max(1, 2_000_000 // m)  # resamples drawn at once: at most 2e6 indices in memory
    for lo in range(0, resamples, chunk):
        idx = rng.integers(0, m, size=(min(chunk, resamples - lo), m))
        with np.errstate(divide="ignore", invalid="ignore"):  # a resample of zero bounds only: inf
            ratios[lo : lo + idx.shape[0]] = sq[idx].sum(axis=1) / bound[idx].sum(axis=1)
    tail = (1 - level) / 2
    low, high = np.quantile(np.sqrt(ratios), [tail, 1 - tail])
    return float(low), float(high)


def summarize_cell(trials: Mapping[str, np.ndarray], labels: Mapping[str, str]) -> dict:
    """One row of cells.csv from one cell's per-trial columns."""
    rec = np.asarray(trials["recovered"], dtype=float)
    status = np.asarray(trials["status"]).astype(str)
    row = {
        "n": int(trials["n"][0]),
        "f": int(trials["f"][0]),
        "trials": int(rec.size),
        **labels,
        "baseline_mean": _mean(trials["baseline"]),
        "baseline_sem": sem(trials["baseline"]),
        "recovered_mean": _mean(rec),
        "recovered_median": _quantile(rec, 0.5),
        "recovered_p90": _quantile(rec, 0.90),
        "recovered_p99": _quantile(rec, 0.99),
        "frac_over_1m": float(np.mean(rec[np.isfinite(rec)] > 1.0))
        if np.isfinite(rec).any()
        else float("nan"),
        "recovered_sem": sem(rec),
        "honest_baseline_mean": _mean(trials["honest_baseline"]),
        "honest_mean": _mean(trials["honest"]),
        "honest_median": _quantile(np.asarray(trials["honest"], float), 0.5),
        "all_mean": _mean(trials["all"]),
        "detection_rate": _mean(trials["detection_rate"]),
        "false_positive_rate": _mean(trials["false_positive_rate"]),
        "identification_rate": _mean(np.asarray(trials["identified"], dtype=float)),
    }
    for s in STATUSES:
        row[f"status_{s}"] = float(np.mean(status == s))
    ok = status == "ok"
    for g in ("attacked", "honest"):
        # efficiency = sqrt(mean squared error / mean trace of the bound), both over the same
        # trials: those with a finite bound and an error (the others are counted); over every
        # trial whatever its status, and over the ok verdicts only (what a user may use)
        sq_t, bound_t = np.asarray(trials[f"{g}_sq"], float), np.asarray(trials[f"{g}_bound"], float)
        both = np.isfinite(sq_t) & np.isfinite(bound_t)
        row[f"{g}_efficiency"] = _efficiency(sq_t[both], bound_t[both])
        row[f"{g}_efficiency_ok"] = _efficiency(sq_t[both & ok], bound_t[both & ok])
        row[f"{g}_bound_excluded"] = int((~both).sum()) if np.isfinite(bound_t).any() else 0
        row[f"{g}_nees"] = _mean(np.asarray(trials[f"{g}_nees"], float))
        row[f"{g}_catastrophic"] = _mean(np.asarray(trials[f"{g}_catastrophic"], float))
    # nan where the trial's verdict has no protection levels (`paper`): not judged
    mis_t = np.asarray(trials["misleading"], float)
    judged = np.isfinite(mis_t)
    mis = mis_t > 0
    row["misleading_rate"] = float(mis[ok & judged].mean()) if (ok & judged).any() else float("nan")
    row["misleading_trials"] = int(mis.sum()) if judged.any() else float("nan")
    row["ok_over_20m_pl"] = int(np.asarray(trials["ok_over_20m_pl"], float).sum())
    row["ok_over_20m_hv"] = int(np.asarray(trials["ok_over_20m_hv"], float).sum())
    row["ok_over_100m"] = int(np.asarray(trials["ok_over_100m"], float).sum())
    n = int(trials["n"][0])
    row["undetermined_rate"] = float(np.asarray(trials["undetermined"], float).sum() / (n * rec.size))
    return row
