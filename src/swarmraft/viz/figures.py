"""Figures from results tables (matplotlib, written to files; no screen needed)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from swarmraft.viz.axes import plain_log_labels  # noqa: E402

TRUE_STYLE = {"c": "green", "marker": "x", "s": 60, "label": "true position"}
REPORT_STYLE = {"c": "red", "marker": "^", "s": 50, "label": "report"}
RECOVERED_STYLE = {
    "c": "gold",
    "marker": "*",
    "s": 140,
    "edgecolors": "darkgoldenrod",
    "linewidths": 0.6,
    "label": "verified (SwarmRaft)",
}


def _save(fig: plt.Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return path


def _title(cells: Mapping[str, np.ndarray]) -> str:
    return f"preset {cells['preset'][0]}, detector {cells['detector'][0]}, attack {cells['attack'][0]}"


def _per_cell(counts: Sequence[int]) -> str:
    """'200' or '180-200': the trials per cell of a figure's title."""
    lo, hi = min(counts), max(counts)
    return f"{lo}" if lo == hi else f"{lo}-{hi}"


def scaling(cells: Mapping[str, np.ndarray], path: Path) -> Path:
    """Mean error of the attacked drones against n on a log axis: reports (baseline) and
    verified positions, annotated (n, f); one recovered curve per f when the grid has several
    f per n (each f drawn a little apart). Error bars: 95 % intervals (1.96 standard errors of
    the mean). For the reference
    preset, the paper's published means (its n = 2f+1 cells) are drawn beside ours."""
    from swarmraft.experiments.published import PUBLISHED

    n, f = np.asarray(cells["n"]), np.asarray(cells["f"])
    fig, ax = plt.subplots(figsize=(7.5, 5))
    diagonal = len(np.unique(n)) == len(n)
    order = np.argsort(n, kind="stable")
    if diagonal:
        ax.errorbar(
            n[order],
            cells["baseline_mean"][order],
            yerr=1.96 * cells["baseline_sem"][order],
            fmt="s--",
            color="red",
            label="reported (baseline)",
        )
        rec = np.asarray(cells["recovered_mean"][order], float)
        ax.errorbar(
            n[order],
            rec,
            yerr=1.96 * cells["recovered_sem"][order],
            fmt="o-",
            color="darkorange",
            label="verified (SwarmRaft), 95 % interval",
            capsize=3,
        )
        for ni, fi, r in zip(n[order], f[order], rec, strict=True):
            if not r > 0:
                continue
            ax.annotate(  # left of the point: the published means are drawn right of it
                f"({ni},{fi})",
                (ni, r),
                textcoords="offset points",
                xytext=(-6, -14),
                ha="right",
                fontsize=9,
            )
        ax.margins(x=0.12)  # room for the first one's, clear of the y axis's labels
    else:
        fs = np.unique(f)
        for k, fi in enumerate(fs):
            sel = order[f[order] == fi]
            rec = np.where(cells["recovered_mean"][sel] > 0, cells["recovered_mean"][sel], np.nan)
            half = 1.96 * np.asarray(cells["recovered_sem"][sel], float)
            # 95 % intervals as on the diagonal, each f a little apart so the bars do not
            # overlap; on a log axis the lower bar stops above 0
            ax.errorbar(
                n[sel] + 0.12 * (k - (len(fs) - 1) / 2),
                rec,
                yerr=np.vstack([np.minimum(np.nan_to_num(half), 0.999 * rec), np.nan_to_num(half)]),
                fmt="o-",
                capsize=2,
                label=f"verified, f = {fi}",
            )
        base = [cells["baseline_mean"][n == ni].mean() for ni in np.unique(n)]
        ax.plot(
            np.unique(n), base, "s--", color="red", label="reported (baseline, mean over the f of each n)"
        )
    zero = np.asarray(cells["recovered_mean"]) <= 0
    for ni, fi in zip(n[zero], f[zero], strict=True):  # a log axis cannot draw 0: say so
        ax.annotate(
            f"({ni},{fi}): mean 0 m",
            (ni, 0.02),
            xycoords=("data", "axes fraction"),
            ha="center",
            fontsize=8,
            color="darkorange",
        )
    if str(cells["preset"][0]) == "reference":
        pub = [
            (ni, PUBLISHED[ni])
            for ni, fi in zip(n.tolist(), f.tolist(), strict=True)
            if PUBLISHED.get(ni, (None,))[0] == fi
        ]
        if pub:
            xs = np.array([p[0] for p in pub], float) + 0.3  # beside ours, not on top
            ax.plot(
                xs,
                [p[1][1] for p in pub],
                "D",
                ms=8,
                mfc="none",
                mec="black",
                mew=1.3,
                label="published, verified (drawn at n + 0.3)",
            )
            ax.plot(
                xs,
                [p[1][2] for p in pub],
                "D",
                ms=7,
                mfc="none",
                mec="0.45",
                mew=1.0,
                label="published, reported",
            )
    ax.set_yscale("log")
    plain_log_labels(ax.yaxis)
    ax.set_xlabel("swarm size n")
    ax.set_ylabel("mean error of attacked drones, m (log)")
    ax.set_xticks(np.unique(n))
    ax.grid(True, which="both", ls=":", alpha=0.6)
    if diagonal:
        ax.legend()
    else:  # a curve per f: a long legend, beside the axes rather than over the curves
        fig.set_size_inches(10, 5)
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=9)
    per_cell = _per_cell([int(t) for t in cells["trials"]])
    ax.set_title(f"Error against swarm size\n{_title(cells)}, {per_cell} trials per cell", fontsize=10)
    return _save(fig, path)


def distribution(trials: Mapping[str, np.ndarray], path: Path, title: str = "") -> Path:
    """Box plots of per-trial errors of the attacked drones, reports and verified, per (n, f),
    on a log axis (verified errors reach 1e-9 m); the title is ``title`` (what made the trials)
    and the trials per cell drawn. Trials whose verified error is undefined (every attacked
    drone left undetermined) are counted under the cell's box instead of drawn."""
    n, f = np.asarray(trials["n"]), np.asarray(trials["f"])
    keys = sorted(set(zip(n.tolist(), f.tolist(), strict=True)))
    floor = 1e-12
    base = [np.maximum(trials["baseline"][(n == a) & (f == b)], floor) for a, b in keys]
    rec_all = [np.asarray(trials["recovered"], float)[(n == a) & (f == b)] for a, b in keys]
    # a trial whose attacked drones were all left undetermined (nan) has no error to draw:
    # it is left out of the box and counted under it
    rec = [np.maximum(r[np.isfinite(r)], floor) for r in rec_all]
    undetermined = [int((~np.isfinite(r)).sum()) for r in rec_all]
    pos = np.arange(len(keys)) * 3.0
    fig, ax = plt.subplots(figsize=(max(7, 1.25 * len(keys)), 5))
    b1 = ax.boxplot(
        base,
        positions=pos - 0.55,
        widths=0.9,
        patch_artist=True,
        showfliers=True,
        flierprops={"markersize": 2, "alpha": 0.3},
    )
    b2 = ax.boxplot(
        rec,
        positions=pos + 0.55,
        widths=0.9,
        patch_artist=True,
        showfliers=True,
        flierprops={"markersize": 2, "alpha": 0.3},
    )
    for patch in b1["boxes"]:
        patch.set_facecolor("#f4a6a6")
    for patch in b2["boxes"]:
        patch.set_facecolor("#ffd36e")
    ax.set_yscale("log")
    plain_log_labels(ax.yaxis)
    # a cell's undetermined trials under its name (drawn in the plot, the count ran over the
    # verified box's whisker)
    names = [
        f"({a},{b})" + (f"\n{k} of {r.size}\nundetermined" if k else "")
        for (a, b), k, r in zip(keys, undetermined, rec_all, strict=True)
    ]
    ax.set_xticks(pos, names, fontsize=9)
    for tick, k in zip(ax.get_xticklabels(), undetermined, strict=True):
        if k:
            tick.set_color("#8a5a00")
    ax.set_xlabel("(n, f)")
    ax.set_ylabel(f"per-trial mean error of attacked drones, m (log; floor {floor:g})")
    ax.legend(
        [b1["boxes"][0], b2["boxes"][0]],
        ["reported", "verified"],
        loc="upper left",
        bbox_to_anchor=(1.0, 1.0),
    )
    ax.grid(True, axis="y", which="major", ls=":", alpha=0.6)
    counts = _per_cell([int(((n == a) & (f == b)).sum()) for a, b in keys])
    under = f"{title}, {counts} trials per cell" if title else f"{counts} trials per cell"
    ax.set_title(f"Error distribution per trial\n{under}", fontsize=10)
    return _save(fig, path)


def recovery(
    cases: Sequence[Mapping[str, np.ndarray]], path: Path, view: str = "projections", title: str = ""
) -> Path:
    """The paper's recovery picture: per case, true positions (green x), reports (red
    triangle), verified positions (yellow star) and arrows from truth to the spoofed reports;
    ``view`` "3d" or "projections" (XY and XZ). A failed recovery is ringed in red and its
    error written beside it: an attacked drone left unflagged, or verified farther from its
    true position than max(1 m, 3 x the RMS error of the honest drones' reports). ``title``
    (what drew the cases: preset, detector, seed) goes above the panels."""
    if view not in ("3d", "projections"):
        raise ValueError("view must be '3d' or 'projections'")
    k = len(cases)
    if view == "3d":
        fig = plt.figure(figsize=(5.5 * k, 5.2))
        axes = [[fig.add_subplot(1, k, i + 1, projection="3d")] for i in range(k)]
        planes = [(0, 1, 2)]
    else:
        fig, grid = plt.subplots(2, k, figsize=(5.2 * k, 9.5), squeeze=False)
        axes = [[grid[0, i], grid[1, i]] for i in range(k)]
        planes = [(0, 1), (0, 2)]
    names = "XYZ"
    for case, row in zip(cases, axes, strict=True):
        truth, rep, ver, att = case["truth"], case["reported"], case["verified"], case["attackers"]
        err_all = np.linalg.norm(ver - truth, axis=1)
        honest_rms = (
            float(np.sqrt(np.mean(np.sum((rep[~att] - truth[~att]) ** 2, axis=1)))) if (~att).any() else 0.0
        )
        limit = max(1.0, 3.0 * honest_rms)
        flagged = case.get("faulty", att)
        # a drone not placed (nan) is a failed recovery too, not a silent pass
        failed = att & (~(err_all <= limit) | ~flagged)
        unplaced = att & np.isnan(err_all)
        for ax, plane in zip(row, planes, strict=True):

            def pts(a: np.ndarray, plane: tuple[int, ...] = plane) -> list[np.ndarray]:
                return [a[:, i] for i in plane]

            ax.scatter(*pts(truth), **TRUE_STYLE)
            ax.scatter(*pts(rep[att]), **REPORT_STYLE)
            ax.scatter(*pts(ver), **{**RECOVERED_STYLE, "s": 90})
            for i in np.flatnonzero(att):
                a, b = truth[i, list(plane)], rep[i, list(plane)]
                if len(plane) == 3:
                    ax.plot(*np.stack([a, b]).T, ls="--", color="grey", lw=1)
                else:
                    ax.annotate(
                        "",
                        xy=b,
                        xytext=a,
                        arrowprops={"arrowstyle": "->", "color": "grey", "ls": "--", "lw": 1},
                    )
            if failed.any():
                ax.scatter(
                    *pts(ver[failed]),
                    s=420,
                    facecolors="none",
                    edgecolors="red",
                    linewidths=1.6,
                    label="failed recovery (not flagged, or error above the limit in the title)",
                )
                if len(plane) == 2:
                    for i in np.flatnonzero(failed & ~unplaced):
                        ax.annotate(
                            f"{err_all[i]:.3g} m" + ("" if flagged[i] else ", not flagged"),
                            ver[i, list(plane)],
                            textcoords="offset points",
                            xytext=(14, -14),  # beside the 420-point ring, not under it
                            fontsize=8,
                            color="red",
                            zorder=5,  # above the markers (a label under one read "1?2 m")
                            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
                        )
            ax.set_xlabel(f"{names[plane[0]]} (m)")
            ax.set_ylabel(f"{names[plane[1]]} (m)")
            if len(plane) == 3:
                ax.set_zlabel("Z (m)")
            else:
                ax.set_aspect("equal", adjustable="datalim")
                ax.grid(True, ls=":", alpha=0.5)
        n, f = len(truth), int(att.sum())
        placed = att & ~unplaced
        err = f"{err_all[placed].mean():.2g} m" if placed.any() else "none placed"
        not_placed = f" ({int(unplaced.sum())} not placed)" if unplaced.any() else ""
        row[0].set_title(
            f"n = {n}, f = {f}: mean error of attacked drones\n"
            f"reported {np.linalg.norm(rep - truth, axis=1)[att].mean():.1f} m, "
            f"verified {err}; failed recoveries: {int(failed.sum())} of {f}{not_placed}\n"
            f"(limit {limit:.3g} m: "
            "3x the honest reports' rms error, at least 1 m)",
            fontsize=10,
        )
    handles, labels = [], []
    for row in axes:
        for h, lab in zip(*row[0].get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), frameon=False)
    top = 1.0
    if title:
        fig.suptitle(f"Recovery, one trial per (n, f)\n{title}", fontsize=11)
        top = 0.96 if view == "projections" else 0.92
    fig.tight_layout(rect=(0, 0.05, 1, top))
    return _save(fig, path)


def _cells_text(cells: Sequence[tuple[int, int]]) -> str:
    return ", ".join(f"({n}, {f})" for n, f in cells)


def compare(
    table: Mapping[str, np.ndarray],
    metric: str,
    label: str,
    log: bool,
    path: Path,
    reference: float | None = None,
) -> Path:
    """One metric per detector and (n, f) cell, a panel per attack: a dot per detector with
    its 95 % interval (the table's ``<metric>_lo`` and ``<metric>_hi`` where it has them, else
    1.96 standard errors from its ``<metric>_sem`` column, or ``recovered_sem`` for
    ``recovered_mean``), detectors side by side within a cell and no line joining cells.
    The axis is linear from 0; when ``log`` allows it and the values span more than two
    decades it is logarithmic (dots only, no bars); a rate's interval is cut at 0 and 1.
    ``reference`` draws a horizontal line (e.g. efficiency 1)."""
    attacks = list(dict.fromkeys(np.asarray(table["attack"]).tolist()))
    detectors = list(dict.fromkeys(np.asarray(table["detector"]).tolist()))
    values = np.asarray(table[metric], float)
    sem_name = metric.removesuffix("_mean") + "_sem"
    sems = np.asarray(table[sem_name], float) if sem_name in table else np.full(values.shape, np.nan)
    # an interval of its own (the efficiency's bootstrap): bars from it, not from a sem
    bounds = f"{metric}_lo" in table and f"{metric}_hi" in table
    if bounds:
        low, high = np.asarray(table[f"{metric}_lo"], float), np.asarray(table[f"{metric}_hi"], float)
    positive = values[np.isfinite(values) & (values > 0)]
    use_log = bool(log and positive.size and positive.max() / positive.min() > 100)
    all_cells = sorted({(int(n), int(f)) for n, f in zip(table["n"], table["f"], strict=True)})
    widest = max(
        len({(n, f) for n, f, a in zip(table["n"], table["f"], table["attack"], strict=True) if a == atk})
        for atk in attacks
    )
    fig, axes = plt.subplots(
        1,
        len(attacks),
        figsize=(max(4.5, 0.9 + 0.45 * widest * len(detectors)) * len(attacks), 4.6),
        squeeze=False,
    )
    width = 0.8
    for ax, attack in zip(axes[0], attacks, strict=True):
        sel_a = np.asarray(table["attack"]) == attack
        cells = sorted({(int(n), int(f)) for n, f in zip(table["n"][sel_a], table["f"][sel_a], strict=True)})
        xs = np.arange(len(cells))
        top = 0.0
        for k, det in enumerate(detectors):
            sel = sel_a & (np.asarray(table["detector"]) == det)
            val = {
                (int(n), int(f)): i
                for n, f, i in zip(table["n"][sel], table["f"][sel], np.flatnonzero(sel), strict=True)
            }
            idx = [val.get(c) for c in cells]
            ys = np.array([values[i] if i is not None else np.nan for i in idx])
            es = np.array([1.96 * sems[i] if i is not None else np.nan for i in idx])
            if bounds:
                ys = np.where(ys > 0, ys, np.nan) if use_log else ys
                lo = np.array([low[i] if i is not None else np.nan for i in idx])
                hi = np.array([high[i] if i is not None else np.nan for i in idx])
                es = hi - ys  # for the top of the axis
                yerr = np.maximum(np.nan_to_num(np.vstack([ys - lo, hi - ys])), 0.0)
            elif use_log:
                ys = np.where(ys > 0, ys, np.nan)
                lower = np.where(np.isfinite(es), np.minimum(es, ys * 0.999), 0.0)
                yerr = np.vstack([lower, np.nan_to_num(es)])
            elif metric.endswith("_rate"):
                # a rate's interval stays within [0, 1] (1.96 standard errors ran past 1)
                e = np.nan_to_num(es)
                yerr = np.vstack([np.minimum(e, np.nan_to_num(ys)), np.minimum(e, 1.0 - np.nan_to_num(ys))])
            else:
                yerr = np.nan_to_num(es)
            off = (k - (len(detectors) - 1) / 2) * width / len(detectors)
            ax.errorbar(xs + off, ys, yerr=yerr, fmt="o", ms=5, capsize=3, lw=1.2, color=f"C{k}", label=det)
            top = max(top, float(np.nanmax(np.append(ys + np.nan_to_num(es), 0.0))))
        for x in xs[:-1]:
            ax.axvline(x + 0.5, color="0.8", lw=0.8)
        if reference is not None:
            ax.axhline(reference, color="k", ls="--", lw=1, label=f"reference {reference:g}")
        ax.set_xticks(xs, [f"({n}, {f})" for n, f in cells], rotation=45 if len(cells) > 8 else 0)
        ax.set_xlim(-0.5, len(cells) - 0.5)
        ax.set_xlabel("(n, f)")
        ax.set_title(f"attack: {attack}", fontsize=10)
        if use_log:
            ax.set_yscale("log")
            plain_log_labels(ax.yaxis)
        else:
            ax.set_ylim(bottom=0)
            if metric.endswith("_rate"):  # a rate: the whole 0-1 range unless all are small
                ax.set_ylim(0, 1.03 if top > 0.4 else 1.2 * top + 1e-3)
        ax.grid(True, axis="y", which="both", ls=":", alpha=0.6)
    for ax in axes[0]:
        ax.set_ylabel(label + (" (log axis)" if use_log else ""), fontsize=9)
    axes[0][-1].legend(title="detector", loc="upper left", bbox_to_anchor=(1.0, 1.0))
    presets = ", ".join(dict.fromkeys(np.asarray(table["preset"]).astype(str).tolist()))
    trials = sorted({int(t) for t in table["trials"]})
    trials_text = (
        f"{trials[0]} trials per cell" if len(trials) == 1 else f"{trials[0]}-{trials[-1]} trials per cell"
    )
    interval = "dots: mean, bars: 95 % interval (1.96 standard errors)"
    if bounds:
        interval = "dots: value, bars: 95 % interval (bootstrap over the trials)"
        if not (np.isfinite(low) & np.isfinite(high)).any():
            interval = "dots: value (no interval in the table)"
    elif not np.isfinite(sems).any():
        interval = "dots: mean (no standard error in the table)"
    fig.suptitle(
        f"{label}\npreset {presets}, {trials_text}, (n, f) = {_cells_text(all_cells)}\n{interval}",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, path)


def roc(points: Sequence, path: Path, title: str = "") -> Path:
    """ROC curves: detection rate against false-alarm rate, one curve per detector through
    its operating points sorted by false-alarm rate (then detection rate); the legend names
    the threshold parameter swept and its values at the two ends. A detector whose flags are
    not monotone in its threshold zig-zags. The false-alarm axis is logarithmic above 1e-3
    and linear below, so a false-alarm rate of exactly 0 is drawn at 0."""
    fig, ax = plt.subplots(figsize=(7.0, 5.4))
    swept = []
    for k, det in enumerate(dict.fromkeys(p.detector for p in points if p.kind == "roc")):
        pts = sorted(
            (p.false_alarm, p.detection, p.threshold) for p in points if p.detector == det and p.kind == "roc"
        )
        name = next(p.parameter for p in points if p.detector == det and p.kind == "roc")
        swept.append(f"{det}: {name}")
        fa, pd, th = (np.array(v) for v in zip(*pts, strict=True))
        ax.plot(
            fa,
            pd,
            "o-",
            ms=3.5,
            lw=1.2,
            color=f"C{k}",
            label=f"{det}: {name} = {th[0]:.3g} (left) to {th[-1]:.3g} (right)",
        )
    ax.set_xscale("symlog", linthresh=1e-3, linscale=0.5)
    ax.set_xlim(0, 1.05)
    ax.set_xlabel(
        "false-alarm rate (honest drones flagged; log above 0.001, linear below)\n"
        f"threshold swept: {'; '.join(swept)}"
    )
    ax.set_ylabel("detection rate (attacked drones flagged)")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(True, which="both", ls=":", alpha=0.6)
    ax.legend(title="detector: threshold swept", fontsize=7.5, loc="lower right")
    offset = next(p.offset for p in points if p.kind == "roc")
    ax.set_title(
        f"ROC, spoofs of {offset:g} m, points sorted by false-alarm rate{chr(10) + title if title else ''}",
        fontsize=10,
    )
    return _save(fig, path)


def detection_vs_offset(points: Sequence, path: Path, false_alarm: float, title: str = "") -> Path:
    """Detection probability against spoof offset at a fixed false-alarm rate."""
    fig, ax = plt.subplots(figsize=(6.2, 5))
    for det in dict.fromkeys(p.detector for p in points):
        pts = sorted(
            (p.offset, p.detection, p.false_alarm) for p in points if p.detector == det and p.kind == "offset"
        )
        off, pd, fa = zip(*pts, strict=True)
        ax.plot(off, pd, "o-", label=f"{det} (false alarms here {np.mean(fa):.1%})")
    ax.set_xlabel("spoof offset, m")
    ax.set_ylabel("detection probability")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(True, ls=":", alpha=0.6)
    ax.legend()
    ax.set_title(
        f"Detection against offset; each threshold: false alarms <= {false_alarm:.1%} in the ROC's"
        f" trials\n(legend: the false-alarm rate measured in these trials){chr(10) + title if title else ''}",
        fontsize=10,
    )
    return _save(fig, path)
