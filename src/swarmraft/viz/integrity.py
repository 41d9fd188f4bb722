"""The Stanford diagram: position error against protection level, one point per verdict.

Each trial of a sweep contributes its worst drone (the one furthest beyond, or closest to,
its protection level; `experiments.trials.integrity_metrics`). The plane is cut by the
diagonal error = protection level: below it the protection level bounds the error (normal
operation); above it, with status ``ok``, is misleading information, the case integrity
monitoring exists to make rare. Counts are binned on log axes; the numbers of points in
each region and of verdicts that were not ``ok`` (no position to protect) are printed on the
panel.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402


def _panel(ax, err: np.ndarray, pl: np.ndarray, label: str, not_ok: dict[str, int]) -> None:
    show = np.isfinite(err) & np.isfinite(pl) & (pl > 0)
    e, p = np.maximum(err[show], 1e-3), pl[show]
    lo = 10 ** np.floor(np.log10(max(min(e.min(initial=1.0), p.min(initial=1.0)), 1e-3)))
    hi = 10 ** np.ceil(np.log10(max(e.max(initial=1.0), p.max(initial=1.0))))
    bins = np.logspace(np.log10(lo), np.log10(hi), 60)
    if e.size:
        h = ax.hist2d(p, e, bins=[bins, bins], norm=LogNorm(), cmap="viridis")
        plt.colorbar(h[3], ax=ax, label="verdicts per cell")
    ax.plot([lo, hi], [lo, hi], color="black", lw=1)
    ax.fill_between([lo, hi], [lo, hi], [hi, hi], color="tab:red", alpha=0.12, lw=0)
    ax.set(xscale="log", yscale="log", xlim=(lo, hi), ylim=(lo, hi))
    ax.set_xlabel(f"{label} protection level, m")
    ax.set_ylabel(f"{label} position error, m (errors below 1 mm drawn at 1 mm)")
    mi = int((e > p).sum())
    normal = int(e.size - mi)
    ax.text(
        0.03,
        0.97,
        f"misleading information\n(error > PL, status ok): {mi}",
        transform=ax.transAxes,
        va="top",
        color="tab:red",
        fontsize=9,
    )
    rest = ", ".join(f"{k} {v}" for k, v in not_ok.items() if v) or "none"
    ax.text(
        0.97,
        0.03,
        f"normal operation: {normal}\nnot ok (not to be used): {rest}",
        transform=ax.transAxes,
        ha="right",
        va="bottom",
        fontsize=9,
    )


def stanford(trials: Mapping[str, np.ndarray], out: Path, title: str) -> Path:
    """Horizontal and vertical Stanford diagrams of the ``ok`` verdicts of ``trials``
    (columns hpe, hpl, vpe, vpl, status of trials.csv) into ``out``."""
    status = np.asarray(trials["status"]).astype(str)
    ok = status == "ok"
    hpl = np.asarray(trials["hpl"], float)
    if not np.isfinite(hpl[ok]).any():
        raise ValueError(
            "no protection levels in these trials: the detector gives none (paper) or no verdict was ok"
        )
    not_ok = {s: int((status == s).sum()) for s in ("alarm", "unidentifiable", "degenerate")}
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.6))
    _panel(axes[0], np.asarray(trials["hpe"], float)[ok], hpl[ok], "horizontal", not_ok)
    _panel(
        axes[1],
        np.asarray(trials["vpe"], float)[ok],
        np.asarray(trials["vpl"], float)[ok],
        "vertical",
        not_ok,
    )
    fig.suptitle(f"Stanford diagram: {title}; {ok.sum()} ok of {status.size} verdicts (worst drone of each)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
