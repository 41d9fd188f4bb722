"""The mission command, and the mission summary and figures the demo reuses."""

from __future__ import annotations

from pathlib import Path

import click

from swarmraft.cli.app import (
    console,
    main,
    progress_bar,
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
