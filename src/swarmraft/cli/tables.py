"""Terminal tables of the `swarmraft` command, laid out to fit 80 columns: short headers, one
space between columns, names never cut, and a legend printed under each table that spells
out every abbreviation. Each function returns (table, legend)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from rich import box
from rich.table import Table


def _table(title: str) -> Table:
    return Table(
        title=title,
        title_justify="left",
        box=box.SIMPLE_HEAD,
        padding=0,  # the box's space between columns is the only gap
        pad_edge=False,
        show_edge=False,
    )


def _names(t: Table, header: str, values: Sequence[object]) -> None:
    """A column of names, wide enough for the longest so none is cut."""
    t.add_column(header, no_wrap=True, min_width=max([len(header), *(len(str(v)) for v in values)]))


def _num(v: float, spec: str) -> str:
    """``v`` formatted by ``spec``; ``-`` where it does not exist (nan), as every table marks it."""
    v = float(v)
    return "-" if np.isnan(v) else format(v, spec)


def _pct(v: float) -> str:
    return _num(v, ".1%")


SUMMARY_LEGEND = (
    "Errors in m, over the trials of each cell. base: the attacked drones' reports before "
    "verification; mean, sem, med, p99: the attacked drones after recovery (mean, its standard "
    "error, median, 99th percentile); >1m: share of trials whose attacked drones' mean error "
    "after recovery is over 1 m; hon: honest drones after verification; det: attacked drones "
    "flagged; FP: honest drones flagged (false positives)."
)


UNDETERMINED_LEGEND = (
    " und: share of the drones left without a position (nan: the geometry does not fix them, or "
    "withheld under the alert limits); "
    "the attacked drones' statistics are over the trials that place them."
)


def _undetermined(rows: Mapping[str, np.ndarray]) -> tuple[np.ndarray, bool]:
    """The rows' shares of undetermined drones, and whether the column is shown (some row has
    any): a sweep's table and a comparison's show it alike."""
    und = np.asarray(rows.get("undetermined_rate", np.zeros(len(rows["n"]))), float)
    return und, bool((und > 0).any())


def summary_table(cells: Mapping[str, np.ndarray], title: str) -> tuple[Table, str]:
    """A sweep's cells: the paper's metric for the attacked drones, and the rates; with a
    column of undetermined drones where any cell has them (its statistics leave them out)."""
    t = _table(title)
    und, shown = _undetermined(cells)
    for col in ("n", "f", "trials", "base", "mean", "sem", "med", "p99", ">1m", "hon", "det", "FP"):
        t.add_column(col, justify="right", no_wrap=True)
    if shown:
        t.add_column("und", justify="right", no_wrap=True)
    for i in range(len(cells["n"])):
        t.add_row(
            str(cells["n"][i]),
            str(cells["f"][i]),
            str(cells["trials"][i]),
            _num(cells["baseline_mean"][i], ".2f"),
            _num(cells["recovered_mean"][i], ".3g"),
            _num(cells["recovered_sem"][i], ".2g"),
            _num(cells["recovered_median"][i], ".2g"),
            _num(cells["recovered_p99"][i], ".3g"),
            _pct(cells["frac_over_1m"][i]),
            _num(cells["honest_mean"][i], ".3g"),
            _pct(cells["detection_rate"][i]),
            _pct(cells["false_positive_rate"][i]),
            *([_pct(und[i])] if shown else []),
        )
    return t, SUMMARY_LEGEND + (UNDETERMINED_LEGEND if shown else "")


COMPARE_LEGEND = (
    "Errors in m. att: attacked drones after verification; hon: honest drones after "
    "verification; GNSS: honest drones' raw GNSS reports; eff: efficiency of the attacked "
    "drones, sqrt(MSE / Cramér-Rao bound), 1 is the bound, - where no Gaussian bound exists; "
    "det: attacked drones flagged; FP: honest drones flagged; id: trials whose flag set is "
    "exactly the attackers; unid: trials the detector called unidentifiable."
)


def compare_table(table: Mapping[str, np.ndarray], title: str) -> tuple[Table, str]:
    """Detectors on identical trials: one row per attack, detector and (n, f); with a column
    of undetermined drones where any row has them (its statistics leave them out), as the
    sweep's table."""
    t = _table(title)
    _names(t, "attack", table["attack"])
    _names(t, "detector", table["detector"])
    und, shown = _undetermined(table)
    for col in (
        "n",
        "f",
        "att",
        "hon",
        "GNSS",
        "eff",
        "det",
        "FP",
        "id",
        "unid",
        *(("und",) if shown else ()),
    ):
        t.add_column(col, justify="right", no_wrap=True)
    for i in range(len(table["n"])):
        eff = float(table["attacked_efficiency"][i])
        t.add_row(
            str(table["attack"][i]),
            str(table["detector"][i]),
            str(table["n"][i]),
            str(table["f"][i]),
            _num(table["recovered_mean"][i], ".3g"),
            _num(table["honest_mean"][i], ".3g"),
            _num(table["honest_baseline_mean"][i], ".3g"),
            _num(eff, ".2f"),
            _pct(table["detection_rate"][i]),
            _pct(table["false_positive_rate"][i]),
            _pct(table["identification_rate"][i]),
            _pct(table["status_unidentifiable"][i]),
            *([_pct(und[i])] if shown else []),
        )
    return t, COMPARE_LEGEND + (UNDETERMINED_LEGEND if shown else "")


def check_legend(max_z: float, max_gap_m: float) -> str:
    return (
        "Means in m. recovered, sem: this sweep's mean error of the attacked drones after "
        "recovery and its standard error; published: the paper's mean; z = (recovered - "
        f"published) / sem; baseline: mean error of the attacked drones' reports, beside the "
        f"published one; ok: |z| <= {max_z:g} and baseline within {max_gap_m:g} m."
    )


def check_table(rows: Sequence[Mapping[str, object]], title: str, legend: str) -> tuple[Table, str]:
    """A reference sweep against the published means, one row per cell n = 2f+1."""
    t = _table(title)
    for col in ("n (f)", "trials", "recovered", "sem", "published", "z", "baseline", "published", "ok"):
        t.add_column(col, justify="right", no_wrap=True)
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
    return t, legend


CALIBRATION_LEGEND = (
    "Thresholds in m, from honest snapshots (paper III.E). tau = pair mu + 3 pair sigma: the "
    "vote's threshold, from the mean and standard deviation over honest pairs of |distance "
    "between their reports - their range|; epsilon = rec mu + 3 rec sigma: the re-marking "
    "threshold, from the distance between an honest drone's report and its multilateration "
    "from the others."
)


def calibration_table(rows: Sequence[tuple[int, object]], title: str) -> tuple[Table, str]:
    """Calibrated thresholds per swarm size n: (n, Calibration) rows."""
    t = _table(title)
    for col in ("n", "tau", "pair mu", "pair sigma", "epsilon", "rec mu", "rec sigma"):
        t.add_column(col, justify="right", no_wrap=True)
    for n, c in rows:
        t.add_row(
            str(n),
            f"{c.tau:.3f}",
            f"{c.pair_mean:.3f}",
            f"{c.pair_std:.3f}",
            f"{c.epsilon:.3f}",
            f"{c.recovery_mean:.3f}",
            f"{c.recovery_std:.3f}",
        )
    return t, CALIBRATION_LEGEND


STATUS_LEGEND = (
    "term, commit, applied, last: the drone's Raft term, commit index, applied index and last "
    "log index; step: the last step it applied; now: the step the clock is at, of the steps; "
    "reach: peers heard from within the longest election timeout (a follower hears its leader, "
    "and with the audit on every drone's report fan-out too); quorum: a leader with those makes "
    "a majority, or a follower heard its leader; "
    "dropped: datagrams its Verifier refused, by reason."
)

PEERS_LEGEND = (
    "The leader's view of each follower: match, the highest log index known to be on it; next, "
    "the next index it sends; state: probe (one append at a time until answered) or replicate "
    "(pipelined); heard: ms since the leader last accepted a datagram from it."
)


def status_table(answers: Mapping[int, object]) -> tuple[Table, str]:
    """One row per drone of `swarmraft status` (answers: drone -> net.status.Answer)."""
    t = _table("Drones")
    for h in ("drone", "address", "role", "term", "leader", "commit", "applied", "last", "step", "now"):
        t.add_column(h, justify="left" if h in ("address", "role") else "right", no_wrap=True)
    t.add_column("reach", justify="right", no_wrap=True)
    t.add_column("quorum", no_wrap=True)
    t.add_column("dropped")
    for i, a in answers.items():
        addr = "{}:{}".format(*a.address)
        f = a.fields
        if f is None:
            t.add_row(str(i), addr, f"[red]{a.problem}[/]", *[""] * 10)
            continue
        dropped = ", ".join(f"{k} {v}" for k, v in sorted(f["dropped"].items())) or "none"
        quorum = "yes" if f["quorum"] else "[red]NO[/]"
        t.add_row(
            str(i),
            addr,
            f["role"],
            str(f["term"]),
            str(f["leader"] or "-"),
            str(f["commit"]),
            str(f["applied"]),
            str(f["last_index"]),
            str(f["last_step"]),
            # before step 0 the clock's step is negative: say how far off step 0 is instead
            f"{f['step_now']}/{f['steps']}" if f["step_now"] >= 0 else f"starts in {-f['step_now']} steps",
            f"{f['reachable_peers']}/{len(f['peers'])}",
            quorum,
            dropped,
        )
    return t, STATUS_LEGEND


def peers_table(leader: int, fields: Mapping[str, object]) -> tuple[Table, str]:
    """The leader's per-follower progress (its status answer's ``peers``)."""
    t = _table(f"Leader {leader}'s followers")
    for h in ("peer", "match", "next", "state", "heard"):
        t.add_column(h, justify="left" if h == "state" else "right", no_wrap=True)
    for p, e in fields["peers"].items():  # type: ignore[union-attr]
        heard = "never" if e["heard_ms"] is None else f"{e['heard_ms']} ms"
        t.add_row(str(p), str(e.get("match", "-")), str(e.get("next", "-")), e.get("state", "-"), heard)
    return t, PEERS_LEGEND


MUTANTS_LEGEND = (
    "Each mutant is one bug written into a copy of the Raft core (swarmraft.sim.mutants), "
    "fuzzed alone (no unit test) until its first failing seed. caught: whether a seed failed; "
    "seed: the first failing seed (replay it on the mutated copy with --seed-start S --seeds 1); "
    "check: the invariant or check that failed; seeds: seeds run. The unmodified core is "
    "fuzzed first over the same seeds: a mutant result means something only if it passes."
)


def mutants_table(rows: Sequence[Mapping[str, object]], title: str) -> tuple[Table, str]:
    """One row per mutant of ``raft-fuzz --mutants``: name, caught, seed, check, seeds."""
    t = _table(title)
    _names(t, "mutant", [r["name"] for r in rows])
    for col in ("caught", "seed", "check", "seeds"):
        t.add_column(col, justify="left" if col in ("caught", "check") else "right", no_wrap=True)
    for r in rows:
        t.add_row(
            str(r["name"]),
            str(r["caught"]),
            "-" if r["seed"] is None else str(r["seed"]),
            str(r["check"] or "-"),
            str(r["seeds"]),
        )
    return t, MUTANTS_LEGEND
