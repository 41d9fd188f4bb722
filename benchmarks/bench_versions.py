"""Two versions of the detectors in one process, step by step: the ratio of their leader-step
times at n = 17, f = 8 (the snapshots of bench_detectors.py, realistic preset, seed 7), which
the machine's drift between minutes does not move (the absolute times do).

The other version is a source tree (e.g. the code before a change):

  git worktree add --detach /tmp/old HEAD~3
  .venv/bin/python benchmarks/bench_versions.py --old /tmp/old/src [--detectors clique,joint]

Its package is copied to a temporary folder as ``swarmraft_old`` (its imports renamed), so
both load side by side; each snapshot is verified by both, in alternating order, and the
median of the per-step ratios new/old is printed with both medians (CPU time per step).
"""

from __future__ import annotations

import argparse
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from swarmraft.experiments import build_config
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.trials import draw


def load_old(src: Path, into: Path):  # noqa: ANN201 (a module)
    """``src``/swarmraft copied to ``into``/swarmraft_old with its imports renamed, imported."""
    pkg = into / "swarmraft_old"
    shutil.copytree(src / "swarmraft", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    for f in pkg.rglob("*.py"):
        text = f.read_text()
        text = re.sub(r"\bswarmraft\.", "swarmraft_old.", text)
        text = re.sub(r"\bfrom swarmraft import\b", "from swarmraft_old import", text)
        text = re.sub(r"^import swarmraft$", "import swarmraft_old", text, flags=re.M)
        f.write_text(text)
    sys.path.insert(0, str(into))
    import swarmraft_old.estimation as old

    return old


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, required=True, help="the other version's src folder")
    ap.add_argument("--detectors", default="clique,joint")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3, help="passes over the snapshots")
    a = ap.parse_args()
    if not (a.old / "swarmraft" / "__init__.py").is_file():
        ap.error(f"--old: {a.old} holds no swarmraft package (give a tree's src folder)")
    import swarmraft.estimation as new

    with tempfile.TemporaryDirectory() as tmp:
        old = load_old(a.old, Path(tmp))
        config = build_config("realistic", n=(17,), f=(8,), trials=a.steps)
        d = draw(config, np.random.default_rng(7), a.steps, 17, 8)
        print(f"{a.steps} snapshots x {a.rounds} rounds, n = 17, f = 8; CPU ms per step (median):")
        for det in a.detectors.split(","):
            params, _ = detector_settings(config.model_copy(update={"detector": det}), 17)
            pair = []
            for mod in (new, old):
                snaps = [
                    mod.Snapshot(
                        reported=d.reported[t], ranges=d.ranges[t], gnss_sigma=(1.5, 3.0), range_sigma=0.1
                    )
                    for t in range(a.steps)
                ]
                for s in snaps[:10]:  # compiled kernels loaded
                    mod.verify(s, det, **params)
                pair.append((mod, snaps))
            times: dict[str, list[float]] = {"new": [], "old": []}
            ratios = []
            for r in range(a.rounds):
                for t in range(a.steps):
                    order = [("new", *pair[0]), ("old", *pair[1])]
                    took = {}
                    for name, mod, snaps in order if (t + r) % 2 else order[::-1]:
                        t0 = time.process_time()
                        mod.verify(snaps[t], det, **params)
                        took[name] = time.process_time() - t0
                        times[name].append(took[name])
                    if took["old"] > 0:
                        ratios.append(took["new"] / took["old"])
            med_new, med_old = (statistics.median(times[k]) * 1e3 for k in ("new", "old"))
            print(
                f"  {det:7s} new {med_new:6.3f}  old {med_old:6.3f}  "
                f"median ratio new/old {statistics.median(ratios):.3f}"
            )


if __name__ == "__main__":
    main()
