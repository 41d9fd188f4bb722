"""A mission's results folder read back: what `swarmraft mission` and `swarmraft launch` wrote
(steps.csv, summary.json, scenario.json), as the MissionLog and error series they came from.

What a folder does not hold comes back empty: the receivers' raw GNSS output and the INS
series (nan), the records each node held, the detector's parameters as used. The error series
are read from steps.csv, not recomputed, so they are exactly the numbers the folder reports.
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from swarmraft.estimation.registry import one_line
from swarmraft.experiments.config import ConfigError
from swarmraft.experiments.mission import MEMBER_COLUMN, STEP_COLUMNS
from swarmraft.sim.mission import MissionLog
from swarmraft.sim.scenario import Scenario

FILES = ("steps.csv", "summary.json", "scenario.json")
_EVENT = re.compile(r"^(-?[0-9.]+) s: (.*)$")


@dataclass(frozen=True)
class MissionFolder:
    path: Path
    log: MissionLog
    errors: dict[str, np.ndarray]  # (S, n) each: gnss, ins_alone, ins_aligned, swarmraft, snapshot_bound
    summary: dict[str, Any]


def is_mission_folder(path: Path) -> bool:
    return all((Path(path) / f).is_file() for f in FILES)


def read_mission(folder: str | Path, option: str = "DIR") -> MissionFolder:
    """The folder's mission, or a one-line ConfigError naming ``option`` and what is wrong."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"{option}: {folder} is not a folder")
    missing = [f for f in FILES if not (folder / f).is_file()]
    if missing:
        raise ConfigError(
            f"{option}: {folder} is not a mission folder (no {', '.join(missing)}; "
            "`swarmraft mission` and `swarmraft launch` write one)"
        )
    name = "summary.json"
    try:
        summary = json.loads((folder / name).read_text())
        name = "scenario.json"
        scenario = Scenario(**json.loads((folder / name).read_text()))
    except (json.JSONDecodeError, ValidationError, TypeError, UnicodeDecodeError) as exc:
        why = one_line(exc, "", Scenario) if isinstance(exc, ValidationError) else str(exc)
        raise ConfigError(f"{option}: {folder / name}: unreadable ({why})") from None
    _check_summary(summary, folder / "summary.json", option)
    with (folder / "steps.csv").open(newline="") as fh:
        reader = csv.DictReader(fh)
        wanted = STEP_COLUMNS + ((MEMBER_COLUMN,) if scenario.dynamic else ())
        absent = [c for c in wanted if c not in (reader.fieldnames or [])]
        if absent:
            raise ConfigError(f"{option}: {folder}/steps.csv lacks columns {', '.join(absent)}")
        rows = list(reader)
    n = scenario.drones
    if not rows or len(rows) % n:
        raise ConfigError(f"{option}: {folder}/steps.csv has {len(rows)} rows, not a multiple of {n} drones")
    S = len(rows) // n

    def col(name: str, kind: type = float) -> np.ndarray:
        if kind is bool:
            return np.array([r[name] == "1" for r in rows], bool).reshape(S, n)
        values = []
        for i, r in enumerate(rows):
            try:
                values.append(kind(r[name]))
            except (TypeError, ValueError):  # a row cut short (None) or text where a number goes
                raise ConfigError(
                    f"{option}: {folder}/steps.csv, row {i + 1}: cut short or not a number in column "
                    f"{name} ({r[name]!r})"
                ) from None
        return np.array(values).reshape(S, n)

    def xyz(prefix: str) -> np.ndarray:
        return np.stack([col(f"{prefix}_{a}") for a in "xyz"], axis=2)

    step = col("step", int)
    drone = col("drone", int)
    if not ((step == np.arange(S)[:, None]).all() and (drone == np.arange(1, n + 1)[None, :]).all()):
        raise ConfigError(f"{option}: {folder}/steps.csv is not one row per step and drone in order")
    nan3 = np.full((S, n, 3), np.nan)
    log = MissionLog(
        scenario=scenario,
        # the simulator's clock (world.motion), not steps.csv's t, which is rounded to 1 ms
        t=np.arange(0.0, scenario.duration_s + 1e-9, scenario.dt_s)[:S],
        truth=xyz("truth"),
        gnss=nan3.copy(),
        honest_gnss=nan3.copy(),
        reported=xyz("reported"),
        ins_alone=nan3.copy(),
        ins_aligned=nan3.copy(),
        spoofed=col("spoofed", bool),
        outage=col("outage", bool),
        alive=col("alive", bool),
        verified=xyz("verified"),
        hpl=col("hpl"),
        vpl=col("vpl"),
        faulty=col("faulty", bool),
        missing=col("missing", bool),
        committed=col("committed", bool)[:, 0],
        status=np.array([r["status"] for r in rows[::n]], dtype=object),
        leader=col("leader", int)[:, 0],
        term=col("term", int)[:, 0],
        latency_ms=col("latency_ms")[:, 0],
        raft_messages=col("raft_messages", int)[:, 0],
        report_messages=col("report_messages", int)[:, 0],
        events=[_event(e) for e in summary.get("events", [])],
        member=col(MEMBER_COLUMN, bool) if MEMBER_COLUMN in rows[0] else None,
        detector_params=dict(summary.get("detector_params", {})),
    )
    errors = {
        "gnss": col("error_gnss"),
        "ins_alone": col("error_ins_alone"),
        "ins_aligned": col("error_ins_aligned"),
        "swarmraft": col("error_swarmraft"),
        "snapshot_bound": col("snapshot_bound"),
    }
    return MissionFolder(folder, log, errors, summary)


#: what every summary.json this version reads has (a report's checks read them: a summary
#: without them would pass its checks on defaults); fields added later are read with .get
SUMMARY_FIELDS = (
    "committed_steps",
    "skipped_steps",
    "steps",
    "records_identical_on_all_nodes",
    "wrong_partition_step_count",
    "honest_false_positive_rate",
    "detections",
    "integrity",
    "events",
)


def _check_summary(summary: object, path: Path, option: str) -> None:
    """A one-line ConfigError unless ``summary`` is an object with `SUMMARY_FIELDS` (and an
    integrity object with its misleading count)."""
    if not isinstance(summary, dict):
        raise ConfigError(f"{option}: {path}: not a JSON object (a mission's summary is one)")
    lacks = [k for k in SUMMARY_FIELDS if k not in summary]
    integrity = summary.get("integrity")
    if "integrity" in summary and not (isinstance(integrity, dict) and "misleading_drone_steps" in integrity):
        lacks.append("integrity.misleading_drone_steps")
    if lacks:
        raise ConfigError(
            f"{option}: {path} lacks {', '.join(lacks)}: not a summary swarmraft wrote, or cut "
            "(run the mission again)"
        )


def _event(text: str) -> tuple[float, str]:
    m = _EVENT.match(text)
    return (float(m.group(1)), m.group(2)) if m else (float("nan"), text)
