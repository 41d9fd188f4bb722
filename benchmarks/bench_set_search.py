"""What `joint`'s ``set_search`` costs a leader step it runs on (a verdict that ends in an
alarm, or in a `degenerate` verdict accusing drones): the first ``--alarms`` such trials of
the sweep's realistic (n, f) cell (seed 2025, chunk 0), each verified alone with the search
off and on (CPU ms, best of ``--repeat``), with the status before and after. No target of
its own: a mission's step has 100 ms at 10 Hz. With ``--geometry flat`` (every drone within
0.5 m of a plane) or ``line``, the trials of that sweep geometry (in a flat layer most
verdicts are searched).

``--search`` and ``--budget`` default to `joint`'s own defaults (``set_search`` 4,096 sets,
``search_budget`` 256 sets estimated for one verdict; a verdict that needs more stands);
``--budget 0`` lifts the budget. The last line gives the median, 90th percentile and largest
CPU ms over the trials timed, search off and on.

Run: .venv/bin/python benchmarks/bench_set_search.py [--n 9 --f 4 --alarms 4] [--search 5000]
     [--geometry flat] [--budget 64 | --budget 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from swarmraft.estimation import verify_batch
from swarmraft.estimation.gnc import JointParams
from swarmraft.experiments import build_config
from swarmraft.experiments.trials import chunk_seed, draw, snapshot_batch


def cpu_ms(fn, repeat: int) -> tuple[float, object]:  # noqa: ANN001
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        best = min(best, (time.process_time() - t0) * 1000)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=9)
    ap.add_argument("--f", type=int, default=4)
    ap.add_argument("--alarms", type=int, default=4)
    defaults = JointParams()
    ap.add_argument("--search", type=int, default=defaults.set_search, help="set_search (sets at most)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--geometry", choices=["cube", "flat", "line"], default="cube")
    ap.add_argument(
        "--budget",
        type=int,
        default=defaults.search_budget,
        help="search_budget (sets estimated at most; 0: no limit)",
    )
    a = ap.parse_args()
    if not (a.n >= 3 and 1 <= a.f <= (a.n - 1) // 2 and a.alarms >= 1 and a.search >= 1 and a.repeat >= 1):
        ap.error("need n >= 3, 1 <= f <= (n-1)//2, and --alarms, --search, --repeat >= 1")
    if a.budget < 0:
        ap.error("--budget must be at least 0 (0: no limit)")
    on_params = {"set_search": a.search, "search_budget": a.budget or None}
    cfg = build_config("realistic", n=(a.n,), f=(a.f,), trials=1000, geometry=a.geometry)
    d = draw(cfg, np.random.default_rng(chunk_seed(cfg.seed, a.n, a.f, 0)), 1000, a.n, a.f)
    batch = snapshot_batch(cfg, d)
    v0 = verify_batch(batch, "joint", set_search=0)
    searched = (v0.status == "alarm") | ((v0.status == "degenerate") & v0.faulty.any(axis=1))
    rows = np.flatnonzero(searched)[: a.alarms]
    print(
        f"joint at ({a.n}, {a.f}), realistic, {a.geometry}: {int(searched.sum())} of 1000 trials searched "
        f"({int((v0.status == 'alarm').sum())} alarm), the first {len(rows)}: CPU ms (best of {a.repeat})"
    )
    label = f"set_search={a.search}, " + (f"budget {a.budget}" if a.budget else "no budget")
    print(f"{'trial':>6} {'off':>8} {label:>26}  status off -> on")
    offs, ons = [], []
    for t in rows:
        one = batch.subset(np.array([t]))
        off, _ = cpu_ms(lambda one=one: verify_batch(one, "joint", set_search=0), a.repeat)
        on, w = cpu_ms(lambda one=one: verify_batch(one, "joint", **on_params), a.repeat)
        offs.append(off)
        ons.append(on)
        print(f"{t:>6} {off:8.1f} {on:26.1f}  {v0.status[t]} -> {w.status[0]}")
    q = [0.5, 0.9]
    print(
        f"over {len(rows)} trials, CPU ms median / p90 / largest: off "
        + " / ".join(f"{x:.1f}" for x in [*np.quantile(offs, q), max(offs)])
        + ", on "
        + " / ".join(f"{x:.1f}" for x in [*np.quantile(ons, q), max(ons)])
    )


if __name__ == "__main__":
    main()
