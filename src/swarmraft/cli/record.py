"""`swarmraft record`: a scenario's sensor readings written as a sensor log (docs/records.md),
the file `swarmraft launch --replay` and a swarm file's replay source read."""

from __future__ import annotations

from pathlib import Path

import click

from swarmraft.cli.app import console, main


@main.command("record")
@click.option(
    "--scenario", required=True, help="a shipped scenario's name or a scenario TOML file (docs/scenarios.md)"
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, writable=True, path_type=Path),
    required=True,
    help="the sensor log to write (CSV; replaced if it exists)",
)
@click.option("--seed", type=click.IntRange(min=0), default=None, help="override the scenario's seed")
@click.option(
    "--seconds",
    type=click.FloatRange(min=0),
    default=None,
    help="record only the first SECONDS of the scenario (default: all of it)",
)
def record(scenario: str, out: Path, seed: int | None, seconds: float | None) -> None:
    """Write what every drone's sensors give in a scenario, one CSV line per drone per step:
    its GNSS fix (spoofed where the scenario spoofs it, empty in an outage), its INS dead
    reckoning, its innovation and its ranges to the other drones, drawn from the scenario and
    its seed exactly as the simulator and `swarmraft node` draw them. `swarmraft launch
    --scenario SAME --replay OUT` then replays it through real drone processes.
    """
    from swarmraft.experiments.mission import load_scenario
    from swarmraft.net.sources.replay import record_world, write_sensor_log
    from swarmraft.sim.sensing import ScenarioWorld

    if out.parent != Path("") and not out.parent.is_dir():
        raise click.BadParameter(f"no folder {out.parent}", param_hint="--out")
    sc = load_scenario(scenario, seed=seed)
    log = record_world(ScenarioWorld.build(sc), seconds)
    try:
        write_sensor_log(out, log)
    except OSError as exc:
        raise click.BadParameter(f"cannot write {out}: {exc.strerror or exc}", param_hint="--out") from None
    steps = len(log.t_s) // sc.drones
    console.print(
        f"wrote {out} ({steps} steps of {sc.dt_s:g} s x {sc.drones} drones, {len(log.t_s)} lines)",
        soft_wrap=True,
    )
