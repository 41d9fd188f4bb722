"""Several detectors on identical trials: the draws depend only on (seed, n, f, chunk), so
sweeps that differ only in the detector see exactly the same snapshots."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from swarmraft.estimation import get_detector
from swarmraft.experiments.config import SweepConfig
from swarmraft.experiments.metrics import CELL_COLUMNS
from swarmraft.experiments.sweep import SweepResult, run_sweep
from swarmraft.experiments.tables import write_rows

#: metric column -> (label, log axis, reference line)
COMPARE_METRICS = {
    "recovered_mean": ("mean error of attacked drones, m", True, None),
    "honest_mean": ("mean error of honest drones, m", True, None),
    "attacked_efficiency": ("efficiency, attacked drones (1 = Cramér-Rao bound)", True, 1.0),
    "detection_rate": ("detection rate", False, None),
    "false_positive_rate": ("false-positive rate", False, None),
    "identification_rate": ("exact identification rate", False, None),
}


def run_compare(
    config: SweepConfig,
    detectors: Sequence[str],
    attacks: Sequence[str],
    out: Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable | None = None,
) -> tuple[dict[str, np.ndarray], list[SweepResult]]:
    """One sweep per (attack, detector) into ``out/<attack>/<detector>``; returns the merged
    cells table (also written to ``out/compare.csv``) and the sweep results."""
    for d in detectors:
        get_detector(d)  # unknown names fail before any work
    out = Path(out)
    results = []
    rows: list[dict] = []
    for attack in attacks:
        for det in detectors:
            cfg = config.model_copy(
                update={"detector": det, "attack": config.attack.model_copy(update={"name": attack})}
            )
            cfg = SweepConfig(**cfg.model_dump())  # re-validate
            labelled = None
            if progress is not None:

                def labelled(total: int, cells: int, name: str = f"{attack}, {det}") -> Callable:
                    return progress(total, cells, name)

            res = run_sweep(cfg, out / attack / det, workers=workers, scheduler=scheduler, progress=labelled)
            results.append(res)
            rows += [{c: res.cells[c][i] for c in CELL_COLUMNS} for i in range(len(res.cells["n"]))]
    write_rows(out / "compare.csv", CELL_COLUMNS, rows)
    table = {c: np.array([r[c] for r in rows]) for c in CELL_COLUMNS}
    return table, results
