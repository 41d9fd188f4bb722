"""Per-cell statistics of per-trial metrics."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

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
    "status_insufficient",
    "status_unidentifiable",
    "attacked_efficiency",
    "attacked_nees",
    "attacked_catastrophic",
    "honest_efficiency",
    "honest_nees",
    "honest_catastrophic",
)


def sem(x: np.ndarray) -> float:
    """Standard error of the mean of the finite values."""
    v = x[np.isfinite(x)]
    return float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan")


def _mean(x: np.ndarray) -> float:
    v = x[np.isfinite(x)]
    return float(v.mean()) if v.size else float("nan")


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
        "recovered_median": float(np.median(rec)),
        "recovered_p90": float(np.quantile(rec, 0.90)),
        "recovered_p99": float(np.quantile(rec, 0.99)),
        "frac_over_1m": float(np.mean(rec > 1.0)),
        "recovered_sem": sem(rec),
        "honest_baseline_mean": _mean(trials["honest_baseline"]),
        "honest_mean": _mean(trials["honest"]),
        "honest_median": float(np.median(trials["honest"])),
        "all_mean": _mean(trials["all"]),
        "detection_rate": _mean(trials["detection_rate"]),
        "false_positive_rate": _mean(trials["false_positive_rate"]),
        "identification_rate": _mean(np.asarray(trials["identified"], dtype=float)),
    }
    for s in ("ok", "insufficient", "unidentifiable"):
        row[f"status_{s}"] = float(np.mean(status == s))
    for g in ("attacked", "honest"):
        # efficiency = sqrt(mean squared error / mean trace of the bound)
        sq, bound = (
            _mean(np.asarray(trials[f"{g}_sq"], float)),
            _mean(np.asarray(trials[f"{g}_bound"], float)),
        )
        row[f"{g}_efficiency"] = float(np.sqrt(sq / bound)) if bound > 0 else float("nan")
        row[f"{g}_nees"] = _mean(np.asarray(trials[f"{g}_nees"], float))
        row[f"{g}_catastrophic"] = _mean(np.asarray(trials[f"{g}_catastrophic"], float))
    return row
