"""Every trusted set, for a verdict that ended in ``alarm``: smallest exclusion first.

A detector's alarm says its chosen set fails its tests and exclusion is exhausted. Where the
swarm is small, every set that leaves out at most ``f_max`` drones can be tried instead, as
RAIM's exhaustive fault detection and exclusion does: for k = 0, 1, ..., ``f_max`` drones
left out, each of the C(n, k) sets is given to the estimator (`integrity.given_set`); at the
smallest k where some set passes every test, one passing set is the answer (judged again by
`integrity.finish`, rivals and all), several are ``unidentifiable`` (estimated from the
drones every passing set trusts, only the drones outside all of them flagged), and where no
set passes up to ``f_max`` the alarm stands. The search stops, leaving the alarm, before the
sets tried would exceed ``cap``: the count grows as C(n, f_max) (126 at n = 9, 1,716 at 13,
24,310 at 17).

At (9, 4) (realistic, jumps of 10-100 m) `joint`'s alarms are 4 % of the trials and 65 % of
the attacked drones' squared error: `benchmarks/alarm_sets.py`, and README, "Integrity,
measured"."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np

from swarmraft.estimation.integrity import IntegrityParams, finish, given_set, status_rank
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch

FIELDS = ("positions", "faulty", "status", "drone_status", "hpl", "vpl")


def sets_leaving_out(n: int, k: int) -> np.ndarray:
    """Every trusted set (C(n, k), n) of n drones with exactly k left out, in
    lexicographic order of the drones left out."""
    out = np.ones((math.comb(n, k), n), dtype=bool)
    for row, left in enumerate(itertools.combinations(range(n), k)):
        out[row, list(left)] = False
    return out


def search_alarms(
    batch: SnapshotBatch, p: IntegrityParams, noise: NoiseModel, v: VerdictBatch, f_max: int, cap: int
) -> VerdictBatch:
    """``v`` with each ``alarm`` verdict replaced by the exhaustive search's answer where it
    is better (see the module docstring); ``cap`` sets at most per trial (0: no search)."""
    rows = np.flatnonzero(v.status == "alarm")
    if cap <= 0 or not rows.size:
        return v
    n = v.faulty.shape[1]
    out = {name: getattr(v, name).copy() for name in FIELDS}
    out["status"] = out["status"].astype(object)
    out["drone_status"] = out["drone_status"].astype(object)
    for t in rows:
        w = _search(batch, p, noise, t, n, f_max, cap)
        if w is None or status_rank(w.status)[0] >= status_rank(np.array(["alarm"]))[0]:
            continue
        for name in FIELDS:
            out[name][t] = getattr(w, name)[0]
    return replace(
        v, **{k: (a.astype(str) if k in ("status", "drone_status") else a) for k, a in out.items()}
    )


def _search(
    batch: SnapshotBatch, p: IntegrityParams, noise: NoiseModel, t: int, n: int, f_max: int, cap: int
) -> VerdictBatch | None:
    """The search's verdict for trial t, or None where no set passes within ``cap`` sets."""
    tried = 0
    one = batch.subset(np.array([t]))
    for k in range(f_max + 1):
        tried += math.comb(n, k)
        if tried > cap:
            return None
        sets = sets_leaving_out(n, k)
        g = given_set(batch.subset(np.full(len(sets), t)), p, sets)
        passing = sets[g.status == "ok"]
        if len(passing) == 1:
            return finish(one, p, noise, passing)
        if len(passing) > 1:
            common = passing.all(axis=0)[None]
            outside = ~passing.any(axis=0)[None]
            return finish(one, p, noise, common, status=np.array(["unidentifiable"]), faulty=outside)
    return None
