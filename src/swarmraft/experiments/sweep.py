"""Monte Carlo sweeps over (n, f): tasks, resumable output folder, tables.

Output folder layout:

- ``run.json``: config, seed, package version, detector parameters and calibration per n;
- ``cells/n{n}_f{f}.csv``: one cell's trials, written when the cell completes (resume skips
  cells whose file exists);
- ``trials.csv``: every trial, one row each; ``cells.csv``: one row per (n, f).
"""

from __future__ import annotations

import json
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarmraft import __version__
from swarmraft.estimation.trust_region import warm_up
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.config import ConfigError, SweepConfig
from swarmraft.experiments.executors import make_executor
from swarmraft.experiments.metrics import CELL_COLUMNS, summarize_cell
from swarmraft.experiments.tables import read_table, write_columns, write_rows
from swarmraft.experiments.trials import TRIAL_COLUMNS, run_chunk

ProgressFn = Callable[[int], None]


@dataclass(frozen=True)
class SweepResult:
    out: Path
    cells: dict[str, np.ndarray]
    computed: list[tuple[int, int]]
    reused: list[tuple[int, int]]
    seconds: float
    executor: str

    @property
    def paths(self) -> list[Path]:
        return [self.out / "cells.csv", self.out / "trials.csv", self.out / "run.json"]


def cell_path(out: Path, n: int, f: int) -> Path:
    return out / "cells" / f"n{n}_f{f}.csv"


def chunks(config: SweepConfig) -> list[tuple[int, int]]:
    """(chunk index, trials) covering ``config.trials`` in blocks of ``chunk_size``."""
    full, rest = divmod(config.trials, config.chunk_size)
    out = [(i, config.chunk_size) for i in range(full)]
    return out + ([(full, rest)] if rest else [])


def _load_run(out: Path, config: SweepConfig) -> dict[str, Any] | None:
    path = out / "run.json"
    if not path.exists():
        return None
    try:
        run = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: unreadable ({exc}); remove it or use another --out") from None
    old = run.get("config", {})
    new = config.model_dump(mode="json")
    diff = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
    if diff:
        raise ConfigError(
            f"--out {out} holds a sweep with a different config ({', '.join(diff)} differ); "
            "use another --out to keep both"
        )
    return run


def _write_run(out: Path, config: SweepConfig, settings: dict, extra: dict) -> None:
    run = {
        "config": config.model_dump(mode="json"),
        "seed": config.seed,
        "version": __version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "detector_params": {str(n): p for n, (p, _) in settings.items()},
        "calibration": {str(n): c for n, (_, c) in settings.items() if c},
        **extra,
    }
    tmp = out / "run.json.tmp"
    tmp.write_text(json.dumps(run, indent=2, sort_keys=True) + "\n")
    tmp.replace(out / "run.json")


def run_sweep(
    config: SweepConfig,
    out: Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], ProgressFn] | None = None,
) -> SweepResult:
    """Run (or resume) a sweep into ``out``. ``progress(total_trials, cells)`` may return a
    callback that is told how many trials just finished."""
    start = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    previous = _load_run(out, config)
    cells = config.cells()
    done = [c for c in cells if cell_path(out, *c).exists()]
    todo = [c for c in cells if c not in done]

    settings: dict[int, tuple[dict, dict]] = {}
    if previous:
        for n_str, p in previous.get("detector_params", {}).items():
            settings[int(n_str)] = (p, previous.get("calibration", {}).get(n_str, {}))
    for n in sorted({n for n, _ in cells} - set(settings)):
        settings[n] = detector_settings(config, n)
    _write_run(out, config, settings, {"complete": False})

    plan = chunks(config)
    tasks = [
        ((n, f, ci), run_chunk, (config, n, f, ci, size, settings[n][0]))
        for n, f in todo
        for ci, size in plan
    ]
    tick = progress(len(tasks) and config.trials * len(todo), len(todo)) if progress else None
    pending: dict[tuple[int, int], dict[int, dict]] = {c: {} for c in todo}
    executor_name = "none (all cells reused)"
    if tasks:
        warm_up()
        with make_executor(workers, scheduler) as ex:
            executor_name = ex.name
            for (n, f, ci), result in ex.run(tasks):
                pending[(n, f)][ci] = result
                if tick:
                    tick(len(result["trial"]))
                if len(pending[(n, f)]) == len(plan):
                    got = pending.pop((n, f))
                    parts = [got[i] for i, _ in plan]
                    merged = {k: np.concatenate([p[k] for p in parts]) for k in TRIAL_COLUMNS}
                    write_columns(cell_path(out, n, f), merged, TRIAL_COLUMNS)

    labels = {"preset": config.preset, "detector": config.detector, "attack": config.attack.name}
    all_trials: list[dict[str, np.ndarray]] = []
    rows = []
    for n, f in cells:
        t = read_table(cell_path(out, n, f))
        all_trials.append(t)
        rows.append(summarize_cell(t, labels))
    merged = {k: np.concatenate([t[k] for t in all_trials]) for k in TRIAL_COLUMNS}
    write_columns(out / "trials.csv", merged, TRIAL_COLUMNS)
    write_rows(out / "cells.csv", CELL_COLUMNS, rows)
    seconds = time.perf_counter() - start
    _write_run(
        out,
        config,
        settings,
        {"complete": True, "executor": executor_name, "wall_seconds": round(seconds, 3)},
    )
    return SweepResult(
        out=out,
        cells=read_table(out / "cells.csv"),
        computed=todo,
        reused=done,
        seconds=seconds,
        executor=executor_name,
    )
