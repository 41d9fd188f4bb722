"""Acceptance runs of range faults (issue 11, items 2 and 4; README "Range faults").

``nlos``: no attack, NLOS on ``--nlos`` of the links (+0.3 to 1 m), per link and per
direction, against the same trials with clean links (same truth and GNSS draws): per detector
the share of honest drones flagged and the mean position error of the honest drones, and its
ratio to the clean error. Targets: flagged <= 2 %, ratio <= 1.3.

``enlarge``: distance enlargement of ``--low``-``--high`` m on f of n drones (their GNSS
honest, or with ``--jump`` also spoofed 10-100 m): per detector the share of attackers flagged,
the share of trials with every attacker flagged, and the share of honest drones flagged.
Target: attackers flagged >= 0.9. Last column: the share of the missed attackers that are
vertices of their swarm's convex hull (on its edge), and the share of all drones that are.

``--links off`` runs the detectors without the range screening (as before it existed);
``--links screen`` turns it on for ``paper`` too (off by default there).

The realistic preset (GNSS 1.5/3 m, UWB 0.10 m, 100 m cube), paper's thresholds calibrated as
a sweep does. Run:
    .venv/bin/python benchmarks/range_faults.py nlos [--trials 1000] [--n 13] [--nlos 0.2]
    .venv/bin/python benchmarks/range_faults.py enlarge [--trials 1000] [--n 11] [--f 2] [--jump]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial import ConvexHull

from swarmraft.estimation import verify_batch
from swarmraft.experiments import build_config
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.trials import chunk_seed, draw, snapshot_batch

DETECTORS = ("paper", "clique", "fde", "joint")


def _run(config, n: int, f: int, det: str, chunk: int, links: str | None = None):
    cfg = config.model_copy(update={"detector": det})
    d = draw(cfg, np.random.default_rng(chunk_seed(cfg.seed, n, f, chunk)), cfg.trials, n, f)
    params, _ = detector_settings(cfg, n)
    if links is not None:
        params["links"] = links
    t0 = time.perf_counter()
    v = verify_batch(snapshot_batch(cfg, d), det, **params)
    return d, v, time.perf_counter() - t0


def _on_hull(truth: np.ndarray) -> np.ndarray:
    """(T, n) the drones that are vertices of their swarm's convex hull (its edge)."""
    out = np.zeros(truth.shape[:2], dtype=bool)
    for t, x in enumerate(truth):
        out[t, ConvexHull(x).vertices] = True
    return out


def nlos(args: argparse.Namespace) -> None:
    print(f"n = {args.n}, no attack, NLOS on {args.nlos:.0%} of links, {args.trials} trials")
    print("detector  links      flagged  honest err  ratio to clean   status ok   s")
    for det in args.detectors:
        errs = {}
        for mode in ("clean", "link", "direction"):
            ranging = {"kind": "uwb", "sigma": 0.10}
            if mode != "clean":
                ranging |= {"nlos_prob": args.nlos, "nlos_mode": mode}
            config = build_config(
                "realistic", n=(args.n,), trials=args.trials, seed=args.seed, ranging=ranging
            )
            # chunk 1: f = 0, chunk 0 is the calibration's stream
            d, v, sec = _run(config, args.n, 0, det, 1, args.links)
            err = np.linalg.norm(v.positions - d.truth, axis=2)
            errs[mode] = np.nanmean(err)
            print(
                f"{det:8s}  {mode:9s}  {v.faulty.mean():7.4f}  {errs[mode]:8.3f} m  "
                f"{errs[mode] / errs['clean']:14.3f}   {np.mean(v.status == 'ok'):9.3f}  {sec:5.1f}",
                flush=True,
            )


def enlarge(args: argparse.Namespace) -> None:
    name = "enlarge-jump" if args.jump else "enlarge"
    print(
        f"n = {args.n}, f = {args.f}, {name} {args.low:g}-{args.high:g} m, {args.trials} trials, "
        f"NLOS {args.nlos:.0%} per link"
    )
    print("detector  attackers flagged  all flagged  honest flagged  status ok   s  missed on hull")
    ranging = {"kind": "uwb", "sigma": 0.10, "nlos_prob": args.nlos}
    attack = {"name": name, "enlarge_low": args.low, "enlarge_high": args.high}
    config = build_config(
        "realistic", n=(args.n,), trials=args.trials, seed=args.seed, attack=attack, ranging=ranging
    )
    for det in args.detectors:
        d, v, sec = _run(config, args.n, args.f, det, 0, args.links)
        hit = v.faulty[d.attackers].mean()
        every = (v.faulty | ~d.attackers).all(axis=1).mean()
        fp = v.faulty[~d.attackers].mean()
        missed = d.attackers & ~v.faulty
        hull = _on_hull(d.truth)
        print(
            f"{det:8s}  {hit:17.3f}  {every:11.3f}  {fp:14.4f}  {np.mean(v.status == 'ok'):9.3f}  {sec:5.1f}"
            f"  {hull[missed].mean():.3f} of {missed.sum()} (all drones {hull.mean():.3f})",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("nlos", "enlarge"):
        p = sub.add_parser(name)
        p.add_argument("--trials", type=int, default=1000)
        p.add_argument("--seed", type=int, default=2025)
        p.add_argument("--detectors", nargs="+", default=list(DETECTORS))
        p.add_argument(
            "--links", choices=("screen", "off"), help="the detectors' range screening (default: theirs)"
        )
    p = sub.choices["nlos"]
    p.add_argument("--n", type=int, default=13)
    p.add_argument("--nlos", type=float, default=0.2)
    p = sub.choices["enlarge"]
    p.add_argument("--n", type=int, default=11)
    p.add_argument("--f", type=int, default=2)
    p.add_argument("--low", type=float, default=2.0)
    p.add_argument("--high", type=float, default=10.0)
    p.add_argument("--nlos", type=float, default=0.0)
    p.add_argument("--jump", action="store_true", help="also spoof the attackers' GNSS by 10-100 m")
    args = ap.parse_args()
    {"nlos": nlos, "enlarge": enlarge}[args.cmd](args)


if __name__ == "__main__":
    main()
