"""Mission figures: error over time per drone, swarm maps, consensus latency, messages."""

from __future__ import annotations

import warnings
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


#: below this the error axes are linear, so an exact zero is drawn at zero (symlog)
LINEAR_BELOW_M = 1e-2


def _fault_lines(ax: plt.Axes, events: Sequence[tuple[float, str]], label_it: bool) -> None:
    """Each fault event (time s, what) as a vertical line (one legend entry, "fault"), with
    ``what`` written along it at the top of the axes where ``label_it``. Every mission figure
    with a time axis marks faults with this."""
    for k, (te, what) in enumerate(events):
        ax.axvline(te, color="k", lw=0.8, alpha=0.7, label="fault" if k == 0 else "_nolegend_")
        if label_it:
            ax.annotate(
                what,
                (te, 1.0),
                xycoords=("data", "axes fraction"),
                xytext=(-2, -3),
                textcoords="offset points",
                rotation=90,
                va="top",
                ha="right",
                fontsize=6.5,
                bbox={"fc": "white", "ec": "none", "alpha": 0.7, "pad": 0.5},
            )


#: at most this many panels; a larger swarm gets a panel for each drone with something to see
#: (wrong side of a partition, spoofed, jammed, crashed) and one for all the others
MAX_PANELS = 16


def error_over_time(
    t: np.ndarray,
    errors: dict[str, np.ndarray],
    spoofed: np.ndarray,
    outage: np.ndarray,
    events: Sequence[tuple[float, str]],
    path: Path,
    title: str = "",
    alive: np.ndarray | None = None,
    wrong: np.ndarray | None = None,
    member: np.ndarray | None = None,
) -> Path:
    """One panel per drone: error of raw GNSS, of INS never reset, of INS aligned at the
    start of a GNSS outage, and of SwarmRaft over time, with the snapshot bound; spoofing,
    GNSS outages, time without the drone (crashed) and, with ``member`` (steps x drones: in
    the swarm), time outside the swarm (before it joins, after it leaves) shaded; faults drawn and labelled
    where there are any. ``wrong`` (steps x drones) marks the steps whose record put the drone
    on the wrong side of the partition (an honest drone flagged, a spoofed one not flagged):
    a marker on that drone's SwarmRaft error, and a tick at the top of every panel. The
    axis is logarithmic above LINEAR_BELOW_M and linear below it, so zero is drawn at zero.

    More than MAX_PANELS drones: a panel for each drone ever on the wrong side, then spoofed,
    jammed or crashed, up to MAX_PANELS - 1 of them, and a last panel for all the others,
    drawn as the median and the maximum over them at each step (the title says how many)."""
    n = spoofed.shape[1]
    alive = np.ones_like(spoofed) if alive is None else alive
    wrong = np.zeros_like(spoofed) if wrong is None else wrong
    out = np.zeros_like(spoofed) if member is None else ~member
    alive = alive | out  # outside the swarm: shaded as such, not as crashed
    wrong_step = wrong.any(axis=1)
    singles, rest = _panel_drones(spoofed, outage, alive & ~out, wrong)
    panels = len(singles) + (1 if rest.size else 0)
    cols = int(np.ceil(np.sqrt(panels)))
    rows = int(np.ceil(panels / cols))
    fig, axes = plt.subplots(
        rows, cols, figsize=(3.8 * cols, 2.8 * rows), sharex=True, sharey=True, squeeze=False
    )
    for k in range(rows * cols):
        ax = axes.flat[k]
        if k >= panels:
            ax.axis("off")
            continue
        group = np.array([singles[k]]) if k < len(singles) else rest
        _error_panel(ax, t, errors, group, spoofed, outage, alive, wrong)
        _shade(ax, t, out[:, group].any(axis=1), "tab:olive", "outside the swarm")
        _fault_lines(ax, events, label_it=k < cols)
        ax.set_yscale("symlog", linthresh=LINEAR_BELOW_M, linscale=0.4)
        if wrong_step.any():
            ax.plot(
                t[wrong_step],
                np.full(wrong_step.sum(), 0.97),
                "v",
                ms=4,
                color="darkorange",
                transform=ax.get_xaxis_transform(),
                label="wrong-partition step",
            )
        if group.size == 1:
            i = int(group[0])
            down = np.flatnonzero(~alive[:, i])
            inside = np.flatnonzero(~out[:, i])
            note = f" (crashed at {t[down[0]]:.1f} s)" if down.size else ""
            if inside.size and inside[0] > 0:
                note = f" (joins at {t[inside[0]]:.1f} s)"
            elif inside.size and inside[-1] < len(t) - 1:
                note = f" (leaves at {t[inside[-1] + 1]:.1f} s)"
            ax.set_title(f"drone {i + 1}" + note, fontsize=9, color="dimgray" if note else "black")
        else:
            ax.set_title(f"the other {group.size} drones: median (solid), maximum (thin)", fontsize=9)
        ax.grid(True, which="major", ls=":", alpha=0.5)
    drawn = np.concatenate([np.ravel(v) for v in errors.values()])
    drawn = drawn[np.isfinite(drawn)]
    top = float(drawn.max()) if drawn.size else 1.0
    # shared axes: limits set once all panels are drawn; the bottom just below 0 so that a
    # line at exactly 0 shows above the frame
    axes.flat[0].set_ylim(-0.2 * LINEAR_BELOW_M, max(top, 10 * LINEAR_BELOW_M) * 1.6)
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
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 5), frameon=False, fontsize=8)
    notes = [f"axes log above {LINEAR_BELOW_M:g} m, linear below (0 drawn at 0)"]
    notes.append(
        f"wrong partition in {int(wrong_step.sum())} steps" if wrong_step.any() else "no wrong-partition step"
    )
    if rest.size:
        notes.append(f"{len(singles)} of {n} drones drawn one by one")
    fig.suptitle(
        f"Position error per drone{': ' + title if title else ''}\n{'; '.join(notes)}",
        fontsize=10,
    )
    legend_rows = int(np.ceil(len(labels) / 5))
    fig.tight_layout(rect=(0, 0.025 + 0.025 * legend_rows, 1, 0.97))
    return _save(fig, path)


def _panel_drones(
    spoofed: np.ndarray, outage: np.ndarray, alive: np.ndarray, wrong: np.ndarray
) -> tuple[list[int], np.ndarray]:
    """The drones drawn one per panel, and the others (drawn together in one panel)."""
    n = spoofed.shape[1]
    if n <= MAX_PANELS:
        return list(range(n)), np.array([], int)
    order: list[int] = []
    for mask in (wrong.any(axis=0), spoofed.any(axis=0), outage.any(axis=0), (~alive).any(axis=0)):
        order += [int(i) for i in np.flatnonzero(mask) if i not in order]
    singles = sorted(order[: MAX_PANELS - 1])
    return singles, np.array([i for i in range(n) if i not in singles], int)


def _error_panel(
    ax: plt.Axes,
    t: np.ndarray,
    errors: dict[str, np.ndarray],
    group: np.ndarray,
    spoofed: np.ndarray,
    outage: np.ndarray,
    alive: np.ndarray,
    wrong: np.ndarray,
) -> None:
    """One drone's error series, or for a group the median and maximum over its drones."""

    def draw(key: str, **style) -> None:
        y = errors[key][:, group]
        if not np.isfinite(y).any():
            return
        if group.size == 1:
            ax.plot(t, y[:, 0], **style)
            return
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-nan steps give nan
            ax.plot(t, np.nanmedian(y, axis=1), **style)
            ax.plot(t, np.fmax.reduce(y, axis=1), **{**style, "lw": 0.5, "alpha": 0.6, "label": "_nolegend_"})

    draw("gnss", color="tab:red", lw=0.8, label="raw GNSS")
    draw("ins_alone", color="tab:gray", lw=0.8, ls=":", label="INS never reset")
    draw("ins_aligned", color="purple", lw=1.0, ls="-.", label="INS aligned at the outage's start")
    draw("swarmraft", color="tab:blue", lw=0.9, label="SwarmRaft")
    draw("snapshot_bound", color="black", lw=0.8, ls="--", label="snapshot bound")
    _shade(ax, t, spoofed[:, group].any(axis=1), "red", "spoofed")
    _shade(ax, t, outage[:, group].any(axis=1), "purple", "GNSS outage")
    _shade(ax, t, (~alive[:, group]).any(axis=1), "black", "crashed (not reporting)")
    mine = wrong[:, group].any(axis=1)
    if mine.any():
        y = np.nan_to_num(np.fmax.reduce(errors["swarmraft"][mine][:, group], axis=1), nan=0.0)
        ax.plot(
            t[mine],
            y,
            "o",
            ms=4,
            mfc="none",
            mec="darkorange",
            mew=1.2,
            label="this drone on the wrong side",
        )


def _place_labels(
    ax: plt.Axes, anchors: np.ndarray, texts: Sequence[str], obstacles: np.ndarray, fontsize: float = 7
) -> None:
    """Label each anchor (data coordinates) at the first of 8 offsets around it whose box
    overlaps neither an earlier label nor a marker (``obstacles``, data coordinates); the
    least crowded offset when all overlap. The axes' limits and aspect must be final."""
    ax.apply_aspect()
    to_px = ax.transData.transform
    marks = to_px(obstacles) if len(obstacles) else np.zeros((0, 2))
    dpi_scale = ax.figure.dpi / 72.0
    h = fontsize * 1.2 * dpi_scale
    gap = 5 * dpi_scale
    placed: list[tuple[float, float, float, float]] = []
    for (x, y), text in zip(to_px(anchors), texts, strict=True):
        w = 0.62 * fontsize * len(text) * dpi_scale
        best, best_cost = None, None
        for dx, dy in ((1, 1), (1, -1), (-1, 1), (-1, -1), (1, 0), (-1, 0), (0, 1), (0, -1)):
            x0 = x + dx * gap + (0 if dx > 0 else -w if dx < 0 else -w / 2)
            y0 = y + dy * gap + (0 if dy > 0 else -h if dy < 0 else -h / 2)
            box = (x0, y0, x0 + w, y0 + h)
            cost = sum(
                1 for b in placed if not (box[2] < b[0] or b[2] < box[0] or box[3] < b[1] or b[3] < box[1])
            )
            cost += int(
                (
                    (marks[:, 0] > box[0] - 3)
                    & (marks[:, 0] < box[2] + 3)
                    & (marks[:, 1] > box[1] - 3)
                    & (marks[:, 1] < box[3] + 3)
                ).sum()
            )
            if best_cost is None or cost < best_cost:
                best, best_cost = box, cost
            if cost == 0:
                break
        placed.append(best)
        ax.annotate(
            text,
            ax.transData.inverted().transform((best[0], best[1])),
            fontsize=fontsize,
            ha="left",
            va="bottom",
        )


def swarm_map(
    ax: plt.Axes,
    truth: np.ndarray,
    reported: np.ndarray,
    verified: np.ndarray,
    faulty: np.ndarray,
    spoofed: np.ndarray,
    outage: np.ndarray,
    alive: np.ndarray,
    title: str,
    leader: int = 0,
    limits: tuple[tuple[float, float], tuple[float, float]] | None = None,
) -> None:
    """One step's swarm seen from above on ``ax`` (each array one row per drone: positions
    (n, 3), flags (n,)): truth, reports, committed positions; each report tied to its drone's
    true position by a line (red for a spoofed drone), flagged drones ringed (at their report,
    dashed, where the record gives no position), crashed drones
    (no report) and jammed drones (reporting their INS) marked, the leader (``leader``, a
    1-based drone id; 0 = none) marked with a black diamond; drone numbers placed so that they
    do not overlap. ``limits`` ((xmin, xmax), (ymin, ymax)), m, fix the view; by default it fits
    every finite point."""
    tr, rp, vf = truth[:, :2], reported[:, :2], verified[:, :2]
    for i in range(truth.shape[0]):
        if np.isfinite(rp[i]).all():
            sp = bool(spoofed[i])
            ax.plot(
                [tr[i, 0], rp[i, 0]],
                [tr[i, 1], rp[i, 1]],
                color="red" if sp else "0.6",
                ls="--" if sp else "-",
                lw=1.0 if sp else 0.6,
                label="spoofed report - its drone" if sp else "report - its drone",
                zorder=1,
            )
    ax.scatter(tr[:, 0], tr[:, 1], **TRUE_STYLE, zorder=3)
    ax.scatter(rp[:, 0], rp[:, 1], **{**REPORT_STYLE, "s": 35}, zorder=3)
    ax.scatter(vf[:, 0], vf[:, 1], **{**RECOVERED_STYLE, "s": 70}, zorder=4)
    # markers over the drones, each (drones, at, style): flagged drones ringed where they were
    # placed; one the record gives no position (undetermined: nan) ringed at its report,
    # dashed, so a frame shows every flag it carries; crashed and jammed drones; the leader
    placed = np.isfinite(vf).all(axis=1)
    ring = {"s": 260, "facecolors": "none", "edgecolors": "tab:blue", "zorder": 4}
    lead = np.arange(truth.shape[0]) == leader - 1
    marks = (
        (faulty & placed, vf, {**ring, "linestyles": "-", "label": "flagged"}),
        (
            faulty & ~placed & np.isfinite(rp).all(axis=1),
            rp,
            {**ring, "linestyles": "--", "label": "flagged, no verified position (ringed at its report)"},
        ),
        (~alive, tr, {"s": 150, "marker": "X", "c": "black", "label": "crashed (no report)", "zorder": 5}),
        (
            outage & alive,
            tr,
            {"s": 200, "marker": "s", "facecolors": "none", "edgecolors": "purple", "lw": 1.4}
            | {"label": "jammed (reports its INS)", "zorder": 5},
        ),
        (
            lead,
            tr,
            {"s": 300, "marker": "D", "facecolors": "none", "edgecolors": "black", "lw": 1.2}
            | {"label": "Raft leader", "zorder": 5},
        ),
    )
    for where, at, style in marks:
        if where.any():
            ax.scatter(at[where, 0], at[where, 1], **style)
    pts = np.concatenate([tr, rp, vf])
    pts = pts[np.isfinite(pts).all(axis=1)]
    if limits is None:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        pad = 0.12 * max(hi - lo) + 2.0
        limits = ((lo[0] - pad, hi[0] + pad), (lo[1] - pad, hi[1] + pad))
    ax.set_xlim(*limits[0])
    ax.set_ylim(*limits[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("east, m")
    ax.grid(True, ls=":", alpha=0.5)
    labels, anchors = [], []
    for i in range(truth.shape[0]):
        labels.append(str(i + 1))
        anchors.append(tr[i])
        if spoofed[i] and np.isfinite(rp[i]).all():
            labels.append(f"{i + 1}'")
            anchors.append(rp[i])
    _place_labels(ax, np.array(anchors), labels, pts)


def map_legend(fig: plt.Figure, axes: Sequence[plt.Axes], ncol: int = 5, markerscale: float = 1.0) -> None:
    """One legend under the maps for every kind of marker any of them drew, at most ``ncol`` a
    row, markers drawn ``markerscale`` times their size on the map."""
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(
        handles,
        labels,
        loc="lower center",
        ncol=min(len(labels), ncol),
        frameon=False,
        fontsize=8,
        markerscale=markerscale,
    )


def swarm_maps(
    truth: np.ndarray,
    reported: np.ndarray,
    verified: np.ndarray,
    faulty: np.ndarray,
    steps: Sequence[int],
    t: np.ndarray,
    path: Path,
    spoofed: np.ndarray | None = None,
    outage: np.ndarray | None = None,
    alive: np.ndarray | None = None,
) -> Path:
    """XY maps at chosen steps, one panel each (`swarm_map`), side by side."""
    spoofed = np.zeros_like(faulty) if spoofed is None else spoofed
    outage = np.zeros_like(faulty) if outage is None else outage
    alive = np.ones_like(faulty) if alive is None else alive
    k = len(steps)
    fig, axes = plt.subplots(1, k, figsize=(5.4 * k, 5.4), squeeze=False)
    for ax, s in zip(axes[0], steps, strict=True):
        swarm_map(
            ax,
            truth[s],
            reported[s],
            verified[s],
            faulty[s],
            spoofed[s],
            outage[s],
            alive[s],
            f"t = {t[s]:.1f} s",
        )
    axes[0][0].set_ylabel("north, m")
    map_legend(fig, axes[0])
    fig.suptitle("Swarm seen from above (n' labels the spoofed report of drone n)", fontsize=10)
    fig.tight_layout(rect=(0, 0.1, 1, 0.97))
    return _save(fig, path)


def consensus_latency(
    t: np.ndarray, latency_ms: np.ndarray, events: Sequence[tuple[float, str]], path: Path
) -> Path:
    """Time from each step's start to its record's first application; gaps = skipped steps."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [3, 1]})
    a1.plot(t, latency_ms, ".", ms=2)
    _fault_lines(a1, events, label_it=True)
    skipped = ~np.isfinite(latency_ms)
    if skipped.any():
        a1.plot(t[skipped], np.zeros(skipped.sum()), "x", color="tab:red", ms=4, label="skipped step")
        # outside the axes: inside, the box hid the points under it
        a1.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=8, frameon=False)
    a1.set_xlabel("time, s")
    a1.set_ylabel("step start to commit, ms")
    a1.grid(True, ls=":", alpha=0.5)
    done = latency_ms[np.isfinite(latency_ms)]
    a2.hist(done, bins=40, orientation="horizontal", color="tab:blue")
    if not done.size:  # an empty histogram would say nothing
        a2.text(0.5, 0.5, "no step committed", transform=a2.transAxes, ha="center", color="tab:red")
        a2.set_xticks([])
        a2.set_yticks([])
    a2.set_xlabel("steps")
    a2.grid(True, ls=":", alpha=0.5)
    fig.suptitle("Consensus latency", fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def messages_per_step(
    t: np.ndarray,
    raft: np.ndarray,
    reports: np.ndarray,
    n: int,
    path: Path,
    events: Sequence[tuple[float, str]] = (),
) -> Path:
    """Messages sent per step (Raft, and reports to the leader) against the Raft minimum for
    one committed entry, 2(n-1): an append and its answer per follower; faults marked as in
    the other mission figures."""
    fig, ax = plt.subplots(figsize=(9, 3.8))
    ax.plot(t, raft, lw=0.8, label="Raft messages (appends, answers, heartbeats, votes)")
    ax.plot(t, reports, lw=0.8, label="reports to the leader")
    ax.axhline(2 * (n - 1), color="k", ls="--", lw=1, label=f"Raft minimum 2(n-1) = {2 * (n - 1)}")
    _fault_lines(ax, events, label_it=True)
    ax.set_xlabel("time, s")
    ax.set_ylabel("messages per step")
    ax.grid(True, ls=":", alpha=0.5)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    return _save(fig, path)
