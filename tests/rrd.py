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
