"""Rigid collusion under realistic noise (issue 11, item 1): exact identification, wrong
accusations and `unidentifiable` answers per detector, on the trials `swarmraft compare`
draws (same seeds and chunks: `experiments.trials.draw`), with every attacker moved at least
``--min-move`` m.

    python benchmarks/bench_collusion.py --trials 1000 --detectors shape,clique,joint

Cells (n = 2f+4 for f = 3, 4, 5 about 1 and 2 pivots, with f_max = (n-1)//2 and f_max = f;
3 pivots with f_max = f; n = 2f+1 about 1, 2 and 3 pivots) and per cell and detector:
``exact`` (flags = attackers), ``wrong`` (trials in which some honest drone is flagged),
``fp`` (honest drones flagged), ``unid`` (status unidentifiable), ``unid|exact``,
``misl`` (trials whose `ok` verdict places a drone beyond max(20 m, its level), horizontally
or vertically: misleading information) and ``ms`` (mean verification time per trial in a
batch of ``--chunk``). ``--step`` instead times single-snapshot verification (a leader
step) at one cell: best and median of ``--repeat`` snapshots, each detector on the same
snapshots. ``--param KEY=VALUE``
(repeatable) is given to every detector run, e.g. ``--detectors joint --param
registration_rivals=true``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from cli_args import param_values
from swarmraft.estimation import verify_batch
from swarmraft.experiments import build_config
from swarmraft.experiments.trials import chunk_seed, draw, integrity_metrics, snapshot_batch


def cells() -> list[tuple[str, int, int, str]]:
    """(attack, n, f, f_max rule) of the acceptance: 'default' = (n-1)//2, 'f' = f."""
    out = []
    for f in (3, 4, 5):
        for k in (1, 2):
            out += [(f"collusion-{k}", 2 * f + 4, f, "default"), (f"collusion-{k}", 2 * f + 4, f, "f")]
        out.append(("collusion-3", 2 * f + 4, f, "f"))
        for k in (1, 2, 3):
            out.append((f"collusion-{k}", 2 * f + 1, f, "default"))
    return out


def run_cell(attack, n, f, rule, detectors, trials, seed, min_move, chunk, extra=None):
    cfg = build_config(
        "realistic",
        n=(n,),
        f=(f,),
        trials=trials,
        seed=seed,
        chunk_size=chunk,
        attack={"name": attack, "min_move": min_move},
    )
    params = {**(extra or {}), **({"f_max": f} if rule == "f" else {})}
    stats = {d: {"exact": [], "wrong": [], "fp": [], "unid": [], "misl": [], "t": 0.0} for d in detectors}
    for c, lo in enumerate(range(0, trials, chunk)):
        T = min(chunk, trials - lo)
        d = draw(cfg, np.random.default_rng(chunk_seed(seed, n, f, c)), T, n, f)
        b = snapshot_batch(cfg, d)
        for det in detectors:
            t0 = time.perf_counter()
            v = verify_batch(b, det, **params)
            s = stats[det]
            s["t"] += time.perf_counter() - t0
            s["exact"].append((v.faulty == d.attackers).all(axis=1))
            s["wrong"].append((v.faulty & ~d.attackers).any(axis=1))
            s["fp"].append(v.faulty[~d.attackers])
            s["unid"].append(v.status == "unidentifiable")
            s["misl"].append(integrity_metrics(d, v)["ok_over_20m_hv"] > 0)
    rows = []
    for det in detectors:
        s = {k: np.concatenate(v) if isinstance(v, list) else v for k, v in stats[det].items()}
        rows.append(
            (
                attack,
                n,
                f,
                rule,
                det,
                s["exact"].mean(),
                s["wrong"].mean(),
                s["fp"].mean(),
                s["unid"].mean(),
                (s["unid"] | s["exact"]).mean(),
                s["misl"].mean(),
                1e3 * s["t"] / trials,
            )
        )
    return rows


def step_times(detectors, n, f, repeat, seed, extra=None):
    """Best and median single-snapshot time (ms) per detector, on the same ``repeat``
    snapshots of a realistic jump cell (n, f); with ``extra`` parameters, each detector
    also with them, interleaved, and the ratio of the two medians."""
    cfg = build_config("realistic", n=(n,), f=(f,), trials=repeat, seed=seed)
    d = draw(cfg, np.random.default_rng(chunk_seed(seed, n, f, 0)), repeat, n, f)
    b = snapshot_batch(cfg, d)
    snaps = [b.subset(np.array([t])) for t in range(repeat)]
    runs = [(det, {}) for det in detectors]
    if extra:
        runs += [(det, extra) for det in detectors]
    label = {
        i: det + ("" if not p else " " + ",".join(f"{k}={v}" for k, v in p.items()))
        for i, (det, p) in enumerate(runs)
    }
    for det, p in runs:  # warm-up: compiled kernels, imports
        verify_batch(snaps[0], det, **p)
    times = {i: [] for i in label}
    for snap in snaps:
        for i, (det, p) in enumerate(runs):  # interleaved, so load drifts hit every run alike
            t0 = time.perf_counter()
            verify_batch(snap, det, **p)
            times[i].append(1e3 * (time.perf_counter() - t0))
    for i in label:
        t = np.array(times[i])
        print(
            f"{label[i]:8s} n={n} f={f}: best {t.min():.2f} ms, median {np.median(t):.2f} ms ({repeat} steps)"
        )
    for i, det in enumerate(detectors if extra else []):
        ratio = np.median(times[len(detectors) + i]) / np.median(times[i])
        print(f"{det}: median with {label[len(detectors) + i].split(' ', 1)[1]} / without: {ratio:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--detectors", default="shape,clique,joint")
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=2025)
    ap.add_argument("--min-move", type=float, default=30.0, help="every attacker moved at least, m")
    ap.add_argument("--chunk", type=int, default=1000, help="trials per batch (sweeps: chunk_size)")
    ap.add_argument("--only", default="", help="comma-separated attack names to keep (e.g. collusion-3)")
    ap.add_argument("--f", default="", help="comma-separated attacker counts to keep (of 3, 4, 5)")
    ap.add_argument("--step", default="", help="N,F: time single-snapshot steps at this cell instead")
    ap.add_argument("--repeat", type=int, default=200, help="--step: snapshots timed")
    ap.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a parameter of every detector run (repeatable), e.g. registration_rivals=true",
    )
    a = ap.parse_args()
    dets = a.detectors.split(",")
    extra = {}
    for det in dets:
        extra = param_values(ap, a.param, det)
    if a.step:
        n, f = (int(v) for v in a.step.split(","))
        step_times(dets, n, f, a.repeat, a.seed, extra)
        return
    keep = set(a.only.split(",")) if a.only else None
    print("attack       n  f  f_max    detector exact  wrong  fp     unid   unid|exact  misl   ms/trial")
    for attack, n, f, rule in cells():
        if (keep and attack not in keep) or (a.f and str(f) not in a.f.split(",")):
            continue
        for row in run_cell(attack, n, f, rule, dets, a.trials, a.seed, a.min_move, a.chunk, extra):
            at, n_, f_, r, det, ex, wr, fp, un, ue, ml, ms = row
            fm = n_ - 1 >> 1 if r == "default" else f_
            print(
                f"{at:12s} {n_:2d} {f_:2d} {fm:2d} ({r:7s}) {det:8s} {ex:.3f}  {wr:.3f}  {fp:.4f} "
                f"{un:.3f}  {ue:.3f}       {ml:.3f}  {ms:.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
