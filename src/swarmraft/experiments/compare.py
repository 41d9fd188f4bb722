"""Several detectors on identical trials: the draws depend only on (seed, n, f, chunk), so
sweeps that differ only in the detector see exactly the same snapshots."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from swarmraft.estimation import get_detector
from swarmraft.estimation.registry import one_line
from swarmraft.experiments.config import ConfigError, SweepConfig
from swarmraft.experiments.metrics import CELL_COLUMNS, efficiency_interval, sem
from swarmraft.experiments.sweep import CELL_TEXT_COLUMNS, SweepResult, read_run, run_sweep
from swarmraft.experiments.tables import TableError, read_table, write_rows

#: standard errors of the compared metrics that cells.csv does not hold, computed per cell
#: from the sweep's trials.csv (recovered_sem is in cells.csv already), and the efficiency's
#: 95 % bootstrap interval (`metrics.efficiency_interval`: a ratio of heavy-tailed means has
#: no symmetric interval worth drawing)
SEM_COLUMNS = (
    "honest_sem",
    "detection_rate_sem",
    "false_positive_rate_sem",
    "identification_rate_sem",
    "attacked_efficiency_lo",
    "attacked_efficiency_hi",
)


def cell_sems(trials: dict[str, np.ndarray], n: int, f: int, seed: int) -> dict[str, float]:
    """SEM_COLUMNS for one (n, f) cell of a trials table; the efficiency's interval from
    the bootstrap generator seeded by (``seed``, n, f), so the same trials give the same
    interval."""
    sel = (np.asarray(trials["n"]) == n) & (np.asarray(trials["f"]) == f)

    def col(name: str) -> np.ndarray:
        return np.asarray(trials[name], float)[sel]

    rng = np.random.default_rng([seed, n, f])
    lo, hi = efficiency_interval(col("attacked_sq"), col("attacked_bound"), rng)
    return {
        "honest_sem": sem(col("honest")),
        "detection_rate_sem": sem(col("detection_rate")),
        "false_positive_rate_sem": sem(col("false_positive_rate")),
        "identification_rate_sem": sem(col("identified")),
        "attacked_efficiency_lo": lo,
        "attacked_efficiency_hi": hi,
    }


#: metric column -> (label, log axis allowed, reference line)
COMPARE_METRICS = {
    "recovered_mean": ("mean error of attacked drones, m", True, None),
    "honest_mean": ("mean error of honest drones, m", True, None),
    "attacked_efficiency": ("efficiency, attacked drones (1 = Cramér-Rao bound)", True, 1.0),
    "detection_rate": ("detection rate", False, None),
    "false_positive_rate": ("false-positive rate", False, None),
    "identification_rate": ("exact identification rate", False, None),
}


def check_out(out: Path) -> None:
    """A ConfigError unless ``out`` is new or a comparison's folder (`require_own`)."""
    from swarmraft.experiments.results_folder import require_own

    require_own(out, "compare", "a comparison")


def listed(out: Path) -> list[str]:
    """The sweeps ('attack/detector') an existing OUT/compare.csv lists, in its order; none if
    it is missing or unreadable."""
    try:
        t = read_table(Path(out) / "compare.csv", ("attack", "detector"), ("attack", "detector"))
    except TableError:
        return []
    return list(dict.fromkeys(f"{a}/{d}" for a, d in zip(t["attack"], t["detector"], strict=True)))


def for_detector(config: SweepConfig, detector: str, attack: str | None = None) -> SweepConfig:
    """``config`` for one detector (and attack) of a comparison, validated again: a
    ConfigError naming the field where that detector does not take its parameters."""
    update: dict = {"detector": detector}
    if attack is not None:
        update["attack"] = config.attack.model_copy(update={"name": attack})
    try:
        return SweepConfig(**config.model_copy(update=update).model_dump())
    except ValidationError as exc:
        raise ConfigError(one_line(exc, "", SweepConfig)) from None


def check_detectors(config: SweepConfig, detectors: Sequence[str]) -> None:
    """Before any work: every detector is registered and takes the config's parameters."""
    for d in detectors:
        get_detector(d)
        for_detector(config, d)


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
    cells table with the standard errors of SEM_COLUMNS (also written to
    ``out/compare.csv``) and the sweep results."""
    check_detectors(config, detectors)
    out = Path(out)
    check_out(out)
    results = []
    rows: list[dict] = []
    for attack in attacks:
        for det in detectors:
            cfg = for_detector(config, det, attack)
            labelled = None
            if progress is not None:

                def labelled(total: int, cells: int, name: str = f"{attack}, {det}") -> Callable:
                    return progress(total, cells, name)

            res = run_sweep(cfg, out / attack / det, workers=workers, scheduler=scheduler, progress=labelled)
            results.append(res)
            trials = read_table(res.out / "trials.csv")
            for i in range(len(res.cells["n"])):
                row = {c: res.cells[c][i] for c in CELL_COLUMNS}
                rows.append({**row, **cell_sems(trials, int(row["n"]), int(row["f"]), cfg.seed)})
    columns = (*CELL_COLUMNS, *SEM_COLUMNS)
    write_rows(out / "compare.csv", columns, rows)
    table = {c: np.array([r[c] for r in rows]) for c in columns}
    return table, results


def read_compare(folder: Path) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """A comparison's folder read back: compare.csv's columns, and the run.json of each sweep
    it ran, keyed by its folder ``attack/detector``; a missing or corrupt file is a one-line
    error naming it."""
    folder = Path(folder)
    table = read_table(folder / "compare.csv", (*CELL_COLUMNS, *SEM_COLUMNS), CELL_TEXT_COLUMNS)
    if not len(table["n"]):
        raise ConfigError(f"{folder / 'compare.csv'}: no row in it")
    runs = {}
    for attack, det in dict.fromkeys(zip(table["attack"], table["detector"], strict=True)):
        runs[f"{attack}/{det}"] = read_run(folder / str(attack) / str(det))
    return table, runs


def compare_figure_names(table: dict[str, np.ndarray]) -> list[str]:
    """The figures `swarmraft compare` draws for this table: one per metric with a value."""
    return [f"{m}.png" for m in COMPARE_METRICS if not np.isnan(np.asarray(table[m], float)).all()]
