"""Mission figures: error over time per drone, swarm maps, consensus latency, messages."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from swarmraft.viz.figures import RECOVERED_STYLE, REPORT_STYLE, TRUE_STYLE, _save, plt


def _shade(ax: plt.Axes, t: np.ndarray, mask: np.ndarray, color: str, label: str | None) -> None:
    if not mask.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(t[a], t[min(b, len(t) - 1)], color=color, alpha=0.15, lw=0, label=label)
        label = None


def error_over_time(
    t: np.ndarray,
    errors: dict[str, np.ndarray],
    spoofed: np.ndarray,
    outage: np.ndarray,
    events: Sequence[tuple[float, str]],
    path: Path,
    title: str = "",
) -> Path:
    """One panel per drone: error of raw GNSS, INS alone and SwarmRaft over time (log axis),
    with the Cramér-Rao bound; spoofing and GNSS outages shaded, faults marked."""
    n = spoofed.shape[1]
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(
        rows, cols, figsize=(3.6 * cols, 2.6 * rows), sharex=True, sharey=True, squeeze=False
    )
    floor = 1e-2
    for i in range(rows * cols):
        ax = axes.flat[i]
        if i >= n:
            ax.axis("off")
            continue
        ax.plot(t, np.maximum(errors["gnss"][:, i], floor), color="tab:red", lw=0.8, label="raw GNSS")
        ax.plot(
            t,
            np.maximum(errors["ins_alone"][:, i], floor),
            color="tab:gray",
            lw=0.8,
            ls=":",
            label="INS alone",
        )
        ax.plot(t, np.maximum(errors["swarmraft"][:, i], floor), color="tab:blue", lw=0.9, label="SwarmRaft")
        if np.isfinite(errors["bound"][:, i]).any():
            ax.plot(t, errors["bound"][:, i], color="black", lw=0.8, ls="--", label="Cramér-Rao bound")
        _shade(ax, t, spoofed[:, i], "red", "spoofed")
        _shade(ax, t, outage[:, i], "purple", "GNSS outage")
        for te, _ in events:
            ax.axvline(te, color="k", lw=0.6, alpha=0.5)
        ax.set_yscale("log")
        ax.set_title(f"drone {i + 1}", fontsize=9)
        ax.grid(True, which="major", ls=":", alpha=0.5)
    for ax in axes[-1]:
        ax.set_xlabel("time, s")
    for ax in axes[:, 0]:
        ax.set_ylabel("error, m")
    handles, labels = [], []
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), frameon=False)
    fig.suptitle(
        f"Position error per drone{': ' + title if title else ''} (vertical lines: faults)", fontsize=11
    )
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    return _save(fig, path)


def swarm_maps(
    truth: np.ndarray,
    reported: np.ndarray,
    verified: np.ndarray,
    faulty: np.ndarray,
    steps: Sequence[int],
    t: np.ndarray,
    path: Path,
) -> Path:
    """XY maps at chosen steps: truth, reports, committed positions; flagged drones ringed."""
    k = len(steps)
    fig, axes = plt.subplots(1, k, figsize=(5.0 * k, 4.8), squeeze=False)
    for ax, s in zip(axes[0], steps, strict=True):
        ax.scatter(truth[s, :, 0], truth[s, :, 1], **TRUE_STYLE)
        ax.scatter(reported[s, :, 0], reported[s, :, 1], **{**REPORT_STYLE, "s": 35})
        ax.scatter(verified[s, :, 0], verified[s, :, 1], **{**RECOVERED_STYLE, "s": 70})
        f = faulty[s]
        if f.any():
            ax.scatter(
                verified[s, f, 0],
                verified[s, f, 1],
                s=260,
                facecolors="none",
                edgecolors="tab:blue",
                label="flagged",
            )
        for i in range(truth.shape[1]):
            ax.annotate(str(i + 1), truth[s, i, :2], textcoords="offset points", xytext=(4, 4), fontsize=7)
        ax.set_title(f"t = {t[s]:.1f} s", fontsize=10)
        ax.set_xlabel("east, m")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, ls=":", alpha=0.5)
    axes[0][0].set_ylabel("north, m")
    handles, labels = axes[0][0].get_legend_handles_labels()
    for ax in axes[0][1:]:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), frameon=False)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return _save(fig, path)


def consensus_latency(
    t: np.ndarray, latency_ms: np.ndarray, events: Sequence[tuple[float, str]], path: Path
) -> Path:
    """Time from each step's start to its record's first application; gaps = skipped steps."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [3, 1]})
    a1.plot(t, latency_ms, ".", ms=2)
    for te, label in events:
        a1.axvline(te, color="k", lw=0.7, alpha=0.6)
        a1.annotate(
            label,
            (te, np.nanmax(latency_ms) if np.isfinite(latency_ms).any() else 1),
            fontsize=7,
            rotation=90,
            va="top",
            ha="right",
        )
    skipped = ~np.isfinite(latency_ms)
    if skipped.any():
        a1.plot(t[skipped], np.zeros(skipped.sum()), "x", color="tab:red", ms=4, label="skipped step")
        a1.legend(loc="upper left")
    a1.set_xlabel("time, s")
    a1.set_ylabel("step start to commit, ms")
    a1.grid(True, ls=":", alpha=0.5)
    a2.hist(latency_ms[np.isfinite(latency_ms)], bins=40, orientation="horizontal", color="tab:blue")
    a2.set_xlabel("steps")
    a2.grid(True, ls=":", alpha=0.5)
    fig.suptitle("Consensus latency", fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def messages_per_step(t: np.ndarray, raft: np.ndarray, reports: np.ndarray, n: int, path: Path) -> Path:
    """Messages sent per step (Raft, and reports to the leader) against the Raft minimum for
    one committed entry, 2(n-1): an append and its answer per follower."""
    fig, ax = plt.subplots(figsize=(9, 3.8))
    ax.plot(t, raft, lw=0.8, label="Raft messages (appends, answers, heartbeats, votes)")
    ax.plot(t, reports, lw=0.8, label="reports to the leader")
    ax.axhline(2 * (n - 1), color="k", ls="--", lw=1, label=f"Raft minimum 2(n-1) = {2 * (n - 1)}")
    ax.set_xlabel("time, s")
    ax.set_ylabel("messages per step")
    ax.grid(True, ls=":", alpha=0.5)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    return _save(fig, path)
