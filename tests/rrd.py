"""A rerun recording (.rrd) read back for the tests: each entity's rows on the ``time``
timeline, through rerun's chunk reader (`rerun.chunk.RrdReader`)."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any


def recording_rows(path: Path) -> dict[str, list[tuple[float, dict[str, Any]]]]:
    """entity path -> [(time s, {column: value})] sorted by time; static rows have time nan."""
    from rerun.chunk import RrdReader

    out: dict[str, list[tuple[float, dict[str, Any]]]] = defaultdict(list)
    for chunk in RrdReader(str(path)).stream().collect().stream():
        batch = chunk.to_record_batch()
        names = [name for name in batch.schema.names if ":" in name or name == "time"]
        cols = {name: batch.column(name).to_pylist() for name in names}
        times = cols.get("time", [None] * batch.num_rows)
        for r in range(batch.num_rows):
            t = times[r].total_seconds() if times[r] is not None else float("nan")
            out[chunk.entity_path].append((t, {name: v[r] for name, v in cols.items() if ":" in name}))
    for rows in out.values():
        rows.sort(key=lambda tr: tr[0])
    return dict(out)


def assert_swarm_recorded(path: Path, drones: int, min_move_m: float = 5.0) -> dict:
    """The recording holds every drone (labels 1..n on the verified positions), positions that
    change between its first and last full step (each drone moves more than ``min_move_m``),
    and a leader change (two leaders in the leader series, two "leader: drone N" events).
    The rows, for more checks."""
    import numpy as np

    rows = recording_rows(path)
    labels: set[str] = set()
    for _, r in rows["/swarm/verified"]:
        labels |= {lab.rstrip("*") for lab in r["Points3D:labels"] or []}
    assert labels == {str(i) for i in range(1, drones + 1)}, f"drones in the recording: {sorted(labels)}"
    full = [np.array(r["Points3D:positions"]) for _, r in rows["/swarm/verified"]]
    full = [p for p in full if len(p) == drones]
    assert len(full) >= 2, "fewer than two steps hold every drone"
    moved = np.linalg.norm(full[-1] - full[0], axis=1)
    assert (moved > min_move_m).all(), f"drones that did not move: {np.flatnonzero(moved <= min_move_m) + 1}"
    leaders = {r["Scalars:scalars"][0] for _, r in rows.get("/raft", []) if r.get("Scalars:scalars")}
    assert len(leaders - {0.0}) >= 2, f"leaders in the recording: {sorted(leaders)}"
    told = {
        r["TextLog:text"][0]
        for _, r in rows.get("/events", [])
        if r["TextLog:text"][0].startswith("leader: ")
    }
    assert len(told) >= 2, f"leader changes in the event log: {sorted(told)}"
    return rows
