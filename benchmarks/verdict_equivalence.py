"""Do two versions of the detectors give the same verdicts? A fixed set of seeded trials,
every detector, saved once and compared after a change (a speed-up must not change a verdict).

Cells: n = 5, 7, 9, 13, 17; f = n // 4 and f_max = (n - 1) // 2; jump (10-100 m) and
collusion-3 (collusion-2 at n = 5) attacks; cube, flat and near-line geometry; realistic
noise (GNSS 1.5/3 m, UWB 0.10 m). Each cell is verified as one batch (as a sweep does);
the benchmark's own snapshots (bench_detectors.py: n = 17, f = 8, seed 7) are also verified
one at a time (as the leader does). Detectors: paper (reference recovery and joint
recovery), clique, fde, joint.

With ``--sparse N``, also the first N snapshots of bench_sparse.py (n = 65, f = 16, 60 m
range in a 150 m formation, seed 7) verified one at a time by `joint`, `fde` and `shape`:
the sparse range graph's solver (save and check with the same options).

Compared: flags, per-drone trusted set, status and per-drone status exactly; positions, hpl and vpl
bit for bit (``exact``) or within ``--tol`` m with the same nan/inf pattern.

Run:
  .venv/bin/python benchmarks/verdict_equivalence.py save /tmp/verdicts_before.npz
  .venv/bin/python benchmarks/verdict_equivalence.py check /tmp/verdicts_before.npz [--tol 1e-9]
``check`` exits 1 if any verdict differs beyond the tolerance. The small reference the
tests compare against (tests/data/verdicts_small.npz, 9 cells of 2 trials) is made with
  .venv/bin/python benchmarks/verdict_equivalence.py save tests/data/verdicts_small.npz \
      --small --trials 2 --steps 0
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from bench_sparse import formation_draw
from swarmraft.estimation import Snapshot, SnapshotBatch, VerdictBatch, verify, verify_batch
from swarmraft.experiments import build_config
from swarmraft.experiments.trials import draw, snapshot_batch

SIZES = (5, 7, 9, 13, 17)
GEOMETRIES = ("cube", "flat", "line")
ATTACKS = ("jump", "collusion-3")  # collusion-2 at n = 5
DETECTORS = {
    "paper": {},
    "paper-joint": {"recovery": "joint"},
    "clique": {},
    "fde": {},
    "joint": {},
}
EXACT_FIELDS = ("faulty", "trusted", "status", "drone_status")
CLOSE_FIELDS = ("positions", "hpl", "vpl")


SMALL = {"sizes": (5, 9, 17), "attacks": ("jump",), "both_f": False}  # tests/test_verdicts.py


def cells(
    trials: int, sizes=SIZES, attacks=ATTACKS, both_f: bool = True
) -> Iterator[tuple[str, SnapshotBatch]]:
    """(name, batch) of every cell, each drawn from its own seed (``both_f``: f = n // 4 and
    f_max, else f_max only)."""
    for gi, geometry in enumerate(GEOMETRIES):
        for ai, name in enumerate(ATTACKS):
            if name not in attacks:
                continue
            for n in sizes:
                for f in sorted({n // 4, (n - 1) // 2} if both_f else {(n - 1) // 2}):
                    attack = name
                    if f < 1:
                        continue
                    if attack.startswith("collusion") and (n - 1) // 2 < 3:
                        attack = "collusion-2"  # 3 pivots need f_max >= 3 (n >= 7)
                    config = build_config(
                        "realistic",
                        n=(n,),
                        f=(f,),
                        trials=trials,
                        geometry=geometry,
                        attack={"name": attack, "jump": "shell", "low": 10.0, "high": 100.0},
                    )
                    seq = np.random.SeedSequence(entropy=2025, spawn_key=(n, f, gi, ai))
                    d = draw(config, np.random.default_rng(seq), trials, n, f)
                    yield f"{geometry}/{attack}/n{n}/f{f}", snapshot_batch(config, d)


def bench_snapshots(steps: int) -> list[Snapshot]:
    """The first ``steps`` snapshots of bench_detectors.py (n = 17, f = 8, seed 7)."""
    config = build_config("realistic", n=(17,), f=(8,), trials=steps)
    d = draw(config, np.random.default_rng(7), steps, 17, 8)
    return [
        Snapshot(reported=d.reported[t], ranges=d.ranges[t], gnss_sigma=(1.5, 3.0), range_sigma=0.1)
        for t in range(steps)
    ]


SPARSE_DETECTORS = ("joint", "fde", "shape")


def sparse_snapshots(steps: int) -> list[Snapshot]:
    """The first ``steps`` snapshots of bench_sparse.py (n = 65, f = 16, seed 7)."""
    _, d = formation_draw(65, 16, steps)
    return [
        Snapshot(reported=d.reported[t], ranges=d.ranges[t], gnss_sigma=(1.5, 3.0), range_sigma=0.1)
        for t in range(steps)
    ]


def fields(v: VerdictBatch) -> dict[str, np.ndarray]:
    n = v.faulty.shape[1]
    trusted = v.diagnostics.get("trusted", np.zeros(v.faulty.shape, dtype=bool))
    return {
        "positions": np.asarray(v.positions, float),
        "hpl": np.asarray(v.hpl, float),
        "vpl": np.asarray(v.vpl, float),
        "faulty": np.asarray(v.faulty, bool),
        "trusted": np.asarray(trusted, bool).reshape(-1, n),
        "status": np.asarray(v.status).astype("<U14"),
        "drone_status": np.asarray(v.drone_status).astype("<U14"),
    }


def stacked(verdicts: list) -> dict[str, np.ndarray]:
    """Single verdicts as the fields of one batch."""
    batch = VerdictBatch(
        positions=np.stack([v.positions for v in verdicts]),
        faulty=np.stack([v.faulty for v in verdicts]),
        status=np.array([v.status for v in verdicts]),
        diagnostics={"trusted": np.stack([v.diagnostics.get("trusted") for v in verdicts])},
        drone_status=np.stack([v.drone_status for v in verdicts]),
        hpl=np.stack([v.hpl for v in verdicts]),
        vpl=np.stack([v.vpl for v in verdicts]),
    )
    return fields(batch)


def collect(
    trials: int,
    steps: int,
    detectors: tuple[str, ...] = tuple(DETECTORS),
    small: bool = False,
    sparse: int = 0,
) -> dict[str, np.ndarray]:
    """Every verdict field of every cell and detector, keyed 'cell/detector/field'
    (``small``: only the cells of `SMALL`; ``sparse``: and that many sparse snapshots)."""
    out: dict[str, np.ndarray] = {}
    batches = list(cells(trials, **(SMALL if small else {})))
    for det in detectors:
        name = det.split("-")[0]
        for cell, batch in batches:
            for k, arr in fields(verify_batch(batch, name, **DETECTORS[det])).items():
                out[f"{cell}/{det}/{k}"] = arr
        if steps and name != "paper":
            verdicts = [verify(s, name, **DETECTORS[det]) for s in bench_snapshots(steps)]
            for k, arr in stacked(verdicts).items():
                out[f"bench/{det}/{k}"] = arr
    if sparse:
        snaps = sparse_snapshots(sparse)
        for det in SPARSE_DETECTORS:
            for k, arr in stacked([verify(s, det) for s in snaps]).items():
                out[f"sparse65/{det}/{k}"] = arr
    return out


def compare(ref: dict[str, np.ndarray], new: dict[str, np.ndarray], tol: float) -> list[str]:
    """One line per field that differs beyond ``tol`` (0: bit for bit); empty if none."""
    problems = []
    for key in sorted(set(ref) | set(new)):
        if key not in ref or key not in new:
            problems.append(f"{key}: only in {'reference' if key in ref else 'new'}")
            continue
        a, b = ref[key], new[key]
        if a.shape != b.shape:
            problems.append(f"{key}: shape {a.shape} vs {b.shape}")
            continue
        if key.rsplit("/", 1)[1] in EXACT_FIELDS:
            bad = a != b
        else:
            same_kind = (np.isnan(a) == np.isnan(b)) & (np.isinf(a) == np.isinf(b))
            finite = np.isfinite(a) & np.isfinite(b)
            with np.errstate(invalid="ignore"):
                close = np.where(finite, np.abs(a - b) <= tol, (a == b) | (np.isnan(a) & np.isnan(b)))
            bad = ~(same_kind & close)
        if bad.any():
            trials = np.unique(np.nonzero(bad)[0])
            detail = ""
            if key.rsplit("/", 1)[1] in CLOSE_FIELDS:
                with np.errstate(invalid="ignore"):
                    diff = np.where(np.isfinite(a) & np.isfinite(b), np.abs(a - b), np.nan)
                detail = f", largest finite difference {np.nanmax(diff, initial=0.0):.3g}"
            problems.append(f"{key}: {bad.sum()} entries in trials {trials[:10].tolist()} differ{detail}")
    return problems


def largest_difference(ref: dict[str, np.ndarray], new: dict[str, np.ndarray]) -> float:
    """The largest finite difference of positions, hpl and vpl over every key both hold."""
    worst = 0.0
    for key in set(ref) & set(new):
        if key.rsplit("/", 1)[1] in CLOSE_FIELDS and ref[key].shape == new[key].shape:
            a, b = ref[key], new[key]
            both = np.isfinite(a) & np.isfinite(b)
            if both.any():
                worst = max(worst, float(np.abs(a[both] - b[both]).max()))
    return worst


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("action", choices=("save", "check"))
    ap.add_argument("path")
    ap.add_argument("--trials", type=int, default=8, help="trials per cell (60 cells)")
    ap.add_argument("--steps", type=int, default=40, help="bench snapshots verified one at a time")
    ap.add_argument("--tol", type=float, default=0.0, help="m; 0: bit for bit")
    ap.add_argument("--small", action="store_true", help="9 cells (the reference of tests/test_verdicts.py)")
    ap.add_argument("--sparse", type=int, default=0, help="sparse 65-drone snapshots verified one at a time")
    args = ap.parse_args(argv)
    if args.sparse < 0:
        ap.error("--sparse: need a count >= 0")
    if args.action == "check" and not Path(args.path).is_file():
        ap.error(f"{args.path}: no such file (make it first with `save` and the same options)")
    new = collect(args.trials, args.steps, small=args.small, sparse=args.sparse)
    if args.action == "save":
        np.savez_compressed(args.path, **new)
        print(f"saved {len(new)} arrays to {args.path}")
        return 0
    with np.load(args.path, allow_pickle=False) as z:
        ref = {k: z[k] for k in z.files}
    problems = compare(ref, new, args.tol)
    n_trials = sum(v.shape[0] for k, v in ref.items() if k.endswith("/status"))
    worst = largest_difference(ref, new)
    print(f"{len(ref)} arrays, {n_trials} verdicts; largest position/hpl/vpl difference {worst:.3g} m")
    for line in problems:
        print("DIFFERS", line)
    print("identical" if not problems else f"{len(problems)} fields differ (tol {args.tol:g} m)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
