"""The raft-fuzz command: the fault fuzzer, and its mutation suite (``--mutants``)."""

from __future__ import annotations

import sys
import time

import click

from swarmraft.cli.app import (
    console,
    main,
    print_table,
    print_wrapped,
    progress_bar,
)
from swarmraft.sim.invariants import INVARIANTS

_CHECKS = (*INVARIANTS, "liveness")  # what --without may switch off


@main.command("raft-fuzz")
@click.option(
    "--seeds",
    type=click.IntRange(min=1),
    default=None,
    help="how many seeds to run [default: 500; with --mutants, the budget per mutant: 300]",
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
    default=None,
    help="cluster size, 3 or more (the runs partition the cluster and crash nodes) [default: 3-7 per seed]",
)
@click.option(
    "--fault-ms",
    type=click.FloatRange(min=0),
    default=3000.0,
    show_default=True,
    help="virtual time with faults per seed",
)
@click.option(
    "--loss", type=click.FloatRange(0, 1), default=None, help="loss per link [default: 0-0.3 per seed]"
)
@click.option(
    "--max-entries",
    type=click.IntRange(min=1),
    default=None,
    help="entries per append at most [default: 1-4 per seed, 64 in one seed in five]",
)
@click.option("--pre-vote/--no-pre-vote", default=None, help="PreVote on or off [default: drawn per seed]")
@click.option(
    "--check-quorum/--no-check-quorum", default=None, help="CheckQuorum on or off [default: drawn per seed]"
)
@click.option(
    "--membership/--no-membership",
    default=None,
    help="membership changes, leader transfers and linearizable reads in every seed, or in none "
    "[default: in half the seeds]",
)
@click.option(
    "--without",
    type=click.Choice(_CHECKS),
    multiple=True,
    metavar="NAME",
    help="do not check this invariant, or liveness (repeatable): shows what each one alone catches; "
    f"one of {', '.join(_CHECKS)}",
)
@click.option(
    "--mutants",
    is_flag=True,
    help="the mutation suite: fuzz each injected bug of swarmraft.sim.mutants alone; exit 1 if one survives",
)
@click.option(
    "--mutant",
    "only",
    multiple=True,
    metavar="NAME",
    help="with --mutants: only this mutant (repeatable)",
)
def raft_fuzz(
    seeds,
    seed_start,
    nodes,
    fault_ms,
    loss,
    max_entries,
    pre_vote,
    check_quorum,
    membership,
    without,
    mutants,
    only,
) -> None:
    """Randomised Raft fault runs in the simulator, every safety invariant checked after
    every event: 3-7 nodes with PreVote and CheckQuorum drawn per seed; crashes, crashes
    restarted at once and crashes between saving a Ready and sending it; partitions, one-way
    cuts, loss, duplication, reordering by up to 400 ms; appends of 1-4 entries, and in one
    seed in ten logs of 1000-3000 entries; in half the seeds, membership changes (nodes join
    as learners, learners are promoted, voters and the leader removed), leader transfers and
    linearizable reads. Once the faults stop, liveness (with PreVote: a leader among its
    voters that every member follows within two election timeouts, then no term change) and
    convergence (every committed entry on every member).

    Exits 1 and prints each failing seed if any run fails.

    With --mutants: the mutation suite. Each injected bug of swarmraft.sim.mutants is written
    into a copy of the package and fuzzed alone in a child process until its first failing
    seed (at most --seeds, default 300); prints which invariant caught it, and exits 1 if a
    mutant survives or the unmodified core fails.
    """
    from swarmraft.sim.fuzz import FuzzConfig, run_seeds

    if mutants:
        _mutation_suite(seeds or 300, seed_start, without, only)
        return
    if only:
        raise click.BadParameter("needs --mutants", param_hint="--mutant")
    seeds = seeds or 500
    cfg = FuzzConfig(
        nodes=nodes,
        fault_ms=fault_ms,
        loss=loss,
        max_entries_per_msg=max_entries,
        pre_vote=pre_vote,
        check_quorum=check_quorum,
        without=frozenset(without),
        membership=0.5 if membership is None else float(membership),
    )
    failed = []
    events = longest = changes = reads = 0
    t0 = time.perf_counter()
    prog, start = progress_bar("raft-fuzz", "seeds")
    with prog:
        advance = start(seeds, 0)
        for r in run_seeds(seed_start, seeds, cfg):
            events += r.events
            longest = max(longest, r.last_index)
            changes += r.conf_changes
            reads += r.reads
            if not r.ok:
                failed.append(r)
                prog.console.print(f"[red]FAIL[/] seed {r.seed} ({r.invariant}): {r.error}")
            advance(1)
    print_wrapped(
        f"{seeds} seeds ({seed_start}..{seed_start + seeds - 1}), {fault_ms:.0f} ms of faults each, "
        f"{events} events checked, logs up to {longest} entries, {changes} configuration changes, "
        f"{reads} reads answered, {time.perf_counter() - t0:.0f} s: "
        + (
            "no violation"
            if not failed
            else f"{len(failed)} failing seed(s): " + ", ".join(str(r.seed) for r in failed)
        )
    )
    sys.exit(1 if failed else 0)


def _mutation_suite(budget: int, seed_start: int, without: tuple[str, ...], only: tuple[str, ...]) -> None:
    from swarmraft.cli.tables import mutants_table
    from swarmraft.sim.mutants import MUTANTS, MutantTree, by_name

    try:
        chosen = by_name(only) if only else list(MUTANTS)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--mutant") from None
    rows = []
    t0 = time.perf_counter()
    prog, start = progress_bar("mutants", "seeds")
    with prog, MutantTree() as tree:
        for mutant in [None, *chosen]:
            name = mutant.name if mutant else "(unmodified core)"
            advance = start(budget, 0, name)
            ran, failure = 0, None
            for outcome in tree.run(mutant, budget, seed_start, without):
                ran += 1
                advance(1)
                if not outcome.ok:
                    failure = outcome
            if mutant is None:
                caught = "[red]FAILS[/]" if failure else "passes"
            else:
                caught = "yes" if failure else "[red]NO[/]"
            rows.append(
                {
                    "name": name,
                    "caught": caught,
                    "seed": failure.seed if failure else None,
                    "check": failure.invariant if failure else None,
                    "seeds": ran,
                    "survived": mutant is not None and failure is None,
                    "control_failed": mutant is None and failure is not None,
                }
            )
            if failure and mutant is None:
                prog.console.print(f"[red]the unmodified core fails[/] seed {failure.seed}: {failure.error}")
    title = f"Mutation suite: up to {budget} seeds from {seed_start} per mutant"
    if without:
        title += f", without {', '.join(without)}"
    print_table(mutants_table(rows, title))
    survived = [r["name"] for r in rows if r["survived"]]
    bad_control = any(r["control_failed"] for r in rows)
    console.print(
        f"{len(chosen) - len(survived)} of {len(chosen)} mutants caught in {time.perf_counter() - t0:.0f} s"
        + (f"; survived: {', '.join(survived)}" if survived else "")
        + ("; the unmodified core failed too" if bad_control else "")
    )
    sys.exit(1 if survived or bad_control else 0)
