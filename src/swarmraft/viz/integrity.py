"""The Stanford diagram: position error against protection level, one point per verdict.

Each trial of a sweep contributes its worst drone (the one furthest beyond, or closest to,
its protection level; `experiments.trials.integrity_metrics`). The plane is cut by the
diagonal error = protection level: below it the protection level bounds the error (normal
operation); above it, with status ``ok``, is misleading information, the case integrity
monitoring exists to make rare; right of the alert limit (dashed) a position is unavailable,
withheld, so no ok verdict is drawn there. Counts are binned on log axes; the numbers of points in
each region are printed on each panel, the verdicts that were not ``ok`` (no position to
protect) by status in the title.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402

from swarmraft.viz.axes import plain_log_labels  # noqa: E402


def _panel(ax, err: np.ndarray, pl: np.ndarray, label: str, limit: float | None = None) -> None:
    show = np.isfinite(err) & np.isfinite(pl) & (pl > 0)
    e, p = np.maximum(err[show], 1e-3), pl[show]
    lo = 10 ** np.floor(np.log10(max(min(e.min(initial=1.0), p.min(initial=1.0)), 1e-3)))
    top = max(e.max(initial=1.0), p.max(initial=1.0), 1.01 * (limit or 0.0))
    hi = 10 ** np.ceil(np.log10(top))
    bins = np.logspace(np.log10(lo), np.log10(hi), 60)
    if e.size:
        # counts from 1 to at least 10 on the colour bar (a bar of one value has no scale)
        top = max(10.0, float(np.histogram2d(p, e, bins=[bins, bins])[0].max()))
        h = ax.hist2d(p, e, bins=[bins, bins], norm=LogNorm(vmin=1, vmax=top), cmap="viridis")
        bar = plt.colorbar(h[3], ax=ax, label="verdicts per cell")
        plain_log_labels(bar.ax.yaxis)  # counts as numbers, not 2x10^0
    ax.plot([lo, hi], [lo, hi], color="black", lw=1)
    ax.fill_between([lo, hi], [lo, hi], [hi, hi], color="tab:red", alpha=0.12, lw=0)
    if limit is not None:
        # the alert limit: a level beyond it makes the position unavailable (withheld, the
        # verdict not ok), so no ok verdict is drawn right of it
        ax.axvline(limit, color="0.3", ls="--", lw=1)
        ax.axvspan(limit, hi, color="0.5", alpha=0.15, lw=0)
        ax.text(
            limit * 0.93,
            10 ** (0.5 * (np.log10(lo) + np.log10(hi))),
            f"alert limit {limit:g} m: beyond it, unavailable (withheld)",
            rotation=90,
            ha="right",
            va="center",
            fontsize=8,
            color="0.3",
        )
    ax.set(xscale="log", yscale="log", xlim=(lo, hi), ylim=(lo, hi))
    plain_log_labels(ax.xaxis)
    plain_log_labels(ax.yaxis)
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
    ax.text(  # below the diagonal, left of where the levels usually lie
        0.16,
        0.03,
        f"normal operation\n(error <= PL, status ok): {normal}",
        transform=ax.transAxes,
        ha="left",
        va="bottom",
        fontsize=9,
    )


def verdict_counts(status: np.ndarray) -> str:
    """The figure's count of verdicts by status: how many are ``ok`` (drawn) and how many,
    of each other status, have no position to use (not drawn)."""
    status = np.asarray(status).astype(str)
    not_ok = {s: int((status == s).sum()) for s in ("alarm", "unidentifiable", "degenerate")}
    rest = ", ".join(f"{k} {v}" for k, v in not_ok.items() if v) or "none"
    return f"{int((status == 'ok').sum())} ok of {status.size} verdicts; not ok (not to be used): {rest}"


def stanford(
    trials: Mapping[str, np.ndarray],
    out: Path,
    title: str,
    limits: tuple[float | None, float | None] = (None, None),
) -> Path:
    """Horizontal and vertical Stanford diagrams of the ``ok`` verdicts of ``trials``
    (columns hpe, hpl, vpe, vpl, status of trials.csv) into ``out``; ``limits``: the
    detector's horizontal and vertical alert limits (m, None: none), drawn with the region
    beyond them (unavailable)."""
    status = np.asarray(trials["status"]).astype(str)
    ok = status == "ok"
    hpl = np.asarray(trials["hpl"], float)
    if not np.isfinite(hpl[ok]).any():
        raise ValueError(
            "no protection levels in these trials: the detector gives none (paper) or no verdict was ok"
        )
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.6))
    _panel(axes[0], np.asarray(trials["hpe"], float)[ok], hpl[ok], "horizontal", limits[0])
    _panel(
        axes[1],
        np.asarray(trials["vpe"], float)[ok],
        np.asarray(trials["vpl"], float)[ok],
        "vertical",
        limits[1],
    )
    # the verdicts with no position to use are counted once, beside the ok ones, not lost
    # in a corner of a panel
    fig.suptitle(f"Stanford diagram: {title}; worst drone of each ok verdict\n{verdict_counts(status)}")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
