"""Sweep commands: sweep, figure, check, compare, calibrate, curves, detectors."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import click
import numpy as np
from click.core import ParameterSource

from swarmraft.cli.app import console, err_console, main, print_table, print_wrapped, progress_bar
from swarmraft.cli.options import (
    ATTACK_NAMES,
    PRESET,
    SCHEDULER,
    WORKERS,
    ImageFile,
    OutFolder,
    key_values,
    name_list,
    repeated,
    swarm_sizes,
    sweep_config,
    typed,
)
from swarmraft.cli.tables import (
    calibration_table,
    check_legend,
    check_table,
    compare_table,
    summary_table,
)

PARAMS = click.option(
    "--param",
    "params",
    multiple=True,
    metavar="KEY=VALUE",
    help="detector parameter, repeatable (e.g. --param tau=0.3; the value is read as JSON, null: none).",
)


@main.command()
@click.option(
    "--preset",
    type=PRESET,
    default="reference",
    show_default=True,
    help="reference: the paper's code; realistic: GNSS and UWB noise (docs/models.md).",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="TOML file with sweep settings (flags typed here override it; defaults do not).",
)
@click.option("--n", "n_text", help="swarm sizes: 3,5,7 or 3-17 or 3-17:2 [default 3-17:2]")
@click.option("--f", "f_text", help="attacker counts (default: every f <= (n-1)/2)")
@click.option("--diagonal", is_flag=True, help="only the cells n = 2f+1 (as the paper).")
@click.option("--trials", type=click.IntRange(min=1), help="trials per cell [default 10000]")
@click.option("--seed", type=click.IntRange(min=0), help="master seed [default 2025]")
@click.option("--detector", help="registered detector name [default paper]")
@PARAMS
@click.option(
    "--attack",
    help=f"attack [default jump]: {', '.join(ATTACK_NAMES)}, or one registered (docs/models.md)",
)
@click.option(
    "--known-set",
    is_flag=True,
    default=None,
    help="give the detector the true honest set instead of detecting it: its estimate and "
    "assessment with perfect detection (clique, fde, joint, shape: the same with their default "
    "parameters; a detection parameter, the rival search's included, is refused).",
)
@WORKERS
@SCHEDULER
@click.option(
    "--out",
    type=OutFolder(),
    help="results folder [default results/<preset>]; an existing one is resumed.",
)
def sweep(
    preset,
    config_file,
    n_text,
    f_text,
    diagonal,
    trials,
    seed,
    detector,
    params,
    attack,
    known_set,
    workers,
    scheduler,
    out,
) -> None:
    """Monte Carlo sweep over swarm size n and attacker count f.

    Writes cells.csv (one row per (n, f)), trials.csv (one row per trial) and run.json
    (config, seed, version, and each run's executor and time). Cells already in --out are not
    recomputed; a folder made with another seed or config is refused.
    """
    from swarmraft.experiments import run_sweep
    from swarmraft.experiments.executors import check_executor
    from swarmraft.experiments.sweep import check_resume

    config = sweep_config(
        preset,
        config_file,
        n_text,
        f_text,
        diagonal,
        trials,
        seed,
        {
            "detector": detector,
            "detector_params": key_values(params) or None,
            "attack": {"name": attack} if attack else None,
            "known_set": known_set,
        },
    )
    out = out or Path("results") / config.preset
    check_executor(workers, scheduler)
    check_resume(out, config)
    cells = config.cells()
    note_sizes_without_cells(config)
    console.print(
        f"sweep: preset {config.preset}, detector {config.detector}"
        f"{' given the true honest set' if config.known_set else ''}, attack "
        f"{config.attack.name}, {len(cells)} cells x {config.trials} trials, "
        f"seed {config.seed} -> {out}",
        soft_wrap=True,
    )
    prog, start = progress_bar("sweep")
    with prog:
        result = run_sweep(config, out, workers=workers, scheduler=scheduler, progress=start)
    if result.reused:
        console.print(f"reused {len(result.reused)} finished cells from {out}", soft_wrap=True)
    print_table(summary_table(result.cells, f"{config.preset}: mean error of attacked drones"))
    if line := calibration_line(out):
        print_wrapped(line)
    if result.computed:
        console.print(f"done in {result.seconds:.1f} s on {result.executor}")
    else:
        console.print("nothing to run: every cell was already finished")
    for p in result.paths:
        console.print(f"  wrote {p}", soft_wrap=True)


def note_sizes_without_cells(config) -> None:  # noqa: ANN001 (a SweepConfig)
    """A note (stderr) for each swarm size given that makes no cell: no attacker count given
    fits it (f <= (n-1)//2, and the attack's honest drones), so the run leaves it out."""
    have = {n for n, _ in config.cells()}
    if missing := sorted(set(config.n) - have):
        what = (
            "on the diagonal (n = 2f+1 needs n odd)" if config.diagonal else "with the attacker counts given"
        )
        err_console.print(
            f"note: no cell at n = {', '.join(map(str, missing))} {what}: left out", soft_wrap=True
        )


def calibration_line(out: Path) -> str | None:
    """The calibrated thresholds of a results folder, in one line (None if none ran)."""
    from swarmraft.experiments.sweep import read_run

    cal = read_run(out).get("calibration", {})
    if not cal:
        return None
    taus = [c["tau"] for c in cal.values()]
    eps = [c["epsilon"] for c in cal.values()]

    def span(v: list[float]) -> str:
        return f"{min(v):.2f}" if f"{min(v):.2f}" == f"{max(v):.2f}" else f"{min(v):.2f}-{max(v):.2f}"

    return (
        f"thresholds calibrated from honest runs (paper III.E, mu + 3 sigma) for n = "
        f"{', '.join(sorted(cal, key=int))}: tau {span(taus)} m, epsilon {span(eps)} m"
    )


FIGURE_KINDS = ["scaling", "distribution", "recovery", "integrity", "all", "animation"]


@main.command()
@click.argument("kind", type=click.Choice(FIGURE_KINDS))
@click.argument("results", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--out",
    metavar="FILE",
    help="image file, .png, .pdf or .svg (default RESULTS/figures/KIND.png); for animation .gif, "
    "or .mp4 with ffmpeg on PATH (default RESULTS/figures/animation.gif)",
)
@click.option(
    "--view",
    type=click.Choice(["projections", "3d"]),
    default="projections",
    show_default=True,
    help="recovery picture: XY and XZ projections, or 3-D.",
)
@click.option(
    "--fps",
    type=click.FloatRange(min=0, min_open=True),
    help="animation: frames per second [default 10]",
)
@click.option(
    "--every",
    type=click.IntRange(min=1),
    help="animation: draw every k-th step [default: the smallest k giving at most 120 frames]",
)
def figure(kind, results, out, view, fps, every) -> None:
    """Draw a figure from a results folder written by `swarmraft sweep`, or animate a
    mission's.

    scaling: mean error against n (log axis); distribution: box plots of per-trial errors;
    recovery: the paper's picture for (n, f) = (6, 2), (11, 5), (16, 7) drawn with the
    folder's config and seed; integrity: the Stanford diagram (error against protection
    level of every ok verdict, misleading information marked; detectors with a noise model
    only); all: scaling, distribution and recovery.

    animation: a mission's or networked run's folder (`swarmraft mission`, `swarmraft launch`)
    as the swarm seen from above over time, one frame per --every steps at --fps: true,
    reported and committed positions, flagged, crashed and jammed drones and the Raft leader
    marked, time, step and record status in each frame's title.
    """
    from swarmraft.cli.options import IMAGE_SUFFIXES
    from swarmraft.viz.animation import ANIMATION_SUFFIXES

    ctx = click.get_current_context()
    out_param = next(p for p in ctx.command.params if p.name == "out")
    if kind != "animation":
        for name, value in (("--fps", fps), ("--every", every)):
            if value is not None:
                raise click.BadParameter("only for `swarmraft figure animation`", ctx, param_hint=name)
    # an option the figure would not use is refused, not ignored
    if kind not in ("recovery", "all") and ctx.get_parameter_source("view") != ParameterSource.DEFAULT:
        raise click.BadParameter("only for `swarmraft figure recovery` (and all)", ctx, param_hint="--view")
    if kind == "all" and out is not None:
        raise click.BadParameter(
            "names one file, and `all` writes three (into RESULTS/figures): draw one kind at a time",
            ctx,
            param_hint="--out",
        )
    if kind == "animation":
        if out is not None:
            out = ImageFile(ANIMATION_SUFFIXES).convert(out, out_param, ctx)
        draw_animation(results, out, fps or 10.0, every)
        return
    if out is not None:
        out = ImageFile(IMAGE_SUFFIXES).convert(out, out_param, ctx)
    from swarmraft.experiments.config import ConfigError
    from swarmraft.experiments.results_folder import folder_kind

    other = folder_kind(results)
    if other is not None and other != "sweep":
        instead = (
            f"each of its sweeps is in {results}/<attack>/<detector>"
            if other == "compare"
            else "`swarmraft figure animation` animates it"
        )
        raise ConfigError(
            f"RESULTS: {results} is a {other} folder; `swarmraft figure {kind}` draws from a sweep "
            f"folder (cells.csv and run.json): {instead}"
        )
    for path in draw_figures(kind, results, out, view):
        console.print(f"wrote {path}", soft_wrap=True)


def draw_animation(results: Path, out: Path | None, fps: float, every: int | None) -> Path:
    """`swarmraft figure animation`: the folder's mission as a GIF or MP4, with a progress bar."""
    from swarmraft.experiments.mission_folder import read_mission
    from swarmraft.experiments.results_folder import require_kind
    from swarmraft.viz.animation import check_target, default_every, frame_steps, swarm_animation

    require_kind(results, ("mission", "launch"), "RESULTS", "`swarmraft figure animation`")
    target = out or Path(results) / "figures" / "animation.gif"
    try:
        check_target(target)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--out") from None
    m = read_mission(results, "RESULTS")
    steps = len(m.log.t)
    every = every or default_every(steps)
    frames = len(frame_steps(steps, every))
    prog, start = progress_bar("animation", "frames")
    with prog:
        swarm_animation(m.log, target, fps, every, str(m.summary.get("scenario", "")), start(frames, 0))
    console.print(
        f"wrote {target} ({frames} frames, one per {every} of the {steps} steps, {fps:g} frames/s, "
        f"{target.stat().st_size / 1e6:.1f} MB)",
        soft_wrap=True,
    )
    return target


def draw_figures(kind: str, results: Path, out: Path | None = None, view: str = "projections") -> list[Path]:
    from swarmraft import viz
    from swarmraft.estimation.registry import detector_params
    from swarmraft.experiments import SweepConfig
    from swarmraft.experiments.cases import recovery_cases
    from swarmraft.experiments.sweep import load_results

    cells, trials, run = load_results(Path(results))
    if kind in ("distribution", "integrity", "all") and not trials:
        raise ValueError(f"{Path(results) / 'trials.csv'}: missing; the {kind} figure needs it")
    config = SweepConfig(**run["config"])
    labels = f"preset {config.preset}, detector {config.detector}, attack {config.attack.name}"
    kinds = ["scaling", "distribution", "recovery"] if kind == "all" else [kind]
    paths = []
    for k in kinds:
        name = f"{k}_3d.png" if (k == "recovery" and view == "3d") else f"{k}.png"
        target = out if (out and kind != "all") else Path(results) / "figures" / name
        if k == "scaling":
            paths.append(viz.scaling(cells, target))
        elif k == "distribution":
            paths.append(viz.distribution(trials, target, labels))
        elif k == "integrity":
            cellset = ", ".join(f"({a}, {b})" for a, b in zip(cells["n"], cells["f"], strict=True))
            title = f"{cells['preset'][0]}, {cells['detector'][0]}, (n, f) = {cellset}"
            p = detector_params(config.detector, **config.detector_params)
            limits = (getattr(p, "alert_limit_h", None), getattr(p, "alert_limit_v", None))
            paths.append(viz.stanford(trials, target, title, limits))
        else:
            title = f"{labels}, seed {config.seed}"
            paths.append(viz.recovery(recovery_cases(config), target, view, title))
    return paths


@main.command()
@click.argument("results", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="print the comparison as JSON on stdout (criteria, one object per cell, pass)",
)
def check(results, as_json) -> None:
    """Compare a reference sweep with the paper's published means (docs/models.md).

    Passes when every recovered mean is within 3 standard errors of the published one and
    every baseline within 0.3 m; exits 1 otherwise.
    """
    from swarmraft.experiments.published import (
        MAX_BASELINE_GAP,
        MAX_Z,
        PUBLISHED,
        compare_published,
        not_the_papers,
    )
    from swarmraft.experiments.sweep import load_results

    cells, _, run = load_results(Path(results))
    preset = run["config"].get("preset")
    if preset != "reference":
        raise ValueError(
            f"{results}: the published numbers are for --preset reference, this folder is {preset!r}"
        )
    if differ := not_the_papers(run["config"]):
        raise ValueError(f"{results}: not the paper's experiment: {'; '.join(differ)}")
    rows = compare_published(cells)
    if not rows:
        raise ValueError(f"{results}: no cell with n = 2f+1 for f = 1..8 to compare")
    bad = [r for r in rows if not r["ok"]]
    if as_json:
        report = {
            "results": str(results),
            "criteria": {"max_abs_z": MAX_Z, "max_baseline_gap_m": MAX_BASELINE_GAP},
            "cells": rows,
            "pass": not bad,
        }
        click.echo(json.dumps(json_safe(report), indent=2))
        sys.exit(1 if bad else 0)
    title = f"{results} against the published means"
    print_table(check_table(rows, title, check_legend(MAX_Z, MAX_BASELINE_GAP)))
    console.print(
        f"criteria: |z| <= {MAX_Z}, baseline within {MAX_BASELINE_GAP} m: "
        + ("all cells pass" if not bad else f"{len(bad)} cell(s) fail")
        + (
            f" ({len(rows)} of the paper's {len(PUBLISHED)} published cells in this folder)"
            if len(rows) < len(PUBLISHED)
            else ""
        )
    )
    sys.exit(1 if bad else 0)


def json_safe(value: object) -> object:
    """``value`` with numpy scalars as Python numbers and nan or inf as null (valid JSON)."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def report_compare(table: dict, out: Path, title: str, to=None) -> list[Path]:
    """Print a comparison table (on ``to``, default the console) and draw one figure per
    metric into ``out/figures``; returns what was written (compare.csv, written by
    run_compare, included)."""
    from swarmraft import viz
    from swarmraft.experiments.compare import COMPARE_METRICS, compare_figure_names

    print_table(compare_table(table, title), to)
    written = [Path(out) / "compare.csv"]
    # each (attack, detector)'s own sweep folder, OUT/<attack>/<detector>, of those tabled
    for pair in dict.fromkeys(zip(table["attack"], table["detector"], strict=True)):
        cells = Path(out, *map(str, pair), "cells.csv")
        files = (cells, cells.with_name("trials.csv"), cells.with_name("run.json"))
        written += [p for p in files if p.exists()]
    drawn = compare_figure_names(table)
    for name in drawn:
        metric = name.removesuffix(".png")
        label, log, ref = COMPARE_METRICS[metric]
        written.append(viz.compare(table, metric, label, log, Path(out) / "figures" / name, ref))
    for metric in COMPARE_METRICS:  # a metric without a value this time: its old figure goes
        if f"{metric}.png" not in drawn:
            (Path(out) / "figures" / f"{metric}.png").unlink(missing_ok=True)
    (Path(out) / "report.html").unlink(missing_ok=True)  # drawn from the comparison before
    return written


def _every_detector(exc: Exception) -> str:
    """A parameter error's text for `compare`, which gives every detector the parameters: the
    registry's hint is for choosing one detector."""
    return str(exc).replace(": choose one of them as the detector)", ": compare only detectors that take it)")


@main.command("compare")
@click.option("--preset", type=PRESET, default="realistic", show_default=True)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="TOML file with sweep settings (flags typed here override it; the defaults of --n, "
    "--trials, --attacks and --preset apply only where it sets nothing, its [attack] name "
    "the attack compared).",
)
@click.option(
    "--detectors",
    default="paper,clique,fde,joint",
    show_default=True,
    help="comma-separated registered detectors",
)
@click.option(
    "--attacks",
    default="jump",
    show_default=True,
    help=f"comma-separated attacks: {', '.join(ATTACK_NAMES)}, or registered ones",
)
@click.option("--n", "n_text", default="9,13,17", show_default=True, help="swarm sizes")
@click.option("--f", "f_text", help="attacker counts (default: every f <= (n-1)/2)")
@click.option("--diagonal", is_flag=True, help="only the cells n = 2f+1")
@PARAMS
@click.option("--trials", type=click.IntRange(min=1), default=1000, show_default=True, help="trials per cell")
@click.option("--seed", type=click.IntRange(min=0), help="master seed [default 2025]")
@WORKERS
@SCHEDULER
@click.option(
    "--out",
    type=OutFolder(),
    help="results folder [default results/compare-<preset>]",
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="print the comparison as JSON on stdout, one object per row of compare.csv "
    "(the lines saying what was written go to stderr)",
)
def compare_cmd(
    preset,
    config_file,
    detectors,
    attacks,
    n_text,
    f_text,
    diagonal,
    params,
    trials,
    seed,
    workers,
    scheduler,
    out,
    as_json,
) -> None:
    """Run several detectors on identical trials and compare them.

    Writes compare.csv (one row per attack, detector and (n, f)), each sweep's folder under
    OUT/<attack>/<detector>, and one figure per metric in OUT/figures: error of attacked and
    honest drones, efficiency against the Cramér-Rao bound, detection, false-positive and
    identification rates. A --param is given to every detector compared (each must take it).
    """
    from swarmraft.estimation import detector_names, detector_params
    from swarmraft.experiments.compare import check_detectors, check_out, listed, run_compare
    from swarmraft.experiments.config import ConfigError

    dets = name_list(detectors, "--detectors", list(detector_names()), "detector")
    from swarmraft.experiments.config import attack_names

    for det in dets:  # every detector compared takes every --param
        try:
            detector_params(det, **key_values(params))
        except ValueError as exc:
            raise click.BadParameter(_every_detector(exc), param_hint="--param") from None
    given = {"detector": dets[0], "detector_params": key_values(params)} if params else {}
    config = sweep_config(preset, config_file, n_text, f_text, diagonal, trials, seed, given)
    if config_file is not None and not typed("attacks"):
        attacks = config.attack.name  # the file's, or the preset's (jump, compare's default too)
    atks = name_list(attacks, "--attacks", attack_names(), "attack")
    try:
        check_detectors(config, dets)
    except ConfigError as exc:  # what is left is the file's (a detector_params one lacks)
        if config_file is None:
            raise
        raise ConfigError(f"--config {config_file}: {_every_detector(exc)}") from None
    out = out or Path("results") / f"compare-{config.preset}"
    check_out(out)
    before = listed(out)
    say = err_console if as_json else console
    note_sizes_without_cells(config)
    say.print(
        f"compare: {', '.join(dets)} on {', '.join(atks)}, preset {config.preset}, "
        f"{len(config.cells())} cells x {config.trials} trials -> {out}",
        soft_wrap=True,
    )
    prog, start = progress_bar("compare")
    with prog:
        table, _ = run_compare(config, dets, atks, out, workers=workers, scheduler=scheduler, progress=start)
    written = report_compare(table, out, "detectors on identical trials", to=err_console if as_json else None)
    if as_json:
        rows = [{k: table[k][i] for k in table} for i in range(len(table["n"]))]
        click.echo(json.dumps(json_safe(rows), indent=2))
    for path in written:
        say.print(f"wrote {path}", soft_wrap=True)
    if dropped := [s for s in before if s not in listed(out)]:
        say.print(
            f"note: compare.csv lists this run's sweeps only; it listed {', '.join(dropped)} too, whose "
            "folders are kept (run compare with them again to table them)",
            soft_wrap=True,
        )


@main.command()
@click.option(
    "--preset",
    type=PRESET,
    default="realistic",
    show_default=True,
)
@click.option("--n", "n_text", default="17", show_default=True, help="swarm sizes (3 or more)")
@click.option(
    "--trials", type=click.IntRange(min=10), default=2000, show_default=True, help="honest snapshots"
)
@click.option("--seed", type=click.IntRange(min=0), default=2025, show_default=True)
def calibrate(preset, n_text, trials, seed) -> None:
    """Calibrate tau and epsilon (mu_e + 3 sigma_e of honest residuals, paper III.E)."""
    from swarmraft.experiments import build_config
    from swarmraft.experiments.calibration import calibrate_cell

    ns = swarm_sizes(n_text)
    config = build_config(preset, n=ns, seed=seed, calibration_trials=trials)
    if not config.calibrate:  # the table's zeros are right, and not what its sweeps use: said first
        from swarmraft.estimation import detector_params

        p = detector_params(config.detector, **config.detector_params)
        console.print(
            f"preset {preset} does not calibrate (calibrate = false): its sweeps use the "
            f"{config.detector} detector's tau {p.tau:g} m and epsilon {p.epsilon:g} m; what "
            "its honest snapshots would give:",
            soft_wrap=True,
        )
    rows = [(n, calibrate_cell(config, n)) for n in ns]
    print_table(calibration_table(rows, f"calibration, preset {preset}, {trials} honest snapshots"))


@main.command()
@click.option("--preset", type=PRESET, default="realistic", show_default=True)
@click.option(
    "--detectors",
    default="paper,clique,fde,joint",
    show_default=True,
    help="detectors with a threshold to move (paper, clique, fde, joint; not shape)",
)
@click.option("--n", "n", type=click.IntRange(min=4), default=13, show_default=True, help="swarm size")
@click.option("--f", "f", type=click.IntRange(min=1), default=3, show_default=True, help="attackers")
@click.option(
    "--trials", type=click.IntRange(min=10), default=200, show_default=True, help="trials per point"
)
@click.option(
    "--false-alarm",
    type=click.FloatRange(0, 1),
    default=0.01,
    show_default=True,
    help="false-alarm rate for the detection-against-offset curve",
)
@click.option("--offsets", default="1,2,4,6,8,10,15,20,30,50", show_default=True, help="spoof offsets, m")
@click.option(
    "--roc-offset",
    type=click.FloatRange(min=0),
    default=10.0,
    show_default=True,
    help="spoof offset of the ROC trials, m",
)
@click.option(
    "--attack",
    type=click.Choice(["jump", "enlarge"]),
    default="jump",
    show_default=True,
    help="jump: the offset is a GNSS spoof's; enlarge: each attacker's distance enlargement, m",
)
@click.option("--seed", type=click.IntRange(min=0), default=2025, show_default=True)
@click.option("--out", type=OutFolder(), default="results/curves", show_default=True)
def curves(preset, detectors, n, f, trials, false_alarm, offsets, roc_offset, attack, seed, out) -> None:
    """Detection curves per detector: ROC (detection against false-alarm rate as the
    threshold moves) and detection probability against spoof offset (or, with --attack
    enlarge, distance enlargement) at a fixed false-alarm rate. Writes curves.csv, roc.png
    and detection_vs_offset.png."""
    from swarmraft import viz
    from swarmraft.experiments import build_config
    from swarmraft.experiments.curves import CURVE_COLUMNS, THRESHOLDS, detection_curves
    from swarmraft.experiments.tables import write_rows

    if f > (n - 1) // 2:
        raise ValueError(f"--f: {f} attackers need n >= {2 * f + 1}")
    from swarmraft.estimation import detector_names

    dets = name_list(detectors, "--detectors", list(detector_names()), "detector")
    if no_threshold := [d for d in dets if d not in THRESHOLDS]:  # before the progress bar
        raise click.BadParameter(
            f"no threshold parameter known for {', '.join(no_threshold)}; curves draws "
            f"{', '.join(THRESHOLDS)}",
            param_hint="--detectors",
        )
    try:
        offs = [float(v) for v in offsets.split(",")]
    except ValueError:
        raise click.BadParameter(
            f"expected numbers like 1,2,5, got {offsets!r}", param_hint="--offsets"
        ) from None
    if not all(math.isfinite(v) and v >= 0 for v in offs):  # checked before any work, not by the attack
        raise click.BadParameter(
            f"offsets are distances, finite and >= 0 m: got {offsets!r}", param_hint="--offsets"
        )
    if twice := repeated(offs):
        raise click.BadParameter(f"{', '.join(f'{v:g}' for v in twice)} m twice", param_hint="--offsets")
    from swarmraft.experiments.results_folder import require_own

    require_own(out, "curves", "curves")
    config = build_config(preset, n=(n,), f=(f,), trials=trials, seed=seed)
    total = sum(len(THRESHOLDS[d][1]) + len(offs) for d in dets if d in THRESHOLDS)
    prog, start = progress_bar("curves", "points")
    with prog:
        points = detection_curves(
            config, dets, n, f, trials, offs, false_alarm, roc_offset, start(total, 0), attack
        )
    write_rows(out / "curves.csv", CURVE_COLUMNS, [p.__dict__ for p in points])
    for line in curve_lines(points, false_alarm):
        print_wrapped(line)
    title = f"preset {preset}, {attack}, n = {n}, f = {f}, {trials} trials per point"
    console.print(f"wrote {out / 'curves.csv'}", soft_wrap=True)
    console.print(f"wrote {viz.roc(points, out / 'roc.png', title)}", soft_wrap=True)
    console.print(
        f"wrote {viz.detection_vs_offset(points, out / 'detection_vs_offset.png', false_alarm, title)}",
        soft_wrap=True,
    )


def curve_lines(points: list, false_alarm: float) -> list[str]:
    """One line per detector: the threshold the offset curve uses (the best detection with
    false alarms at most ``false_alarm`` in the ROC's trials), the false alarms measured at it
    in the offset trials, and the smallest offsets at which half and 90 % of the attacked
    drones are flagged."""
    out = []
    for det in dict.fromkeys(p.detector for p in points):
        pts = sorted((p for p in points if p.detector == det and p.kind == "offset"), key=lambda p: p.offset)
        if not pts:
            continue

        def first(share: float, what: str, pts: list = pts) -> str:
            hit = next((p.offset for p in pts if p.detection >= share), None)
            if hit is None:
                return f"{what} flagged at no offset up to {pts[-1].offset:g} m"
            return f"{what} flagged from {hit:g} m"

        fa = float(np.mean([p.false_alarm for p in pts]))
        out.append(
            f"{det}: {pts[0].parameter} = {pts[0].threshold:.4g} (false alarms <= {false_alarm:.1%} in the "
            f"ROC's trials; {fa:.1%} in the offset trials); {first(0.5, 'half the attacked drones')}, "
            f"{first(0.9, '90 %')} (of the offsets tried)"
        )
    return out


@main.command()
def detectors() -> None:
    """List the registered detectors and their parameters."""
    from rich.markup import escape

    from swarmraft.estimation import detector_names, get_detector

    for name in detector_names():
        det = get_detector(name)
        print_wrapped(f"[bold]{name}[/]: {escape(det.summary)}")
        for field, info in det.params.model_fields.items():
            print_wrapped(escape(f"{field} = {info.default!r}  {info.description or ''}"), 4)
