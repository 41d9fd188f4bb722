"""Where a detector's efficiency over every trial goes: its `alarm` verdicts, by cause, and
whether any trusted set could have answered them (issue 8: `joint`'s efficiency over every
trial at (9, 4)). The trials are the sweep's own (`swarmraft sweep --preset realistic
--detector DET --n N --f F --trials 1000*CHUNKS`: the same seeds, chunks of 1,000).

Printed: the attacked drones' efficiency over every trial with a bound and an error (as
`cells.csv`'s `attacked_efficiency`), each status' share of the trials and of the squared
error, the alarms by cause; then, for every alarm, each set that leaves exactly f drones out
(as many as there are attackers) given to the estimator (`verify_given`: the robust
estimate and assessment, no detection): how many such sets pass every test (status `ok`) and
whether the true honest set is among them. C(n, f) sets a trial: 126 at (9, 4), 24,310 at (17, 8).

Run: .venv/bin/python benchmarks/alarm_sets.py [--n 9 --f 4 --chunks 2 --detector joint]
     [--param set_search=5000 --param better_fit_margin=11.34]
"""

from __future__ import annotations

import argparse
import collections

import numpy as np

from cli_args import param_values
from swarmraft.estimation import verify_batch, verify_given
from swarmraft.estimation.integrity import given_set_fields
from swarmraft.estimation.set_search import sets_leaving_out
from swarmraft.experiments import build_config
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.trials import bound_metrics, chunk_seed, draw, snapshot_batch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=9)
    ap.add_argument("--f", type=int, default=4)
    ap.add_argument("--chunks", type=int, default=2, help="chunks of 1,000 trials")
    ap.add_argument("--detector", default="joint", choices=["clique", "fde", "joint", "shape"])
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="a detector parameter")
    a = ap.parse_args()
    n, f = a.n, a.f
    if not (n >= 3 and 1 <= f <= (n - 1) // 2 and a.chunks >= 1):
        ap.error(f"need n >= 3, 1 <= f <= (n-1)//2 and --chunks >= 1; got n = {n}, f = {f}")
    config = build_config("realistic", n=(n,), f=(f,), trials=1000 * a.chunks, detector=a.detector)
    params, _ = detector_settings(config, n)
    params.update(param_values(ap, a.param, a.detector))
    given = {k: v for k, v in params.items() if k in given_set_fields()}  # not detection's
    sets = sets_leaving_out(n, f)  # as many drones out as there are attackers
    sq, bound, status, cause = [], [], [], []
    search = collections.Counter()
    for c in range(a.chunks):
        d = draw(config, np.random.default_rng(chunk_seed(config.seed, n, f, c)), 1000, n, f)
        v = verify_batch(snapshot_batch(config, d), a.detector, **params)
        m = bound_metrics(config, d, v.positions)
        sq.append(m["attacked_sq"])
        bound.append(m["attacked_bound"])
        status.append(v.status)
        cause.append(np.asarray(v.diagnostics["alarm_cause"]).astype(str))
        for t in np.flatnonzero(v.status == "alarm"):
            S = len(sets)
            b = snapshot_batch(config, d).subset(np.full(S, t))
            ok = np.flatnonzero(verify_given(b, sets, a.detector, **given).status == "ok")
            right = bool((sets[ok] == ~d.attackers[t]).all(axis=1).any())
            kind = "none" if not ok.size else "one" if ok.size == 1 else "several"
            search[(kind, right)] += 1
    sq, bound = np.concatenate(sq), np.concatenate(bound)
    status, cause = np.concatenate(status), np.concatenate(cause)
    use = np.isfinite(sq) & np.isfinite(bound)
    total = sq[use].sum()
    print(f"{a.detector} at ({n}, {f}), realistic, {len(status)} trials (seed {config.seed})")
    eff = np.sqrt(sq[use].mean() / bound[use].mean())
    print(f"attacked efficiency over every trial: {eff:.3f} ({(~use).sum()} left out)")
    for s in sorted(set(status)):
        k = use & (status == s)
        eff = np.sqrt(sq[k].mean() / bound[k].mean()) if k.any() else float("nan")
        share = sq[k].sum() / total
        print(f"  {s:15s} {(status == s).sum():6d} trials, {share:6.1%} of the squared error, eff. {eff:.2f}")
    for c in sorted(set(cause[status == "alarm"])):
        k = use & (status == "alarm") & (cause == c)
        print(f"  alarm, {c:20s} {(k).sum():4d} trials with an error, {sq[k].sum() / total:6.1%} of it")
    print(f"every alarm given each of the {len(sets)} sets with f = {f} drones out:")
    for (kind, right), count in sorted(search.items()):
        print(f"  {kind:8s} passing, the true set {'among them' if right else 'not among them'}: {count}")


if __name__ == "__main__":
    main()
