"""Monte Carlo sweeps over (n, f): tasks, resumable output folder, tables.

Output folder layout:

- ``run.json``: config, seed, package version, detector parameters and calibration per n, and
  ``runs``: one entry per run that computed cells (seed, config hash, executor, start, wall time);
- ``cells/n{n}_f{f}.csv``: one cell's trials, written when the cell completes (resume skips
  cells whose file exists), and ``cells/n{n}_f{f}.json``: the seed, config hash and source
  hash it was made with, so a resume with another seed, config or code is refused even
  without run.json;
- ``trials.csv``: every trial, one row each; ``cells.csv``: one row per (n, f).
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from swarmraft import __version__
from swarmraft.estimation.registry import get_detector, one_line
from swarmraft.estimation.trust_region import warm_up
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.config import PRESETS, ConfigError, SweepConfig, attack_plugin
from swarmraft.experiments.executors import check_executor, make_executor
from swarmraft.experiments.metrics import (
    CELL_COLUMNS,
    CELL_COUNTS,
    CELL_FINITE,
    CELL_SHARES,
    summarize_cell,
)
from swarmraft.experiments.tables import read_table, write_columns, write_json, write_rows
from swarmraft.experiments.trials import TRIAL_COLUMNS, run_chunk
from swarmraft.provenance import add_package_sources

ProgressFn = Callable[[int], None]

#: the columns of cells.csv and of trials.csv that hold names, not numbers
CELL_TEXT_COLUMNS = ("preset", "detector", "attack")
TRIAL_TEXT_COLUMNS = ("status",)


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


def config_hash(config: SweepConfig) -> str:
    """sha256 of the config as canonical JSON (seed included): what made a cell."""
    text = json.dumps(config.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


@functools.cache
def code_hash(detector: str | None = None, attack: str | None = None) -> str:
    """sha256 of the package's source files: which code made a cell (a resume with other
    code would mix two versions' numbers in one table). With ``detector`` and ``attack``,
    also the source files of a detector or attack registered from outside the package (a
    plugin or a script's own), whose changes would otherwise pass unseen."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    add_package_sources(h)
    plugin = attack_plugin(attack) if attack else None
    functions = [get_detector(detector).run if detector else None, plugin.make if plugin else None]
    for fn in functions:
        source = inspect.getsourcefile(fn) if fn else None
        if source and not Path(source).resolve().is_relative_to(root):
            h.update(Path(source).read_bytes())
    return h.hexdigest()


def provenance_path(out: Path, n: int, f: int) -> Path:
    """``cells/n{n}_f{f}.json``: the seed and config hash a finished cell was made with."""
    return cell_path(out, n, f).with_suffix(".json")


def check_out_folder(out: Path, flag: str = "--out") -> Path:
    """``out`` if it can be a results folder: not empty, not a file, no file on its way."""
    if str(out) in ("", "."):
        raise ConfigError(f"{flag}: give a folder name (an empty path would write into the current folder)")
    for p in (out, *out.parents):
        if p.exists():
            if not p.is_dir():
                raise ConfigError(f"{flag}: {p} is a file, not a folder")
            break
    return out


def read_run(folder: Path) -> dict[str, Any]:
    """A results folder's run.json; missing or corrupt is a one-line ConfigError naming it."""
    path = Path(folder) / "run.json"
    try:
        run = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: missing (every sweep writes one)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc}); no sweep can resume this folder") from None
    if not isinstance(run, dict) or not isinstance(run.get("config"), dict):
        raise ConfigError(f"{path}: no 'config' object; not a run.json this program wrote")
    try:
        SweepConfig(**run["config"])
    except ValidationError as exc:
        raise ConfigError(f"{path}: {one_line(exc, 'config')}") from None
    return run


def load_results(folder: Path) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, Any]]:
    """(cells, trials, run) of a finished results folder, each file validated: a missing,
    truncated or corrupt one is a one-line error naming it. ``trials`` is empty when the
    folder has no trials.csv."""
    folder = Path(folder)
    if not (folder / "cells.csv").exists():
        from swarmraft.experiments.results_folder import folder_kind

        if not folder.is_dir():
            raise ConfigError(f"{folder}: no such folder (so no cells.csv)")
        kind = folder_kind(folder)
        if kind is not None:  # not to be told to sweep into a mission's or comparison's folder
            where = " (its sweeps are in <attack>/<detector>)" if kind == "compare" else ""
            raise ConfigError(f"{folder}: a {kind} folder, not a sweep's (no cells.csv){where}")
        raise ConfigError(f"{folder}: no cells.csv here; run `swarmraft sweep --out {folder}` first")
    run = read_run(folder)
    cells = read_table(folder / "cells.csv", CELL_COLUMNS, CELL_TEXT_COLUMNS)
    if not len(cells["n"]):
        raise ConfigError(f"{folder / 'cells.csv'}: no cell in it")
    config = SweepConfig(**run["config"])
    check_cells(cells, config, folder / "cells.csv")
    path = folder / "trials.csv"
    trials = read_table(path, TRIAL_COLUMNS, TRIAL_TEXT_COLUMNS) if path.exists() else {}
    if trials:
        _check_cell_set(trials, config, path)
        # every cell's trials, each once: a file cut at a row boundary still parses
        for n, f in config.cells():
            ids = trials["trial"][(trials["n"] == n) & (trials["f"] == f)]
            if len(ids) != config.trials or len(set(ids.tolist())) != config.trials:
                raise ConfigError(
                    f"{path}: cell ({n}, {f}) has {len(ids)} rows ({len(set(ids.tolist()))} trials) where "
                    f"run.json's config has {config.trials} trials a cell (a cut or edited file?)"
                )
    return cells, trials, run


def _cells_text(pairs: object) -> str:
    return ", ".join(f"({n}, {f})" for n, f in sorted(set(pairs)))  # type: ignore[call-overload]


def _check_cell_set(table: dict[str, np.ndarray], config: SweepConfig, path: Path) -> None:
    """The table's (n, f) cells are the ones run.json's config lists, or a ConfigError."""
    have = {(int(n), int(f)) for n, f in zip(table["n"], table["f"], strict=True)}
    if have != set(config.cells()):
        raise ConfigError(
            f"{path}: cells {_cells_text(have) or '(none: no row)'} where run.json's config lists "
            f"{_cells_text(config.cells())}"
        )


def _number(v: float) -> str:
    return str(v) if isinstance(v, int | np.integer) else format(float(v), "g")


def _kind(column: str) -> str:
    if column.endswith("_sem"):
        return "a standard error"
    if column in CELL_COUNTS:
        return "a count"
    if column in CELL_SHARES:
        return "a share"
    return "a size, mean or ratio"


def check_cells(cells: dict[str, np.ndarray], config: SweepConfig, path: Path) -> None:
    """What cells.csv says agrees with run.json's config and with what its columns mean:
    preset, detector and attack are the config's, the (n, f) cells are the config's with its
    trials each, and every number is >= 0, finite where it is always defined
    (`metrics.CELL_FINITE`), at most 1 for a share. Anything else is a one-line ConfigError
    naming the file (and the line and column)."""
    labels = {"preset": config.preset, "detector": config.detector, "attack": config.attack.name}
    for k in range(len(cells["n"])):
        at = f"{path}, line {k + 2}, column"
        if (preset := str(cells["preset"][k])) not in PRESETS:
            raise ConfigError(f"{at} preset: unknown preset {preset!r}; known: {', '.join(PRESETS)}")
        for name, want in labels.items():
            if str(cells[name][k]) != want:
                raise ConfigError(
                    f"{at} {name}: {str(cells[name][k])!r} where run.json's config has {want!r}"
                )
        for name in CELL_COLUMNS:
            if name in CELL_TEXT_COLUMNS:
                continue
            v = cells[name][k]
            if not np.isfinite(v):
                if name in CELL_FINITE:
                    raise ConfigError(f"{at} {name}: {_number(v)} where a finite number is required")
                if not np.isnan(v):
                    raise ConfigError(f"{at} {name}: {_number(v)} where a finite number or nan is expected")
                continue
            if v < 0:
                raise ConfigError(f"{at} {name}: {_number(v)} is negative; {_kind(name)} cannot be")
            if name in CELL_SHARES and v > 1:
                raise ConfigError(f"{at} {name}: {_number(v)} is a share above 1")
        if cells["trials"][k] != config.trials:
            raise ConfigError(
                f"{at} trials: {_number(cells['trials'][k])} where run.json's config has {config.trials}"
            )
    _check_cell_set(cells, config, path)


def check_resume(out: Path, config: SweepConfig) -> dict[str, Any] | None:
    """What a folder already holds (its run.json, None if none), checked against ``config``
    before anything is written: run.json (if any) must hold the same config, and every
    finished cell must have been made with it (its provenance file; a cell without one is
    taken on run.json's word, and refused without run.json) and be whole."""
    from swarmraft.experiments.results_folder import require_own

    out = Path(out)
    if not out.exists():
        return None
    require_own(out, "sweep", "a sweep")
    previous = read_run(out) if (out / "run.json").exists() else None
    if previous is not None:
        old = previous["config"]
        new = config.model_dump(mode="json")
        diff = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
        if diff:
            raise ConfigError(
                f"--out {out} holds a sweep with a different config ({', '.join(diff)} differ); "
                "use another --out to keep both"
            )
    want = config_hash(config)
    for n, f in config.cells():
        csv_path = cell_path(out, n, f)
        if not csv_path.exists():
            continue
        meta_path = provenance_path(out, n, f)
        try:
            meta = json.loads(meta_path.read_text())
        except FileNotFoundError:
            if previous is not None:  # a folder from before cells carried provenance
                meta = {"seed": config.seed, "config_sha256": want}
            else:
                raise ConfigError(
                    f"{csv_path}: neither {meta_path.name} nor run.json says what made it; "
                    "remove the cell or use another --out"
                ) from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ConfigError(
                f"{meta_path}: not valid JSON ({exc}); remove the cell or use another --out"
            ) from None
        now = code_hash(config.detector, config.attack.name)
        if meta.get("code_sha256", now) != now:
            raise ConfigError(
                f"--out {out}: {csv_path.name} was made by other code (source "
                f"{str(meta.get('code_sha256'))[:12]}, now {now[:12]}); its numbers would "
                "mix with this version's: use another --out, or remove the cells to recompute"
            )
        if meta.get("config_sha256") != want:
            raise ConfigError(
                f"--out {out}: {csv_path.name} was made with seed {meta.get('seed')} and config "
                f"{str(meta.get('config_sha256'))[:12]}, this run has seed {config.seed} and config "
                f"{want[:12]}; use another --out to keep both"
            )
        t = read_table(csv_path, TRIAL_COLUMNS, TRIAL_TEXT_COLUMNS)
        if len(t["n"]) != config.trials:
            raise ConfigError(
                f"{csv_path}: {len(t['n'])} trials where the config has {config.trials} "
                "(a truncated file); remove it to recompute the cell"
            )
    return previous


def _write_run(out: Path, config: SweepConfig, settings: dict, runs: list, extra: dict) -> None:
    run = {
        "config": config.model_dump(mode="json"),
        "config_sha256": config_hash(config),
        "seed": config.seed,
        "version": __version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "detector_params": {str(n): p for n, (p, _) in settings.items()},
        "calibration": {str(n): c for n, (_, c) in settings.items() if c},
        "runs": runs,
        **extra,
    }
    write_json(out / "run.json", run)


def run_sweep(
    config: SweepConfig,
    out: Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], ProgressFn] | None = None,
) -> SweepResult:
    """Run (or resume) a sweep into ``out``. ``progress(total_trials, cells)`` may return a
    callback that is told how many trials just finished.

    Bad input (an unusable folder, a folder made with another seed or config, a truncated
    cell, a bad executor) raises before anything is written. run.json keeps one entry per run
    that computed cells (seed, config hash, executor, start time, wall time, cells)."""
    start = time.perf_counter()
    started = datetime.now(UTC).isoformat(timespec="seconds")
    out = check_out_folder(Path(out))
    previous = check_resume(out, config)
    check_executor(workers, scheduler)
    cells = config.cells()
    done = [c for c in cells if cell_path(out, *c).exists()]
    todo = [c for c in cells if c not in done]

    settings: dict[int, tuple[dict, dict]] = {}
    if previous:
        for n_str, p in previous.get("detector_params", {}).items():
            settings[int(n_str)] = (p, previous.get("calibration", {}).get(n_str, {}))
    for n in sorted({n for n, _ in cells} - set(settings)):
        settings[n] = detector_settings(config, n)
    runs = list(previous.get("runs", [])) if previous else []

    plan = chunks(config)
    tasks = [
        ((n, f, ci), run_chunk, (config, n, f, ci, size, settings[n][0]))
        for n, f in todo
        for ci, size in plan
    ]
    tick = progress(config.trials * len(todo), len(todo)) if progress and tasks else None  # no bar of 0/0
    pending: dict[tuple[int, int], dict[int, dict]] = {c: {} for c in todo}
    executor_name = "none (all cells reused)"
    meta = {
        "seed": config.seed,
        "config_sha256": config_hash(config),
        "code_sha256": code_hash(config.detector, config.attack.name),
    }
    # this run's entry, listed as its first cell is written and brought up to date with each
    # one after it: an interrupted run keeps the provenance of the cells it finished
    this_run: dict = {
        **meta,
        "executor": executor_name,
        "started": started,
        "wall_seconds": None,
        "cells": [],
    }
    if tasks:
        warm_up()
        with make_executor(workers, scheduler) as ex:
            # written once the executor runs: one that cannot start (an unreachable
            # scheduler) leaves nothing behind
            out.mkdir(parents=True, exist_ok=True)
            _write_run(out, config, settings, runs, {"complete": False})
            executor_name = this_run["executor"] = ex.name
            for (n, f, ci), result in ex.run(tasks):
                pending[(n, f)][ci] = result
                if tick:
                    tick(len(result["trial"]))
                if len(pending[(n, f)]) == len(plan):
                    got = pending.pop((n, f))
                    parts = [got[i] for i, _ in plan]
                    merged = {k: np.concatenate([p[k] for p in parts]) for k in TRIAL_COLUMNS}
                    write_json(provenance_path(out, n, f), {**meta, "n": n, "f": f, "trials": config.trials})
                    write_columns(cell_path(out, n, f), merged, TRIAL_COLUMNS)
                    if not this_run["cells"]:
                        runs.append(this_run)
                    this_run["cells"].append([n, f])
                    this_run["wall_seconds"] = round(time.perf_counter() - start, 3)
                    _write_run(out, config, settings, runs, {"complete": False})

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
    if todo:
        this_run["wall_seconds"] = round(seconds, 3)
        this_run["cells"] = [list(c) for c in todo]  # in the config's order, as before
    _write_run(out, config, settings, runs, {"complete": True})
    return SweepResult(
        out=out,
        cells=read_table(out / "cells.csv"),
        computed=todo,
        reused=done,
        seconds=seconds,
        executor=executor_name,
    )
