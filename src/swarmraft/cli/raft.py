"""The raft-fuzz command."""

from __future__ import annotations

import sys

import click

from swarmraft.cli.app import (
    console,
    main,
    progress_bar,
)


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
@click.option(
    "--nodes",
    type=click.IntRange(min=3),
    default=5,
    show_default=True,
    help="cluster size (3 or more: the runs partition the cluster and crash nodes)",
)
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
