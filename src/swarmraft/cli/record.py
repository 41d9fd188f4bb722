"""`swarmraft record`, two uses: a scenario's sensor readings written as a sensor log
(``--scenario X --out FILE.csv``; docs/records.md), the file `swarmraft launch --replay` and a
swarm file's replay source read; and a mission's results folder converted to a rerun
recording (``record DIR``; docs/live.md)."""

from __future__ import annotations

from pathlib import Path

import click

from swarmraft.cli.app import console, main


@main.command("record")
@click.argument("folder", metavar="[DIR]", required=False, type=click.Path(path_type=Path))
@click.option("--scenario", help="a shipped scenario's name or a scenario TOML file (docs/scenarios.md)")
@click.option(
    "--out",
    type=click.Path(dir_okay=False, writable=True, path_type=Path),
    help="with --scenario: the sensor log to write (CSV; replaced if it exists); with DIR: the "
    "recording to write (.rrd) [default: DIR/recording.rrd]",
)
@click.option("--seed", type=click.IntRange(min=0), default=None, help="override the scenario's seed")
@click.option(
    "--seconds",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="record only the first SECONDS of the scenario (default: all of it)",
)
def record(
    folder: Path | None, scenario: str | None, out: Path | None, seed: int | None, seconds: float | None
) -> None:
    """Two uses.

    `swarmraft record --scenario X --out FILE.csv` writes what every drone's sensors give in
    a scenario, one CSV line per drone per step: its GNSS fix (spoofed where the scenario
    spoofs it, empty in an outage), its INS dead reckoning, its innovation and its ranges to
    the other drones, drawn from the scenario and its seed exactly as the simulator and
    `swarmraft node` draw them. `swarmraft launch --scenario SAME --replay OUT` then replays it
    through real drone processes.

    `swarmraft record DIR` converts a mission's results folder (what `swarmraft mission` or
    `swarmraft launch` wrote) to a rerun recording, DIR/recording.rrd or --out FILE.rrd, the
    stream `--live` shows; open it with `swarmraft view FILE.rrd` (needs the live extra).
    """
    if folder is not None:
        if scenario is not None or seed is not None or seconds is not None:
            raise click.UsageError(
                "give either a mission folder DIR or --scenario (with --seed, --seconds), not both"
            )
        _record_folder(folder, out)
        return
    if scenario is None:
        raise click.UsageError(
            "give a mission folder DIR (to write a .rrd recording) or --scenario X --out FILE.csv "
            "(to write a sensor log)"
        )
    if out is None:
        raise click.BadParameter("with --scenario, give the sensor log to write", param_hint="--out")
    from swarmraft.experiments.mission import load_scenario
    from swarmraft.net.sources.replay import record_world, write_sensor_log
    from swarmraft.sim.sensing import ScenarioWorld

    if out.suffix.lower() == ".rrd":
        raise click.BadParameter(
            f"{out}: with --scenario the file written is a sensor log (CSV); a .rrd recording is made "
            "from a mission's folder: swarmraft record DIR",
            param_hint="--out",
        )
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


def _record_folder(folder: Path, out: Path | None) -> None:
    from swarmraft.experiments.mission_folder import read_mission
    from swarmraft.viz.live import record_mission, require_rerun

    require_rerun("swarmraft record DIR")
    if out is None and not folder.is_dir():  # the default --out is inside DIR: DIR is what is missing
        raise click.BadParameter(f"no folder {folder}", param_hint="DIR")
    out = out if out is not None else folder / "recording.rrd"
    if out.suffix.lower() != ".rrd":
        raise click.BadParameter(f"{out}: give a file name ending in .rrd", param_hint="--out")
    if out.parent != Path("") and not out.parent.is_dir():
        raise click.BadParameter(f"no folder {out.parent}", param_hint="--out")
    mission = read_mission(folder, "DIR")
    steps = record_mission(mission.log, mission.errors, out)
    sc = mission.log.scenario
    console.print(f"wrote {out} ({steps} steps of {sc.dt_s:g} s x {sc.drones} drones)", soft_wrap=True)
