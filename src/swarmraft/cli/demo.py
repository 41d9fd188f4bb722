"""The demo command (what `make demo` runs)."""

from __future__ import annotations

from pathlib import Path

import click

from swarmraft.cli.app import console, heading, main, print_table, print_wrapped, progress_bar
from swarmraft.cli.missions import mission_figures, print_mission_summary
from swarmraft.cli.options import WORKERS, OutFolder
from swarmraft.cli.sweeps import calibration_line, draw_figures, report_compare
from swarmraft.cli.tables import summary_table


@main.command()
@click.option(
    "--out",
    type=OutFolder(),
    default="results/demo",
    show_default=True,
    help="folder for everything the demo writes",
)
@click.option(
    "--trials",
    type=click.IntRange(min=1),
    default=2000,
    show_default=True,
    help="trials per cell of the reference sweep; the realistic sweep runs half as many, the "
    "detector comparison an eighth",
)
@WORKERS
@click.option(
    "--scenario",
    "scenario_file",
    default="demo",
    show_default=True,
    help="the demo mission: a scenario file, or the name of a shipped one",
)
def demo(out, trials, workers, scenario_file) -> None:
    """The demo job. First a 60 s mission of 9 drones in the simulator (spoofing, a GNSS
    outage and a leader crash; the shipped scenario `demo`), its summary and figures; then a reference
    sweep (the paper's experiment with fewer trials) compared with the published numbers, a
    realistic sweep, and the four detectors compared on identical realistic trials."""
    from swarmraft.experiments import build_config, run_sweep
    from swarmraft.experiments.mission import load_scenario, run_and_write
    from swarmraft.experiments.published import compare_published
    from swarmraft.experiments.sweep import check_resume

    written: list[Path] = []
    # everything the demo will run, validated before the first step
    sc = load_scenario(scenario_file)
    configs = {
        "reference": build_config("reference", diagonal=True, trials=trials),
        "realistic": build_config("realistic", diagonal=True, trials=max(1, trials // 2)),
    }
    n_compare = max(1, trials // 8)
    compare_config = build_config("realistic", n=(17,), f=(8,), trials=n_compare)
    for preset, config in configs.items():
        check_resume(out / preset, config)
    folder = out / "mission"
    heading(f"[bold]mission[/] {sc.name}: {sc.drones} drones, {sc.duration_s:g} s -> {folder}")
    prog, start = progress_bar("mission", "steps")
    with prog:
        result = run_and_write(sc, folder, start(sc.steps + 1, 0))
    print_mission_summary(result.summary)
    written += [folder / name for name in ("steps.csv", "summary.json", "scenario.json")]
    written += mission_figures(result, folder)
    for preset, config in configs.items():
        folder = out / preset
        heading(f"[bold]{preset} preset[/]: n = 2f+1, {config.trials} trials per cell -> {folder}")
        prog, start = progress_bar(preset)
        with prog:
            result = run_sweep(config, folder, workers=workers, progress=start)
        print_table(summary_table(result.cells, f"{preset}: mean error of attacked drones"))
        if preset == "reference":
            rows = compare_published(result.cells)
            worst = max(abs(r["z"]) for r in rows)
            console.print(
                f"against the paper's published means: largest |z| = {worst:.2f} "
                f"({sum(abs(r['z']) <= 3 for r in rows)}/{len(rows)} cells within 3 standard errors, "
                f"{sum(r['ok'] for r in rows)}/{len(rows)} also within 0.3 m of the published baseline); "
                f"`swarmraft check {folder}` prints the table",
                soft_wrap=True,
            )
        if line := calibration_line(folder):
            print_wrapped(line)
        written += result.paths + draw_figures("all", folder)
        console.print(f"{preset} done in {result.seconds:.1f} s on {result.executor}")
    from swarmraft.experiments.compare import run_compare

    folder = out / "compare"
    heading(
        f"[bold]detectors compared[/]: realistic, n = 17, f = 8, {n_compare} identical trials -> {folder}"
    )
    prog, start = progress_bar("compare")
    with prog:
        table, _ = run_compare(
            compare_config,
            ["paper", "clique", "fde", "joint"],
            ["jump"],
            folder,
            workers=workers,
            progress=start,
        )
    written += report_compare(table, folder, "mean error (m) and efficiency against the Cramér-Rao bound")
    heading("[bold]written[/]")
    for p in written:
        console.print(f"  {p}", soft_wrap=True)
