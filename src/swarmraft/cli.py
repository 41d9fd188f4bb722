"""The ``swarmraft`` command. Every subcommand prints where its outputs went; bad input is a
one-line error naming the problem (exit status 2)."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click
import numpy as np
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

# Wide tables even when the output is a pipe or a log file (rich would assume 80 columns).
_WIDTH = None if sys.stdout.isatty() else 130
console = Console(highlight=False, width=_WIDTH)
err_console = Console(stderr=True, highlight=False, width=_WIDTH)


def _fail(message: str) -> None:
    err_console.print(f"[bold red]error:[/] {message}", soft_wrap=True, markup=True)
    sys.exit(2)


class _Group(click.Group):
    """Turns expected errors, and click's usage errors, into one line on stderr."""

    def main(self, *args: Any, **kwargs: Any) -> Any:
        try:
            return super().main(*args, standalone_mode=False, **kwargs)
        except click.UsageError as exc:
            hint = f" (see `{exc.ctx.command_path} --help`)" if exc.ctx else ""
            _fail(" ".join(f"{exc.format_message()}{hint}".split()))
        except click.exceptions.Abort:
            _fail("aborted")
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except (ValueError, RuntimeError, FileNotFoundError, KeyError) as exc:
            if isinstance(exc, click.ClickException | click.exceptions.Exit):
                raise
            text = str(exc).strip()
            _fail(text.splitlines()[0] if text else type(exc).__name__)


def _int_list(text: str | None, name: str) -> tuple[int, ...] | None:
    """'3,5,7' or '3-17' or '3-17:2' -> ints."""
    if text is None:
        return None
    out: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part:
                rng, _, step = part.partition(":")
                lo, hi = (int(v) for v in rng.split("-"))
                out += list(range(lo, hi + 1, int(step) if step else 1))
            elif part:
                out.append(int(part))
    except ValueError:
        raise click.BadParameter(
            f"expected integers like 3,5,7 or 3-17:2, got {text!r}", param_hint=name
        ) from None
    if not out:
        raise click.BadParameter("no values given", param_hint=name)
    return tuple(out)


def _params(items: tuple[str, ...]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise click.BadParameter(f"expected KEY=VALUE, got {item!r}", param_hint="--param")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def progress_bar(
    label: str, unit: str = "trials"
) -> tuple[Progress, Callable[[int, int], Callable[[int], None]]]:
    """A progress bar, and the ``progress(total, cells)`` callback factory sweeps take."""
    prog = Progress(
        TextColumn(f"[bold]{label}[/]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn(unit),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=err_console,
        transient=False,
    )

    def start(total: int, cells: int) -> Callable[[int], None]:
        task = prog.add_task(label, total=total)
        return lambda k: prog.advance(task, k)

    return prog, start


def _summary_table(cells: dict, title: str) -> Table:
    t = Table(title=title, title_justify="left")
    for col in (
        "n",
        "f",
        "trials",
        "baseline m",
        "recovered mean m",
        "+/- sem",
        "median m",
        "p99 m",
        ">1 m",
        "honest m",
        "detect",
        "false pos",
    ):
        t.add_column(col, justify="right")
    for i in range(len(cells["n"])):
        t.add_row(
            str(cells["n"][i]),
            str(cells["f"][i]),
            str(cells["trials"][i]),
            f"{cells['baseline_mean'][i]:.2f}",
            f"{cells['recovered_mean'][i]:.3g}",
            f"{cells['recovered_sem'][i]:.2g}",
            f"{cells['recovered_median'][i]:.2g}",
            f"{cells['recovered_p99'][i]:.3g}",
            f"{cells['frac_over_1m'][i]:.1%}",
            f"{cells['honest_mean'][i]:.3g}",
            f"{cells['detection_rate'][i]:.1%}",
            f"{cells['false_positive_rate'][i]:.1%}",
        )
    return t


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="swarmraft")
def main() -> None:
    """SwarmRaft: verify drone-swarm positions against inter-drone ranges.

    Run `swarmraft COMMAND --help` for each command's options.
    """


def _sweep_config(preset, config_file, n_text, f_text, diagonal, trials, seed, extra: dict[str, Any]):
    """A validated SweepConfig from a preset, an optional TOML file and command-line flags
    (flags override the file, the file overrides the preset)."""
    from swarmraft.experiments import build_config
    from swarmraft.experiments.config import read_toml

    settings: dict[str, Any] = {}
    if config_file is not None:
        settings = read_toml(config_file, "--config")
        preset = settings.pop("preset", preset)
    overrides = {
        "n": _int_list(n_text, "--n"),
        "f": _int_list(f_text, "--f"),
        "diagonal": diagonal or None,
        "trials": trials,
        "seed": seed,
        **extra,
    }
    return build_config(preset, **{**settings, **{k: v for k, v in overrides.items() if v is not None}})


PRESET = click.Choice(["reference", "realistic"])
ATTACK_NAMES = ["jump", "range-tamper", "range-bias", "collusion-1", "collusion-2", "collusion-3", "area"]
WORKERS = click.option("--workers", type=int, help="local worker processes [default: all cores]")
SCHEDULER = click.option("--scheduler", help="Dask scheduler tcp://HOST:PORT, or 'local' for a LocalCluster.")


@main.command()
@click.option(
    "--preset",
    type=PRESET,
    default="reference",
    show_default=True,
    help="reference: the paper's code; realistic: FACTS.md noise.",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="TOML file with sweep settings (flags given here override it).",
)
@click.option("--n", "n_text", help="swarm sizes: 3,5,7 or 3-17 or 3-17:2 [default 3-17:2]")
@click.option("--f", "f_text", help="attacker counts (default: every f <= (n-1)/2)")
@click.option("--diagonal", is_flag=True, help="only the cells n = 2f+1 (as the paper).")
@click.option("--trials", type=int, help="trials per cell [default 10000]")
@click.option("--seed", type=int, help="master seed [default 2025]")
@click.option("--detector", help="registered detector name [default paper]")
@click.option(
    "--param",
    "params",
    multiple=True,
    metavar="KEY=VALUE",
    help="detector parameter, repeatable (e.g. --param tau=0.3).",
)
@click.option(
    "--attack",
    type=click.Choice(ATTACK_NAMES),
    help="attack [default jump]",
)
@WORKERS
@SCHEDULER
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
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
    workers,
    scheduler,
    out,
) -> None:
    """Monte Carlo sweep over swarm size n and attacker count f.

    Writes cells.csv (one row per (n, f)), trials.csv (one row per trial) and run.json
    (config, seed, version). Cells already in --out are not recomputed.
    """
    from swarmraft.experiments import run_sweep

    config = _sweep_config(
        preset,
        config_file,
        n_text,
        f_text,
        diagonal,
        trials,
        seed,
        {
            "detector": detector,
            "detector_params": _params(params) or None,
            "attack": {"name": attack} if attack else None,
        },
    )
    out = out or Path("results") / config.preset
    cells = config.cells()
    console.print(
        f"sweep: preset {config.preset}, detector {config.detector}, attack "
        f"{config.attack.name}, {len(cells)} cells x {config.trials} trials, "
        f"seed {config.seed} -> {out}"
    )
    prog, start = progress_bar("sweep")
    with prog:
        result = run_sweep(config, out, workers=workers, scheduler=scheduler, progress=start)
    if result.reused:
        console.print(f"reused {len(result.reused)} finished cells from {out}")
    console.print(_summary_table(result.cells, f"{config.preset}: mean error of attacked drones"))
    if line := _calibration_line(out):
        console.print(line)
    console.print(f"done in {result.seconds:.1f} s on {result.executor}")
    for p in result.paths:
        console.print(f"  wrote {p}")


def _calibration_line(out: Path) -> str | None:
    """The calibrated thresholds of a results folder, in one line (None if none ran)."""
    cal = json.loads((Path(out) / "run.json").read_text()).get("calibration", {})
    if not cal:
        return None
    taus = [c["tau"] for c in cal.values()]
    eps = [c["epsilon"] for c in cal.values()]
    return (
        f"thresholds calibrated from honest runs (paper III.E, mu + 3 sigma) for n = "
        f"{', '.join(sorted(cal, key=int))}: tau {min(taus):.2f}-{max(taus):.2f} m, "
        f"epsilon {min(eps):.2f}-{max(eps):.2f} m"
    )


def _load_results(results: Path) -> tuple[dict, dict, dict]:
    from swarmraft.experiments.tables import read_table

    if not (results / "cells.csv").exists():
        raise FileNotFoundError(f"{results}: no cells.csv here; run `swarmraft sweep --out {results}` first")
    run = json.loads((results / "run.json").read_text())
    trials = read_table(results / "trials.csv") if (results / "trials.csv").exists() else {}
    return read_table(results / "cells.csv"), trials, run


@main.command()
@click.argument("kind", type=click.Choice(["scaling", "distribution", "recovery", "all"]))
@click.argument("results", type=click.Path(file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), help="image file (default RESULTS/figures/KIND.png)")
@click.option(
    "--view",
    type=click.Choice(["projections", "3d"]),
    default="projections",
    show_default=True,
    help="recovery picture: XY and XZ projections, or 3-D.",
)
def figure(kind, results, out, view) -> None:
    """Draw a figure from a results folder written by `swarmraft sweep`.

    scaling: mean error against n (log axis); distribution: box plots of per-trial errors;
    recovery: the paper's picture for (n, f) = (6, 2), (11, 5), (16, 7) drawn with the
    folder's config and seed; all: the three.
    """
    for path in draw_figures(kind, results, out, view):
        console.print(f"wrote {path}")


def draw_figures(kind: str, results: Path, out: Path | None = None, view: str = "projections") -> list[Path]:
    from swarmraft import viz
    from swarmraft.experiments import SweepConfig
    from swarmraft.experiments.cases import recovery_cases

    cells, trials, run = _load_results(Path(results))
    kinds = ["scaling", "distribution", "recovery"] if kind == "all" else [kind]
    paths = []
    for k in kinds:
        target = out if (out and kind != "all") else Path(results) / "figures" / f"{k}.png"
        if k == "scaling":
            paths.append(viz.scaling(cells, target))
        elif k == "distribution":
            title = f"preset {cells['preset'][0]}, detector {cells['detector'][0]}"
            paths.append(viz.distribution(trials, target, title))
        else:
            config = SweepConfig(**run["config"])
            paths.append(viz.recovery(recovery_cases(config), target, view))
    return paths


@main.command()
@click.argument("results", type=click.Path(file_okay=False, path_type=Path))
def check(results) -> None:
    """Compare a reference sweep with the paper's published means (FACTS.md).

    Passes when every recovered mean is within 3 standard errors of the published one and
    every baseline within 0.3 m; exits 1 otherwise.
    """
    from swarmraft.experiments.published import MAX_BASELINE_GAP, MAX_Z, compare_published

    cells, _, run = _load_results(Path(results))
    if run["config"]["preset"] != "reference":
        raise ValueError(
            f"{results}: the published numbers are for --preset reference, "
            f"this folder is {run['config']['preset']!r}"
        )
    rows = compare_published(cells)
    if not rows:
        raise ValueError(f"{results}: no cell with n = 2f+1 for f = 1..8 to compare")
    t = Table(title=f"{results} against the published means", title_justify="left")
    for col in (
        "n (f)",
        "trials",
        "recovered m",
        "sem",
        "published m",
        "z",
        "baseline m",
        "published",
        "ok",
    ):
        t.add_column(col, justify="right")
    for r in rows:
        t.add_row(
            f"{r['n']} ({r['f']})",
            str(r["trials"]),
            f"{r['recovered']:.3f}",
            f"{r['sem']:.3f}",
            f"{r['published']:.3f}",
            f"{r['z']:+.2f}",
            f"{r['baseline']:.2f}",
            f"{r['published_baseline']:.1f}",
            "yes" if r["ok"] else "[red]NO[/]",
        )
    console.print(t)
    bad = [r for r in rows if not r["ok"]]
    console.print(
        f"criteria: |z| <= {MAX_Z}, baseline within {MAX_BASELINE_GAP} m: "
        + ("all cells pass" if not bad else f"{len(bad)} cell(s) fail")
    )
    sys.exit(1 if bad else 0)


@main.command("compare")
@click.option("--preset", type=PRESET, default="realistic", show_default=True)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="TOML file with sweep settings (flags given here override it).",
)
@click.option(
    "--detectors",
    default="paper,clique,fde,joint",
    show_default=True,
    help="comma-separated registered detectors",
)
@click.option(
    "--attacks", default="jump", show_default=True, help=f"comma-separated attacks: {', '.join(ATTACK_NAMES)}"
)
@click.option("--n", "n_text", default="9,13,17", show_default=True, help="swarm sizes")
@click.option("--f", "f_text", help="attacker counts (default: every f <= (n-1)/2)")
@click.option("--diagonal", is_flag=True, help="only the cells n = 2f+1")
@click.option("--trials", type=int, default=1000, show_default=True, help="trials per cell")
@click.option("--seed", type=int, help="master seed [default 2025]")
@WORKERS
@SCHEDULER
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    help="results folder [default results/compare-<preset>]",
)
def compare_cmd(
    preset, config_file, detectors, attacks, n_text, f_text, diagonal, trials, seed, workers, scheduler, out
) -> None:
    """Run several detectors on identical trials and compare them.

    Writes compare.csv (one row per attack, detector and (n, f)), each sweep's folder under
    OUT/<attack>/<detector>, and one figure per metric in OUT/figures: error of attacked and
    honest drones, efficiency against the Cramér-Rao bound, detection, false-positive and
    identification rates.
    """
    from swarmraft import viz
    from swarmraft.experiments.compare import COMPARE_METRICS, run_compare

    dets = [d.strip() for d in detectors.split(",") if d.strip()]
    atks = [a.strip() for a in attacks.split(",") if a.strip()]
    for a in atks:
        if a not in ATTACK_NAMES:
            raise ValueError(f"--attacks: unknown attack {a!r}; known: {', '.join(ATTACK_NAMES)}")
    config = _sweep_config(preset, config_file, n_text, f_text, diagonal, trials, seed, {})
    out = out or Path("results") / f"compare-{config.preset}"
    console.print(
        f"compare: {', '.join(dets)} on {', '.join(atks)}, preset {config.preset}, "
        f"{len(config.cells())} cells x {config.trials} trials -> {out}"
    )
    prog, start = progress_bar("compare")
    with prog:
        table, _ = run_compare(config, dets, atks, out, workers=workers, scheduler=scheduler, progress=start)
    t = Table(title="detectors on identical trials", title_justify="left")
    for col in (
        "attack",
        "detector",
        "n",
        "f",
        "attacked m",
        "honest m",
        "efficiency",
        "detect",
        "false pos",
        "identified",
        "unidentifiable",
    ):
        t.add_column(col, justify="right")
    for i in range(len(table["n"])):
        eff = table["attacked_efficiency"][i]
        t.add_row(
            str(table["attack"][i]),
            str(table["detector"][i]),
            str(table["n"][i]),
            str(table["f"][i]),
            f"{table['recovered_mean'][i]:.3g}",
            f"{table['honest_mean'][i]:.3g}",
            "-" if np.isnan(eff) else f"{eff:.2f}",
            f"{table['detection_rate'][i]:.1%}",
            f"{table['false_positive_rate'][i]:.1%}",
            f"{table['identification_rate'][i]:.1%}",
            f"{table['status_unidentifiable'][i]:.1%}",
        )
    console.print(t)
    console.print(f"wrote {out / 'compare.csv'}")
    for metric, (label, log) in COMPARE_METRICS.items():
        if np.isnan(np.asarray(table[metric], float)).all():
            continue
        console.print(f"wrote {viz.compare(table, metric, label, log, out / 'figures' / f'{metric}.png')}")


@main.command()
@click.option(
    "--preset",
    type=PRESET,
    default="realistic",
    show_default=True,
)
@click.option("--n", "n_text", default="17", show_default=True, help="swarm sizes")
@click.option("--trials", type=int, default=2000, show_default=True)
@click.option("--seed", type=int, default=2025, show_default=True)
def calibrate(preset, n_text, trials, seed) -> None:
    """Calibrate tau and epsilon (mu_e + 3 sigma_e of honest residuals, paper III.E)."""
    from swarmraft.experiments import build_config
    from swarmraft.experiments.calibration import calibrate_cell

    config = build_config(preset, seed=seed, calibration_trials=trials)
    t = Table(title=f"calibration, preset {preset}, {trials} honest snapshots", title_justify="left")
    for col in (
        "n",
        "tau m",
        "pair mu",
        "pair sigma",
        "epsilon m",
        "recovery mu",
        "recovery sigma",
    ):
        t.add_column(col, justify="right")
    for n in _int_list(n_text, "--n") or ():
        c = calibrate_cell(config, n)
        t.add_row(
            str(n),
            f"{c.tau:.3f}",
            f"{c.pair_mean:.3f}",
            f"{c.pair_std:.3f}",
            f"{c.epsilon:.3f}",
            f"{c.recovery_mean:.3f}",
            f"{c.recovery_std:.3f}",
        )
    console.print(t)


@main.command()
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("results/demo"),
    show_default=True,
    help="folder for everything the demo writes",
)
@click.option("--trials", type=int, default=2000, show_default=True, help="trials per cell")
@WORKERS
@click.option(
    "--scenario",
    "scenario_file",
    type=click.Path(dir_okay=False, path_type=Path),
    default=Path("scenarios/demo.toml"),
    show_default=True,
    help="the demo mission",
)
def demo(out, trials, workers, scenario_file) -> None:
    """The demo job. First a 60 s mission of 9 drones in the simulator (spoofing, a GNSS
    outage and a leader crash; scenarios/demo.toml), its summary and figures; then a reference
    sweep (the paper's experiment with fewer trials) compared with the published numbers, a
    realistic sweep, and the four detectors compared on identical realistic trials."""
    from swarmraft.experiments import build_config, run_sweep
    from swarmraft.experiments.mission import load_scenario, run_and_write
    from swarmraft.experiments.published import compare_published

    written: list[Path] = []
    sc = load_scenario(scenario_file)
    folder = out / "mission"
    console.rule(f"[bold]mission[/] {sc.name}: {sc.drones} drones, {sc.duration_s:g} s -> {folder}")
    prog, start = progress_bar("mission", "steps")
    with prog:
        result = run_and_write(sc, folder, start(sc.steps + 1, 0))
    print_mission_summary(result.summary)
    written += [folder / "steps.csv", folder / "summary.json", *mission_figures(result, folder)]
    for preset, n_trials in (("reference", trials), ("realistic", max(1, trials // 2))):
        config = build_config(preset, diagonal=True, trials=n_trials)
        folder = out / preset
        console.rule(f"[bold]{preset} preset[/]: n = 2f+1, {n_trials} trials per cell -> {folder}")
        prog, start = progress_bar(preset)
        with prog:
            result = run_sweep(config, folder, workers=workers, progress=start)
        console.print(_summary_table(result.cells, f"{preset}: mean error of attacked drones"))
        if preset == "reference":
            rows = compare_published(result.cells)
            worst = max(abs(r["z"]) for r in rows)
            console.print(
                f"against the paper's published means: largest |z| = {worst:.2f} "
                f"({sum(r['ok'] for r in rows)}/{len(rows)} cells within 3 standard errors); "
                f"`swarmraft check {folder}` prints the table"
            )
        if line := _calibration_line(folder):
            console.print(line)
        written += result.paths + draw_figures("all", folder)
        console.print(f"{preset} done in {result.seconds:.1f} s on {result.executor}")
    from swarmraft import viz
    from swarmraft.experiments.compare import COMPARE_METRICS, run_compare

    folder = out / "compare"
    n_trials = max(1, trials // 8)
    console.rule(
        f"[bold]detectors compared[/]: realistic, n = 17, f = 8, {n_trials} identical trials -> {folder}"
    )
    config = build_config("realistic", n=(17,), f=(8,), trials=n_trials)
    prog, start = progress_bar("compare")
    with prog:
        table, _ = run_compare(
            config, ["paper", "clique", "fde", "joint"], ["jump"], folder, workers=workers, progress=start
        )
    t = Table(title="mean error (m) and efficiency against the Cramér-Rao bound", title_justify="left")
    for col in ("detector", "attacked m", "honest m", "raw GNSS m", "efficiency", "detected", "false pos"):
        t.add_column(col, justify="right")
    for i in range(len(table["n"])):
        t.add_row(
            str(table["detector"][i]),
            f"{table['recovered_mean'][i]:.2f}",
            f"{table['honest_mean'][i]:.2f}",
            f"{table['honest_baseline_mean'][i]:.2f}",
            f"{table['attacked_efficiency'][i]:.2f}",
            f"{table['detection_rate'][i]:.1%}",
            f"{table['false_positive_rate'][i]:.1%}",
        )
    console.print(t)
    written.append(folder / "compare.csv")
    for metric, (label, log) in COMPARE_METRICS.items():
        written.append(viz.compare(table, metric, label, log, folder / "figures" / f"{metric}.png"))
    console.rule("[bold]written[/]")
    for p in written:
        console.print(f"  {p}")


@main.command("raft-fuzz")
@click.option(
    "--seeds", type=click.IntRange(min=1), default=500, show_default=True, help="how many seeds to run"
)
@click.option(
    "--seed-start",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="first seed (a failing seed replays with --seed-start S --seeds 1)",
)
@click.option("--nodes", type=click.IntRange(min=1), default=5, show_default=True)
@click.option(
    "--fault-ms",
    type=click.FloatRange(min=0),
    default=3000.0,
    show_default=True,
    help="virtual time with faults per seed",
)
@click.option("--loss", type=click.FloatRange(0, 1), default=0.2, show_default=True)
def raft_fuzz(seeds, seed_start, nodes, fault_ms, loss) -> None:
    """Randomised Raft fault runs in the simulator (crashes, restarts, partitions, loss,
    duplication, reordering) with every safety invariant checked after every event.

    Exits 1 and prints each failing seed if any run breaks an invariant or fails to
    deliver a committed entry to every node once the faults stop.
    """
    from swarmraft.sim.fuzz import FuzzConfig, run_seed

    cfg = FuzzConfig(nodes=nodes, fault_ms=fault_ms, loss=loss)
    failed = []
    events = 0
    prog, start = progress_bar("raft-fuzz", "seeds")
    with prog:
        advance = start(seeds, 0)
        for s in range(seed_start, seed_start + seeds):
            r = run_seed(s, cfg)
            events += r.events
            if not r.ok:
                failed.append(r)
                prog.console.print(f"[red]FAIL[/] seed {s}: {r.error}")
            advance(1)
    console.print(
        f"{seeds} seeds ({seed_start}..{seed_start + seeds - 1}), {nodes} nodes, "
        f"{fault_ms:.0f} ms of faults each, {events} events checked: "
        + (
            "no violation"
            if not failed
            else f"{len(failed)} failing seed(s): " + ", ".join(str(r.seed) for r in failed)
        )
    )
    sys.exit(1 if failed else 0)


@main.command()
@click.option("--preset", type=PRESET, default="realistic", show_default=True)
@click.option("--detectors", default="paper,clique,fde,joint", show_default=True)
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
@click.option("--seed", type=int, default=2025, show_default=True)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("results/curves"),
    show_default=True,
)
def curves(preset, detectors, n, f, trials, false_alarm, offsets, roc_offset, seed, out) -> None:
    """Detection curves per detector: ROC (detection against false-alarm rate as the
    threshold moves) and detection probability against spoof offset at a fixed false-alarm
    rate. Writes curves.csv, roc.png and detection_vs_offset.png."""
    from swarmraft import viz
    from swarmraft.experiments import build_config
    from swarmraft.experiments.curves import THRESHOLDS, detection_curves
    from swarmraft.experiments.tables import write_rows

    if f > (n - 1) // 2:
        raise ValueError(f"--f: {f} attackers need n >= {2 * f + 1}")
    dets = [d.strip() for d in detectors.split(",") if d.strip()]
    try:
        offs = [float(v) for v in offsets.split(",")]
    except ValueError:
        raise click.BadParameter(
            f"expected numbers like 1,2,5, got {offsets!r}", param_hint="--offsets"
        ) from None
    config = build_config(preset, n=(n,), f=(f,), trials=trials, seed=seed)
    total = sum(len(THRESHOLDS[d][1]) + len(offs) for d in dets if d in THRESHOLDS)
    prog, start = progress_bar("curves", "points")
    with prog:
        points = detection_curves(config, dets, n, f, trials, offs, false_alarm, roc_offset, start(total, 0))
    cols = ("detector", "kind", "threshold", "offset", "false_alarm", "detection")
    write_rows(out / "curves.csv", cols, [p.__dict__ for p in points])
    title = f"preset {preset}, n = {n}, f = {f}, {trials} trials per point"
    console.print(f"wrote {out / 'curves.csv'}")
    console.print(f"wrote {viz.roc(points, out / 'roc.png', title)}")
    console.print(
        f"wrote {viz.detection_vs_offset(points, out / 'detection_vs_offset.png', false_alarm, title)}"
    )


def mission_figures(result, out: Path) -> list[Path]:
    """The four mission figures for a MissionResult, into ``out/figures``."""
    from swarmraft.viz import mission as vm

    log, errors = result.log, result.errors
    sc = log.scenario
    fig_dir = Path(out) / "figures"
    steps = [min(int(round(ts / sc.dt_s)), len(log.t) - 1) for ts in sc.maps_at_s] or [
        len(log.t) // 4,
        len(log.t) // 2,
        len(log.t) - 1,
    ]
    return [
        vm.error_over_time(
            log.t, errors, log.spoofed, log.outage, log.events, fig_dir / "error_over_time.png", sc.name
        ),
        vm.swarm_maps(
            log.truth, log.reported, log.verified, log.faulty, steps, log.t, fig_dir / "swarm_maps.png"
        ),
        vm.consensus_latency(log.t, log.latency_ms, log.events, fig_dir / "consensus_latency.png"),
        vm.messages_per_step(
            log.t, log.raft_messages, log.report_messages, sc.drones, fig_dir / "messages_per_step.png"
        ),
    ]


def _m(v: float | None) -> str:
    return "n/a" if v is None else f"{v} m"


def print_mission_summary(summary: dict) -> None:
    s = summary
    console.print(
        f"[bold]{s['scenario']}[/]: {s['drones']} drones, {s['steps']} steps, detector {s['detector']}"
    )
    console.print(
        f"  committed {s['committed_steps']} steps, skipped {s['skipped_steps']} "
        f"(longest run {s['longest_skipped_run']}); records identical on all nodes: "
        f"{'yes' if s['records_identical_on_all_nodes'] else '[red]NO[/]'}"
    )
    console.print(
        f"  honest drones: raw GNSS {_m(s['honest_error_gnss_m'])}, "
        f"SwarmRaft {_m(s['honest_error_swarmraft_m'])}, "
        f"bound {_m(s['honest_bound_m'])}; false positives {s['honest_false_positive_rate']:.2%}"
    )
    for d in s["detections"]:
        if d["detected"]:
            console.print(
                f"  {d['kind']} on drone {d['drone']}: detected after {d['time_to_detect_s']} s "
                f"(its GNSS then {d['reported_error_at_detection_m']} m off); afterwards error "
                f"{_m(d['mean_error_after_m'])}, bound {_m(d['mean_bound_after_m'])}"
            )
        else:
            console.print(f"  {d['kind']} on drone {d['drone']}: [red]not detected[/]")
    console.print(f"  consensus latency median {s['latency_ms_median']} ms, p99 {s['latency_ms_p99']} ms")
    console.print(
        f"  Raft messages per committed step {s['raft_messages_per_committed_step']} "
        f"(minimum 2(n-1) = {s['raft_minimum_per_step']}), reports per step {s['reports_per_step']}"
    )
    for o in s["outages"]:
        console.print(
            f"  GNSS outage of drone {o['drone']} ({o['from_s']}-{o['to_s']} s): SwarmRaft "
            f"{_m(o['mean_error_swarmraft_m'])}, INS alone {_m(o['mean_error_ins_alone_m'])}, "
            f"bound {_m(o['mean_bound_m'])}"
        )
    for e in s["events"]:
        console.print(f"  event: {e}")


@main.command()
@click.option(
    "--scenario",
    "scenario_file",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="scenario TOML file (see scenarios/)",
)
@click.option(
    "--out", type=click.Path(file_okay=False, path_type=Path), help="output folder [results/<name>]"
)
@click.option("--seed", type=int, help="override the scenario's seed")
@click.option("--detector", help="override the scenario's detector")
def mission(scenario_file, out, seed, detector) -> None:
    """Run a mission in the simulator: drones fly, sense, report to the Raft leader, and
    apply the verified positions committed through the Raft log, with the scenario's attacks
    and faults. Writes steps.csv (one row per step and drone), summary.json, scenario.json and
    figures (error over time, swarm maps, consensus latency, messages per step)."""
    from swarmraft.experiments.mission import load_scenario, run_and_write

    sc = load_scenario(scenario_file, seed=seed)
    if detector:
        sc = sc.model_copy(update={"protocol": sc.protocol.model_copy(update={"detector": detector})})
        from swarmraft.estimation import get_detector

        get_detector(detector)
    out = out or Path("results") / sc.name
    console.print(
        f"mission {sc.name}: {sc.drones} drones, {sc.duration_s:g} s at {1 / sc.dt_s:g} Hz -> {out}"
    )
    prog, start = progress_bar("mission", "steps")
    with prog:
        result = run_and_write(sc, out, start(sc.steps + 1, 0))
    print_mission_summary(result.summary)
    for p in [out / "steps.csv", out / "summary.json", out / "scenario.json", *mission_figures(result, out)]:
        console.print(f"wrote {p}")


@main.command()
def detectors() -> None:
    """List the registered detectors and their parameters."""
    from swarmraft.estimation import detector_names, get_detector

    for name in detector_names():
        det = get_detector(name)
        console.print(f"[bold]{name}[/]: {det.summary}")
        for field, info in det.params.model_fields.items():
            console.print(f"    {field} = {info.default!r}  {info.description or ''}")


if __name__ == "__main__":
    main()
