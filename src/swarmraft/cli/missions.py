"""The mission command, and the mission summary and figures the demo reuses."""

from __future__ import annotations

import json
from pathlib import Path

import click

from swarmraft.cli.app import (
    console,
    err_console,
    main,
    print_wrapped,
    progress_bar,
)
from swarmraft.cli.live import SPEED, LiveSession, check_live_options, live_options
from swarmraft.cli.options import OutFolder
from swarmraft.sim.scenario import shipped_scenarios


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
    from swarmraft.experiments.mission import judged

    wrong = judged(log) & (log.faulty != log.spoofed)
    up = log.alive & log.in_swarm()  # a drone outside the swarm is drawn as one that is down
    return [
        vm.error_over_time(
            log.t,
            errors,
            log.spoofed,
            log.outage,
            log.events,
            fig_dir / "error_over_time.png",
            sc.name,
            alive=log.alive,
            wrong=wrong,
            member=log.member,
        ),
        vm.swarm_maps(
            log.truth,
            log.reported,
            log.verified,
            log.faulty,
            steps,
            log.t,
            fig_dir / "swarm_maps.png",
            spoofed=log.spoofed,
            outage=log.outage,
            alive=up,
        ),
        vm.consensus_latency(log.t, log.latency_ms, log.events, fig_dir / "consensus_latency.png"),
        vm.messages_per_step(
            log.t,
            log.raft_messages,
            log.report_messages,
            sc.drones,
            fig_dir / "messages_per_step.png",
            log.events,
        ),
    ]


def _m(v: float | None) -> str:
    return "n/a" if v is None else f"{v} m"


def _pct(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.1%}"


def _s(v: float | None) -> str:
    return "never" if v is None else f"after {v} s"


def _ids(ids: list[int]) -> str:
    return ", ".join(str(i) for i in ids)


#: wrong-partition steps printed one by one; summary.json lists all of them
LIST_WRONG = 12


def print_mission_summary(summary: dict) -> None:
    """The summary as prose for a reader: each statement wrapped at TEXT_WIDTH (`app.print_wrapped`)."""
    s = summary
    print_wrapped(
        f"[bold]{s['scenario']}[/]: {s['drones']} drones, {s['steps']} steps, detector {s['detector']}"
    )
    for w in s["warnings"]:
        print_wrapped(f"[red]warning[/]: {w}", 2)
    from swarmraft.experiments.mission import FAULT_SKIP_WINDOW_S

    sk = s["skipped_causes"]
    when = ", ".join(f"{t:g} s" for t in sk["unexplained_times_s"])
    unexplained = (
        f"[red]{sk['unexplained']} unexplained[/] (at {when})" if sk["unexplained"] else "0 unexplained"
    )
    same = s["records_identical_on_all_nodes"]
    print_wrapped(
        f"committed {s['committed_steps']} steps, skipped {s['skipped_steps']} "
        + (
            f"([red]no record at all[/]: {sk['no_record']})"
            if sk.get("no_record")
            else f"(longest run {s['longest_skipped_run']}: {sk['before_first_record']} before the first "
            f"record, {sk['after_fault']} within {FAULT_SKIP_WINDOW_S:g} s after a fault, {unexplained})"
        )
        + "; records identical on all nodes: "
        + (
            "yes"
            if same
            else "[red]NO[/]"
            if same is not None
            else "not judged (no record applied by two nodes)"
        ),
        2,
    )
    ig = s["integrity"]
    statuses = ", ".join(f"{k} {v}" for k, v in ig["status_counts"].items())
    mis = ig["misleading_drone_steps"]
    print_wrapped(
        f"record statuses: {statuses}; protection levels (median, ok records): "
        f"horizontal {_m(ig['median_hpl_m'])}, vertical {_m(ig['median_vpl_m'])}; "
        + (
            f"[red]misleading information (error above its level, status ok): {mis} drone-steps[/]"
            f" at {', '.join(f'{t:g} s' for t in ig['misleading_times_s'])}"
            if mis
            else "misleading information (error above its level, status ok): none"
            if mis is not None
            else "misleading information: not judged (no ok record has a protection level)"
        )
        + (
            f"; [yellow]{unlevelled} drone-steps of ok records have no protection level: not judged[/]"
            if (unlevelled := ig.get("ok_drone_steps_without_level")) and mis is not None
            else ""
        ),
        2,
    )
    print_wrapped(
        f"honest drones: raw GNSS {_m(s['honest_error_gnss_m'])}, "
        f"SwarmRaft {_m(s['honest_error_swarmraft_m'])}, "
        f"snapshot bound {_m(s['honest_snapshot_bound_m'])}; "
        + (
            f"honest drones flagged in {fp:.2%} of their steps"
            if (fp := s["honest_false_positive_rate"]) is not None
            else "honest drones flagged: not judged (no honest drone in a committed step)"
        ),
        2,
    )
    hx = s["honest_worse_than_gnss"]
    print_wrapped(
        f"[{'red' if hx['longest_s'] > 1 else 'green'}]honest drones worse than raw GNSS[/] in "
        f"{hx['steps']} committed steps (longest run {hx['longest_s']:g} s; target: at most 1 s)",
        2,
    )
    wrong = s["wrong_partition_steps"]
    colour = "red" if wrong else "green"
    print_wrapped(
        f"[{colour}]wrong partition[/] (flags differ from the spoofed set among alive, "
        f"reporting drones) in {s['wrong_partition_step_count']} committed steps" + (":" if wrong else ""),
        2,
    )
    for w in wrong[:LIST_WRONG]:
        parts = []
        if w["honest_flagged"]:
            parts.append(f"honest {_ids(w['honest_flagged'])} flagged")
        if w["spoofed_not_flagged"]:
            parts.append(f"spoofed {_ids(w['spoofed_not_flagged'])} not flagged")
        print_wrapped(f"t = {w['t']:.1f} s: {'; '.join(parts)} (status {w['status']})", 4)
    if len(wrong) > LIST_WRONG:
        ranges = ", ".join(
            f"{a:.1f}" if a == b else f"{a:.1f}-{b:.1f}" for a, b in s["wrong_partition_time_ranges_s"]
        )
        print_wrapped(
            f"... {len(wrong) - LIST_WRONG} more (summary.json lists every one); all, s: {ranges}", 4
        )
    for d in s["detections"]:
        head = f"{d['kind']} on drone {d['drone']} from {d['start_s']:g} s:"
        if not d["flagged_at_least_once"]:
            print_wrapped(
                f"{head} [red]never flagged[/] in {d['judged_steps']} steps; error mean "
                f"{_m(d['mean_error_m'])}, worst {_m(d['worst_error_m'])}",
                2,
            )
            continue
        print_wrapped(
            f"{head} flagged in {_pct(d['flagged_fraction'])} of {d['judged_steps']} steps; "
            f"first {_s(d['time_to_first_detection_s'])} (its GNSS then "
            f"{_m(d['reported_error_at_first_detection_m'])} off), sustained "
            f"{_s(d['time_to_sustained_detection_s'])}",
            2,
        )
        print_wrapped(
            f"error from the spoof's start: mean {_m(d['mean_error_m'])}, worst "
            f"{_m(d['worst_error_m'])}; snapshot bound {_m(d['mean_snapshot_bound_m'])}; after "
            f"the first detection: mean {_m(d['mean_error_after_detection_m'])} against a bound of "
            f"{_m(d['mean_snapshot_bound_after_detection_m'])}",
            4,
        )
    for a in s["after_faults"]:
        print_wrapped(
            f"after {a['event']} ({a['from_s']:.1f}-{a['to_s']:.1f} s): honest drones SwarmRaft "
            f"{_m(a['honest_error_swarmraft_m'])} against raw GNSS {_m(a['honest_error_gnss_m'])}; "
            f"{a['skipped_steps']} skipped, {a['wrong_partition_steps']} wrong-partition steps",
            2,
        )
    for o in s["outages"]:
        end = "end" if o["to_s"] is None else f"{o['to_s']:g}"
        print_wrapped(
            f"GNSS outage of drone {o['drone']} ({o['from_s']:g}-{end} s): mean error SwarmRaft "
            f"{_m(o['mean_error_swarmraft_m'])}, snapshot bound {_m(o['mean_snapshot_bound_m'])}",
            2,
        )
        print_wrapped(
            f"INS aligned to the truth at the outage's start {_m(o['mean_error_ins_aligned_m'])}; "
            f"INS never reset {_m(o['mean_error_ins_alone_m'])} "
            f"({_m(o['ins_alone_error_at_start_m'])} off at the start)",
            4,
        )

    def ms(v: float | None) -> str:
        return "n/a" if v is None else f"{v} ms"

    print_wrapped(f"consensus latency median {ms(s['latency_ms_median'])}, p99 {ms(s['latency_ms_p99'])}", 2)
    per = s["raft_messages_per_committed_step"]
    print_wrapped(
        f"Raft messages per committed step {'n/a' if per is None else per} "
        f"(minimum 2(n-1) = {s['raft_minimum_per_step']}), reports per step {s['reports_per_step']}",
        2,
    )
    for e in s["events"]:
        print_wrapped(f"event: {e}", 2)
    if s["detections"]:
        print_wrapped(
            f"sustained: flagged in every step of the {s['sustained_detection_s']:g} s that start "
            "there, within the spoof",
            2,
        )
    print_wrapped(s["bound_note"], 2)


@main.command()
@click.option(
    "--scenario",
    "scenario_file",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="scenario TOML file, or the name of a shipped one: " + ", ".join(shipped_scenarios()),
)
@click.option("--out", type=OutFolder(), help="output folder [results/<name>]")
@click.option("--seed", type=click.IntRange(min=0), help="override the scenario's seed")
@click.option("--detector", help="override the scenario's detector")
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="print the summary as JSON on stdout (the lines saying what was written go to stderr)",
)
@live_options
@SPEED
def mission(
    scenario_file, out, seed, detector, as_json, live, record_to, port, viewer_memory, linger, speed
) -> None:
    """Run a mission in the simulator: drones fly, sense, report to the Raft leader, and
    apply the verified positions committed through the Raft log, with the scenario's attacks
    and faults. Writes steps.csv (one row per step and drone), summary.json, scenario.json and
    figures (error over time, swarm maps, consensus latency, messages per step).

    The summary reports, per spoofed drone, the share of its steps (committed, drone alive
    and heard) in which it was flagged, the time to its first and to its sustained detection
    (flagged in every step of the 3 s that start there, within the spoof), and its mean and worst
    error; the steps with a wrong partition (flags differ from the spoofed set); the honest
    drones' error against raw GNSS after each fault; per GNSS outage, INS aligned to the truth
    at the outage's start beside INS never reset. The "snapshot bound" is the Cramér-Rao bound
    of one step's measurements alone; SwarmRaft, which carries the previous record as a
    prior, can be below it.

    With --live, the swarm streams to rerun's web viewer while it flies, at real-time speed
    (--speed X: X times faster); with --record FILE.rrd, the same stream goes to a file
    (docs/live.md). Neither changes the mission's results."""
    from swarmraft.experiments.mission import load_scenario, run_and_write

    check_live_options(live, speed, linger, port, viewer_memory)
    sc = load_scenario(scenario_file, seed=seed)
    if detector:
        from swarmraft.sim.scenario import with_detector

        sc = with_detector(sc, detector)
    out = out or Path("results") / sc.name
    from swarmraft.experiments.results_folder import require_own

    require_own(out, "mission", "a mission")
    say = err_console if as_json else console
    session = on_step = None
    if live or record_to:
        session = LiveSession(sc.name, live, record_to, port, linger, viewer_memory, say=say)
        on_step = _live_hook(session, sc.dt_s, (speed or 1.0) if live else None)
    try:
        if session is not None:
            session.start()  # a missing extra or a port in use stops here, before the mission
        say.print(
            f"mission {sc.name}: {sc.drones} drones, {sc.duration_s:g} s at {1 / sc.dt_s:g} Hz -> {out}",
            soft_wrap=True,
        )
        prog, start = progress_bar("mission", "steps")
        with prog:
            result = run_and_write(sc, out, start(sc.steps + 1, 0), on_step)
    except BaseException:
        if session is not None:
            session.stop()
        raise
    if as_json:
        click.echo(json.dumps(result.summary, indent=2))
    else:
        print_mission_summary(result.summary)
    for p in [out / "steps.csv", out / "summary.json", out / "scenario.json", *mission_figures(result, out)]:
        say.print(f"wrote {p}", soft_wrap=True)
    if session is not None:
        say.print(session.rate_line(sc.dt_s), soft_wrap=True)
        session.close(result.log, result.errors)


def _live_hook(session: LiveSession, dt_s: float, speed: float | None):  # noqa: ANN202
    """The simulator's per-step hook: pace to ``speed`` (None: as fast as it runs) and log
    the steps known so far."""
    from swarmraft.viz.live import Pacer

    pacer = Pacer(dt_s, speed) if speed is not None else None
    session.pacer = pacer

    def on_step(log, k: int) -> None:  # noqa: ANN001
        if k == 0:
            session.static(log)
        if pacer is not None:
            pacer.wait(k)
        session.update(log, k)

    return on_step
