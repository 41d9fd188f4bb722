"""The commands of the networked runtime (`swarmraft.net`): keygen (key files), node (one drone
process) and launch (a swarm of drone processes on this machine)."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import click

from swarmraft.cli.app import console, err_console, main, print_table
from swarmraft.cli.live import LiveSession, check_live_options, live_options
from swarmraft.cli.options import OutFolder


def _nearest_existing(path: Path) -> Path:
    for p in (path, *path.parents):
        if p.exists():
            return p
    return Path(".")


def _scenario_drones() -> click.IntRange:
    """--n's range: a scenario's (4-256 drones; keys for fewer fly no swarm)."""
    from swarmraft.sim.scenario import SCENARIO_DRONES

    return click.IntRange(*SCENARIO_DRONES)


@main.command("keygen")
@click.option(
    "--n", "n", type=_scenario_drones(), required=True, help="number of drones (4-256); their ids are 1..N"
)
@click.option(
    "--out", type=OutFolder(), required=True, help="folder for drone-<id>.key and swarm-keys.toml (created)"
)
@click.option("--force", is_flag=True, help="replace key files that exist already")
def keygen(n: int, out: Path, force: bool) -> None:
    """Write an Ed25519 key pair for each of N drones: OUT/drone-<id>.key, the drone's private
    key (32 raw bytes, mode 0600: copy it to that drone only), and OUT/swarm-keys.toml, every
    drone's public key in hex (every drone needs it). Existing key files are left alone
    unless --force is given.
    """
    from swarmraft.net.keys import key_files, write_keys

    base = _nearest_existing(out)
    if not os.access(base, os.W_OK | os.X_OK):
        raise click.BadParameter(f"{base} is not writable", param_hint="--out")
    if not force and (taken := [p for p in key_files(out, n) if p.exists() or p.is_symlink()]):
        more = f" (and {len(taken) - 1} more)" if len(taken) > 1 else ""
        raise click.BadParameter(f"{taken[0]} exists{more}; give --force to replace it", param_hint="--out")
    try:
        paths = write_keys(out, n, force=force)
    except OSError as exc:
        raise click.BadParameter(
            f"cannot write {exc.filename or out}: {exc.strerror}", param_hint="--out"
        ) from None
    first, last = paths[0], paths[-2]
    keys = str(first) if n == 1 else f"{first} .. {last}"
    console.print(f"wrote {keys} (private keys, mode 0600: copy each to its drone only)", soft_wrap=True)
    console.print(
        f"wrote {paths[-1]} (the public keys of all {n} drones: every drone needs it)", soft_wrap=True
    )


#: The --swarm option of node and status: the swarm file (docs/net.md).
SWARM_FILE = click.option(
    "--swarm",
    "swarm_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="the swarm file (swarm.toml: addresses, keys, scenario, start time; docs/net.md)",
)


@main.command("node")
@click.option("--id", "drone_id", type=click.IntRange(min=1), required=True, help="this drone's id (1..n)")
@SWARM_FILE
@click.option("-v", "--verbose", is_flag=True, help="log every dropped datagram and role change (INFO)")
def node(drone_id: int, swarm_path: Path, verbose: bool) -> None:
    """Run drone ID of a networked swarm until its scenario ends, or SIGTERM / Ctrl-C.

    It binds its UDP address from the swarm file, keeps its Raft term, vote and log in
    OUT/drone-<ID>.sqlite (a restart on the same file rejoins with its log), computes its own
    sensor readings from the swarm's scenario and seed, reports to the leader each step, and
    writes one JSON line per applied step to OUT/drone-<ID>.steps.jsonl and its starts, role
    changes and final counters to OUT/drone-<ID>.events.jsonl. With the scenario's
    protocol.audit (the default) it checks every record of its leader before it takes it.
    SIGUSR1 makes it lie whenever it leads, as the scenario's lying-leader fault says
    (docs/audit.md).
    """
    import logging

    from swarmraft.net.node import run_node

    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format=f"%(asctime)s drone {drone_id} %(levelname)s %(name)s: %(message)s",
    )
    status = run_node(swarm_path, drone_id)
    if status:
        sys.exit(status)


def short_log(sensor_log, sc, path: Path) -> str | None:  # noqa: ANN001 (SensorLog, Scenario)
    """What launch says when a replayed log ends before the scenario's last step, beyond what
    its last lines serve (the replay source's max_age_s, launch's default) (None: it covers it)."""
    from swarmraft.net.swarmfile import ReplaySourceConfig

    serves = ReplaySourceConfig.model_fields["max_age_s"].default
    last = float(sensor_log.t_s.max()) if sensor_log.t_s.size else 0.0
    flown = sc.steps * sc.dt_s
    if last + serves >= flown - 1e-9:
        return None
    return (
        f"{path} ends at {last:g} s and the scenario flies {flown:g} s: the steps after its end "
        f"have no reading once its last lines are max_age_s ({serves:g} s) old (docs/records.md) "
        "and are skipped"
    )


@main.command("launch")
@click.option(
    "--scenario",
    "scenario",
    required=True,
    help="a shipped scenario's name or a scenario TOML file (docs/scenarios.md)",
)
@click.option(
    "--out",
    type=OutFolder(),
    required=True,
    help="folder for keys, swarm.toml, the drones' files and the results (steps.csv, summary.json, figures)",
)
@click.option("--seed", type=click.IntRange(min=0), default=None, help="override the scenario's seed")
@click.option(
    "--start-delay",
    "start_delay",
    type=click.FloatRange(min=0),
    default=None,
    help="seconds from launch to step 0, for the processes to start (default: 3 + 2.5 x drones / cores)",
)
@click.option(
    "--relay",
    "relay",
    type=click.Choice(["auto", "on", "off"]),
    default="auto",
    show_default=True,
    help="put the fault relay between the drones (delay, loss, duplication, reordering, partitions); "
    "auto: when the scenario has loss, duplication, reordering or partition/heal/loss faults",
)
@click.option(
    "--replay",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="a sensor log every drone replays instead of the scenario's model (docs/records.md)",
)
@live_options
def launch(
    scenario: str,
    out: Path,
    seed: int | None,
    start_delay: float | None,
    relay: str,
    replay: Path | None,
    live: bool,
    record_to: Path | None,
    port: int | None,
    viewer_memory: str | None,
    linger: float | None,
) -> None:
    """Run a scenario as a real swarm on this machine: one `swarmraft node` process per drone
    on 127.0.0.1 over signed UDP datagrams.

    Writes OUT/keys, OUT/scenario.toml and OUT/swarm.toml; starts the processes (their files
    in OUT/nodes); puts the fault relay between them when needed (--relay); applies the
    scenario's faults at their times (crash and crash-leader: SIGKILL; restart: start again on
    the same SQLite file; pause: SIGSTOP, then SIGCONT; partition, heal and loss: the relay);
    waits for the scenario's end; then writes what `swarmraft mission` writes (steps.csv,
    summary.json, scenario.json, figures/) from the drones' files, and OUT/records.csv (per
    step: how many drones hold it and whether their records are identical). Exit status 1 if
    any step's records differ between drones; Ctrl-C stops every process (status 130).

    With --replay LOG the drones' readings come from LOG (copied to OUT/sensors.csv); the
    scenario still sets the protocol, the steps and the faults.

    With --live, the swarm streams to rerun's web viewer as the drones write their step files
    (a few steps behind), the true positions taken from the scenario's world; --record
    FILE.rrd writes the same stream to a file (docs/live.md).
    """
    from swarmraft.cli.missions import mission_figures, print_mission_summary
    from swarmraft.experiments.mission import load_scenario, write_results
    from swarmraft.net.launch import gather_steps
    from swarmraft.net.localswarm import LocalSwarm
    from swarmraft.net.results import launch_log
    from swarmraft.sim.scenario import find_scenario
    from swarmraft.sim.sensing import ScenarioWorld

    sc = load_scenario(scenario, seed=seed)
    # a swarm's own files: new drones would reopen an earlier run's SQLite logs and step files
    # and report its records as theirs
    from swarmraft.net.launch import NODES_DIR

    held = [name for name in ("swarm.toml", "keys", NODES_DIR) if (out / name).exists()]
    if held:
        raise click.BadParameter(
            f"{out} holds a swarm already ({', '.join(held)}); choose another folder", param_hint="--out"
        )
    from swarmraft.experiments.results_folder import require_own

    require_own(out, "launch", "a networked run")  # not beside a sweep's, comparison's or mission's files
    from swarmraft.net.node import step_too_short

    if why := step_too_short(sc.dt_s, sc.raft.tick_ms):  # as each drone would refuse it, before they start
        raise click.BadParameter(f"dt_s: {why}", param_hint="--scenario")
    if start_delay is not None and not math.isfinite(start_delay):
        raise click.BadParameter(
            f"{start_delay}: give a finite number of seconds", param_hint="--start-delay"
        )
    n = sc.drones
    if replay is not None:
        from swarmraft.net.sources.replay import SensorLogError, read_sensor_log

        try:  # a bad log is one line (file:line: field: problem) before anything starts
            sensor_log = read_sensor_log(replay, n)
        except SensorLogError as exc:
            raise click.BadParameter(str(exc), param_hint="--replay") from None
        if short := short_log(sensor_log, sc, replay):  # said before the run, not after it in red skips
            console.print(f"[red]warning[/]: {short}", soft_wrap=True)
    check_live_options(live, None, linger, port, viewer_memory)
    session = follow = world = None
    if live or record_to:
        # the drones' records can come a second or more after their step on a loaded machine
        session = LiveSession(
            sc.name, live, record_to, port, linger, viewer_memory, settle_steps=int(round(3 / sc.dt_s))
        )
        session.start()
        world = ScenarioWorld.build(sc)
    try:
        run = LocalSwarm(
            sc, find_scenario(scenario), out, seed, start_delay, relay, replay, say=console.print
        )
        run.prepare()
        console.print(f"wrote {out / 'keys'} and {run.swarm_path}", soft_wrap=True)
        console.print(
            f"starting {n} drone processes; step 0 at +{run.start_delay_s:.1f} s, "
            f"{sc.duration_s:g} s of scenario"
        )
        console.print(run.network_line(), soft_wrap=True)
        if session is not None:
            from swarmraft.cli.live import FollowLaunch
            from swarmraft.net.results import LaunchTail

            tail = LaunchTail(world, run.nodes_dir, run.start_unix_s, run.events, run.kills)
            follow = FollowLaunch(session, tail, run.start_unix_s, sc.dt_s)
            follow.start()
        run.run_stoppable()
    except BaseException:
        if session is not None:
            if follow is not None:
                follow.stop()
            session.stop()
        raise
    if follow is not None:
        follow.stop()
    # an interrupted run is summarised over the steps it reached (the others were not skipped:
    # they never came); one stopped before step 0 reached none
    flown = run.steps_flown()
    if flown == 0:
        if session is not None:
            session.stop()
        err_console.print(
            f"interrupted ({run.signal_name}) before step 0: nothing flown, no results written "
            f"({out} holds the swarm's keys and files: give another --out to launch again)"
        )
        sys.exit(run.exit_status)
    g = gather_steps(run.nodes_dir, n, flown - 1, sc.dt_s, out / "records.csv")
    up = run.up_after_step0()
    world = world or ScenarioWorld.build(sc)
    log = launch_log(world, run.nodes_dir, run.start_unix_s, run.events, run.kills, run.idle_faults)
    log = log.first_steps(flown)
    extra = {
        "launch": {
            "processes": n,
            "start_delay_s": round(run.start_delay_s, 2),
            "up_after_step0_s": {str(d): t for d, t in up.items()},
            "fault_relay": run.relay is not None,
            "relay_counters": run.relay_counters,
            "steps_with_records_differing": [r["step"] for r in g.rows if not r["identical"]],
            "interrupted": run.interrupted,
            "sigkilled_at_end": run.unstoppable,
            "exited_on_their_own": [{"drone": d, "s": t, "exit_status": rc} for d, t, rc in run.exited],
        }
    }
    result = write_results(log, out, extra)
    print_mission_summary(result.summary)
    late = {d: t for d, t in up.items() if t is None or t > 0}
    if late:
        worst = max((t for t in late.values() if t is not None), default=None)
        never = [d for d, t in late.items() if t is None]
        console.print(
            f"[red]warning[/]: {len(late)} of {n} drone processes were not up at step 0"
            + (f" (the last {worst:.1f} s after it)" if worst is not None else "")
            + (f"; never up: {', '.join(map(str, never))}" if never else "")
            + "; the steps before a quorum was up are skipped: give a longer --start-delay"
            # a value to try: this run's delay plus the lateness seen, and 2 s to spare
            + (f" (here now: about {run.start_delay_s + worst + 2:.0f})" if worst is not None else ""),
            soft_wrap=True,
        )
    skipped = len(g.rows) - g.committed
    same = "yes" if g.all_identical else "[red]NO[/]"
    console.print(
        f"{g.committed} of {len(g.rows)} steps committed, {skipped} skipped; "
        f"every node's records identical: {same}"
    )
    for p in [
        out / "steps.csv",
        out / "summary.json",
        out / "scenario.json",
        *mission_figures(result, out),
        out / "records.csv",
    ]:
        console.print(f"wrote {p}", soft_wrap=True)
    files = "drone-<id>.(steps.jsonl, events.jsonl, sent.csv, log, sqlite)"
    console.print(f"wrote {run.nodes_dir}/{files}", soft_wrap=True)
    if session is not None:
        console.print(session.rate_line(sc.dt_s), soft_wrap=True)
        session.close(result.log, result.errors)
    if run.interrupted:
        err_console.print(f"interrupted ({run.signal_name})")
        sys.exit(run.exit_status)
    if not g.all_identical:
        sys.exit(1)
    if g.committed == 0:  # a run with no record is void, whatever its files say
        err_console.print("error: no step was committed (were the drones up? see the warnings above)")
        sys.exit(1)


@main.command("status")
@SWARM_FILE
@click.option(
    "--timeout",
    type=click.FloatRange(min=0.05, max=60),
    default=1.0,
    show_default=True,
    help="seconds to wait for the answers",
)
@click.option("--json", "as_json", is_flag=True, help="print the answers as JSON")
def status(swarm_path: Path, timeout: float, as_json: bool) -> None:
    """Ask every drone of a running swarm for its state: role, term, leader, commit and
    applied index, last log index, last step applied, whether it hears a quorum, the
    datagrams it dropped, and the leader's view of each follower (match and next index).

    The drones answer at their advertised addresses (through launch's fault relay too) with a
    signed answer, checked against the swarm's public keys. Exit status 0 if every drone
    answered, 1 if some did not.
    """
    import json

    from swarmraft.cli.tables import peers_table, status_table
    from swarmraft.net.keys import KeyFileError, load_public_keys
    from swarmraft.net.status import ask
    from swarmraft.net.swarmfile import SwarmFileError, load_swarm

    try:
        swarm = load_swarm(swarm_path)
        publics = load_public_keys(swarm.public_keys)
    except (SwarmFileError, KeyFileError) as exc:
        raise click.BadParameter(str(exc), param_hint="--swarm") from None
    if missing := sorted(set(swarm.drones) - set(publics)):  # as a node refuses it
        raise click.BadParameter(
            f"{swarm.public_keys}: no public key for drone {missing[0]}", param_hint="--swarm"
        )
    answers = ask(swarm, publics, timeout)
    if as_json:
        out = {str(i): a.fields or {"problem": a.problem} for i, a in answers.items()}
        click.echo(json.dumps(out, indent=2))
    else:
        print_table(status_table(answers))
        leaders = [a for a in answers.values() if a.fields and a.fields["role"] == "leader"]
        for lead in sorted(leaders, key=lambda a: -a.fields["term"]):  # type: ignore[index]
            print_table(peers_table(lead.drone, lead.fields))  # type: ignore[arg-type]
        # no answer at all, and answers that came but were not taken (a bad signature: the
        # wrong keys file, say): told apart, as the rows tell them
        silent = [i for i, a in answers.items() if a.fields is None and a.problem == "no answer"]
        refused = [i for i, a in answers.items() if a.fields is None and a.problem != "no answer"]
        if silent:
            who = ", ".join(map(str, silent))
            console.print(f"[red]{len(silent)} of {len(answers)} drones did not answer[/]: {who}")
        if refused:
            who = ", ".join(map(str, refused))
            console.print(
                f"[red]{len(refused)} of {len(answers)} drones answered with an answer not taken[/] "
                f"(the row says why): {who}"
            )
    if any(a.fields is None for a in answers.values()):
        sys.exit(1)
