"""A mission's swarm map over time: one frame per chosen step, each drawn by
`swarmraft.viz.mission.swarm_map` (truth, reports, committed positions, flagged, crashed and
jammed drones, the Raft leader), written as a GIF (Pillow) or an MP4 (ffmpeg)."""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import animation, rcParams

from swarmraft.viz.figures import plt
from swarmraft.viz.mission import map_legend, swarm_map

ANIMATION_SUFFIXES = (".gif", ".mp4")
#: frames a mission's animation has at most by default (every k-th step, k chosen to fit)
MAX_FRAMES = 120
#: frame size: 6.4 x 6.4 inches at 80 dpi is 512 x 512 pixels
FIGSIZE_IN = (6.4, 6.4)
DPI = 80


def default_every(steps: int, max_frames: int = MAX_FRAMES) -> int:
    """The smallest k for which every k-th of ``steps`` steps gives at most ``max_frames`` frames."""
    return max(1, math.ceil(steps / max_frames))


def frame_steps(steps: int, every: int) -> list[int]:
    """The steps drawn: 0, every, 2 every, ... (ceil(steps / every) frames)."""
    return list(range(0, steps, every))


def check_target(path: Path) -> None:
    """``path`` can be written as an animation here: a .gif, or a .mp4 with ffmpeg on PATH;
    a ValueError saying what to do otherwise."""
    suffix = Path(path).suffix.lower()
    if suffix not in ANIMATION_SUFFIXES:
        raise ValueError(f"{path}: give a file name ending in .gif or .mp4")
    if suffix == ".mp4" and shutil.which(rcParams["animation.ffmpeg_path"]) is None:
        raise ValueError(
            f"{path}: writing .mp4 needs ffmpeg on PATH and there is none; install it "
            "(apt-get install ffmpeg, brew install ffmpeg or conda install ffmpeg) or write a .gif"
        )


def _view(log: Any, steps: list[int]) -> tuple[np.ndarray, float]:
    """Per frame the centre of the true positions (frames, 2), and one half-width, m, for every
    frame: the view follows the swarm at a fixed scale. The half-width covers every true
    position and 99 % of the reported and committed ones (a wild position would otherwise
    shrink the swarm to a dot); a frame says how many points lie beyond it."""
    truth = log.truth[steps, :, :2]
    centre = np.nanmean(truth, axis=1)
    others = np.concatenate([log.reported[steps, :, :2], log.verified[steps, :, :2]], axis=1)
    t_off = np.abs(truth - centre[:, None]).max(axis=2)
    o_off = np.abs(others - centre[:, None]).max(axis=2)
    o_off = o_off[np.isfinite(o_off)]
    half = float(np.nanmax(t_off))
    if o_off.size:
        half = max(half, float(np.percentile(o_off, 99)))
    return centre, 1.08 * half + 3.0


def swarm_animation(
    log: Any,
    path: Path,
    fps: float = 10.0,
    every: int | None = None,
    title: str = "",
    progress: Callable[[int], None] | None = None,
) -> Path:
    """Write the swarm map of every ``every``-th step of a mission (default `default_every`)
    to ``path`` (.gif or .mp4, `check_target`), ``fps`` frames per second. ``log`` is a mission
    log (`swarmraft.sim.mission.MissionLog`, as `swarmraft.experiments.mission_folder` reads
    one back from a results folder). Each frame's title gives the time, the step, the
    leader and the record's status; ``progress(1)`` is called after each frame."""
    path = Path(path)
    check_target(path)
    S = len(log.t)
    every = every or default_every(S)
    steps = frame_steps(S, every)
    centre, half = _view(log, steps)
    if path.suffix.lower() == ".gif":
        writer: animation.AbstractMovieWriter = animation.PillowWriter(fps=fps)
    else:
        writer = animation.FFMpegWriter(fps=fps, extra_args=["-pix_fmt", "yuv420p"])
    path.parent.mkdir(parents=True, exist_ok=True)
    # written beside the target and renamed when whole: an interrupted render leaves no half file
    part = path.with_name(f".{path.stem}.part{path.suffix}")
    fig = plt.figure(figsize=FIGSIZE_IN, dpi=DPI)
    try:
        with writer.saving(fig, str(part), DPI):
            for j, k in enumerate(steps):
                fig.clear()
                ax = fig.add_axes((0.13, 0.2, 0.82, 0.68))
                limits = (
                    (centre[j, 0] - half, centre[j, 0] + half),
                    (centre[j, 1] - half, centre[j, 1] + half),
                )
                record = f"record {log.status[k]}" if log.committed[k] else "no record (skipped)"
                flagged = np.flatnonzero(log.faulty[k] & log.committed[k]) + 1
                swarm_map(
                    ax,
                    log.truth[k],
                    log.reported[k],
                    log.verified[k],
                    log.faulty[k] & log.committed[k],
                    log.spoofed[k],
                    log.outage[k],
                    log.alive[k],
                    f"{record}; flagged: {', '.join(map(str, flagged)) or 'none'}",
                    leader=int(log.leader[k]),
                    limits=limits,
                )
                ax.set_ylabel("north, m")
                pts = np.concatenate([log.truth[k], log.reported[k], log.verified[k]])[:, :2]
                pts = pts[np.isfinite(pts).all(axis=1)]
                beyond = int((np.abs(pts - centre[j]) > half).any(axis=1).sum())
                leader = f"leader {log.leader[k]}" if log.leader[k] else "no leader"
                fig.suptitle(
                    f"{title + ': ' if title else ''}t = {log.t[k]:.1f} s, step {k} of {S - 1}, {leader}"
                    + (f"\n{beyond} point{'s' * (beyond > 1)} beyond the view" if beyond else ""),
                    fontsize=10,
                )
                map_legend(fig, [ax], ncol=3, markerscale=0.6)
                writer.grab_frame()
                if progress is not None:
                    progress(1)
        part.replace(path)
    finally:
        plt.close(fig)
        part.unlink(missing_ok=True)
    return path
