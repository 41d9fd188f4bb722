"""Every attack against every detector in one table (issue: adversaries the swarm misses,
item 7): for one (n, f) cell on the realistic preset, the share of trials whose attackers are
identified exactly, the share with a wrong accusation (at least one honest drone flagged),
the share whose `ok` verdict places a drone beyond max(20 m, its protection level) (misleading
information), the honest drones' mean error against their raw GNSS error, the attacked
drones' mean error, the share of `ok` verdicts, and the detector's median CPU time per
snapshot.

Rows are `swarmraft compare`'s attacks on clean UWB ranges, then `jump` again with 20 % of
the links non-line-of-sight (+0.3 to 1 m, drawn per link). The trials of a row are the same
for every detector (compare's draws depend only on the seed and the cell). Coordinated
drag-off is a mission attack (a slow drift over many steps), not a snapshot one: see the
README's drag-off section.

Run: .venv/bin/python benchmarks/attack_table.py [--n 13] [--f 3] [--trials 1000]
     [--detectors paper,clique,fde,joint] [--attacks jump,collusion-2,...] [--out FOLDER]
     [--param KEY=VALUE ...]   (given to every detector: --detectors joint --param registration_rivals=true)
The compare folders are kept under --out (default: a temporary folder).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cli_args import param_values
from swarmraft.estimation import Snapshot, verify
from swarmraft.experiments import build_config
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.compare import run_compare
from swarmraft.experiments.config import ATTACKS, ConfigError
from swarmraft.experiments.tables import read_table
from swarmraft.experiments.trials import draw

NLOS = {"nlos_prob": 0.2, "nlos_bias": (0.3, 1.0), "nlos_mode": "link"}
TIMED = 40  # snapshots timed one at a time per detector and row


def wrong_share(folder: Path) -> float:
    """Share of trials in which at least one honest drone was flagged."""
    t = read_table(folder / "trials.csv")
    return float(np.mean(np.asarray(t["false_positive_rate"], float) > 0))


def far_share(folder: Path) -> float:
    """Share of trials whose `ok` verdict places a drone beyond max(20 m, its level),
    horizontally or vertically (misleading information: `trials.csv`'s ok_over_20m_hv)."""
    t = read_table(folder / "trials.csv")
    return float(np.mean(np.asarray(t["ok_over_20m_hv"], float) > 0))


def step_ms(config, n: int, f: int, detector: str) -> float:  # noqa: ANN001
    """Median CPU ms of one verification of one snapshot of this row's draws."""
    d = draw(config, np.random.default_rng(7), TIMED, n, f)
    params, _ = detector_settings(config.model_copy(update={"detector": detector}), n)
    sig = (config.gnss.sigma_h, config.gnss.sigma_v)
    snaps = [
        Snapshot(reported=d.reported[t], ranges=d.ranges[t], gnss_sigma=sig, range_sigma=config.ranging.sigma)
        for t in range(TIMED)
    ]
    for s in snaps[:5]:
        verify(s, detector, **params)
    times = []
    for s in snaps:
        t0 = time.process_time()
        verify(s, detector, **params)
        times.append((time.process_time() - t0) * 1e3)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=13)
    ap.add_argument("--f", type=int, default=3)
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--detectors", default="paper,clique,fde,joint")
    ap.add_argument("--attacks", default=",".join(ATTACKS))
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a parameter of every detector (repeatable), e.g. registration_rivals=true",
    )
    a = ap.parse_args()
    detectors = [d for d in a.detectors.split(",") if d]
    attacks = [x for x in a.attacks.split(",") if x]
    bad = [x for x in attacks if x not in ATTACKS]
    if bad:
        sys.exit(f"attack_table: --attacks: unknown {', '.join(bad)}; known: {', '.join(ATTACKS)}")
    extra = {}
    for det in detectors:
        extra = param_values(ap, a.param, det)
    rows = [(x, x, {}) for x in attacks] + [("jump + NLOS 20 % links", "jump", NLOS)]
    out = a.out or Path(tempfile.mkdtemp(prefix="swarmraft-attack-table-"))
    print(f"n = {a.n}, f = {a.f}, realistic preset, {a.trials} trials a row; folders under {out}")
    print(
        "| attack | detector | exact | wrong | ok and beyond max(20 m, PL) | honest / raw GNSS | attacked m "
        "| ok | CPU ms |\n"
        "|---|---|---|---|---|---|---|---|---|",
        flush=True,
    )
    for label, attack, ranging in rows:
        try:
            cfg = build_config(
                "realistic",
                n=(a.n,),
                f=(a.f,),
                trials=a.trials,
                attack={"name": attack},
                ranging=ranging,
                detector=detectors[0],
                detector_params=extra,
            )
        except ConfigError as exc:
            sys.exit(f"attack_table: {exc}")
        folder = out / label.split()[0] / ("nlos" if ranging else "clean")
        table, results = run_compare(cfg, detectors, [attack], folder, workers=a.workers)
        for i, (det, res) in enumerate(zip(detectors, results, strict=True)):
            ratio = table["honest_mean"][i] / table["honest_baseline_mean"][i]
            ms = step_ms(cfg, a.n, a.f, det)
            print(
                f"| {label} | {det} | {table['identification_rate'][i]:.3f} | {wrong_share(res.out):.3f} "
                f"| {far_share(res.out):.3f} "
                f"| {ratio:.2f} | {table['recovered_mean'][i]:.1f} | {table['status_ok'][i]:.3f} "
                f"| {ms:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
