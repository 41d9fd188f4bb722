"""One snapshot a user brings, read from a JSON or CSV file (`swarmraft verify`).

JSON: ``{"reported": [[x, y, z], ...], "ranges": [[...], ...], "gnss_sigma": [h, v],
"range_sigma": s}``, with ``null`` for a range not measured; optional ``"gnss_common"``,
``"prior"`` (rows of null for none) and ``"prior_sigma"``. CSV: one row per drone, columns
``x, y, z`` and ``r0 .. r{n-1}`` (drone i's measured distance to drone j; empty for none);
the noise model then comes from the command's options. Metres, a local ENU frame
(docs/files.md). Anything else is a `SnapshotFileError` naming the file and what is wrong.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from swarmraft.estimation import Snapshot


class SnapshotFileError(ValueError):
    """A snapshot file that cannot be read; the message names the file."""


def _number(value: Any, where: str) -> float:
    if value is None or value == "":
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        raise SnapshotFileError(f"{where}: {value!r} is not a number") from None


def _json_snapshot(path: Path, doc: Any) -> dict[str, Any]:
    if not isinstance(doc, dict):
        raise SnapshotFileError(f"{path}: expected a JSON object with 'reported' and 'ranges'")
    missing = [k for k in ("reported", "ranges") if k not in doc]
    if missing:
        raise SnapshotFileError(f"{path}: no '{missing[0]}'")
    known = {"reported", "ranges", "gnss_sigma", "range_sigma", "gnss_common", "prior", "prior_sigma"}
    if unknown := sorted(set(doc) - known):
        raise SnapshotFileError(f"{path}: unknown key '{unknown[0]}' (known: {', '.join(sorted(known))})")

    def table(key: str) -> np.ndarray:
        rows = doc[key]
        if not isinstance(rows, list) or not rows or not all(isinstance(r, list) for r in rows):
            raise SnapshotFileError(f"{path}: '{key}' must be a non-empty list of rows")
        width = {len(r) for r in rows}
        if len(width) > 1:
            raise SnapshotFileError(f"{path}: '{key}' rows have different lengths {sorted(width)}")
        return np.array(
            [[_number(v, f"{path}: {key}[{i}][{j}]") for j, v in enumerate(r)] for i, r in enumerate(rows)]
        ).reshape(len(rows), -1)

    out: dict[str, Any] = {"reported": table("reported"), "ranges": table("ranges")}
    if "prior" in doc:
        out["prior"] = table("prior")
    for key in ("gnss_sigma", "gnss_common"):
        if doc.get(key) is not None:
            v = doc[key]
            if not isinstance(v, list) or len(v) != 2:
                raise SnapshotFileError(f"{path}: '{key}' must be [horizontal, vertical]")
            out[key] = tuple(_number(x, f"{path}: {key}") for x in v)
    for key in ("range_sigma", "prior_sigma"):
        if doc.get(key) is not None:
            out[key] = _number(doc[key], f"{path}: {key}")
    return out


def _csv_snapshot(path: Path, text: str) -> dict[str, Any]:
    lines = list(csv.reader(text.splitlines()))
    # a row of another length than the header: DictReader filled a short one with None (a
    # missing range read as unmeasured) and keyed a long one's extra values by None
    for i, row in enumerate(lines[1:], start=2):
        if row and len(row) != len(lines[0]):
            width = len(lines[0])
            raise SnapshotFileError(f"{path}, line {i}: {len(row)} values where the header has {width}")
    rows = list(csv.DictReader(text.splitlines()))
    if not rows:
        raise SnapshotFileError(
            f"{path}: no drones (expected a header x,y,z,r0,...,r<n-1> and a row per drone)"
        )
    n = len(rows)
    need = ["x", "y", "z", *(f"r{j}" for j in range(n))]
    header = list(rows[0].keys())
    if missing := [c for c in need if c not in header]:
        raise SnapshotFileError(
            f"{path}: {n} drones, but no column {missing[0]} (need x, y, z, r0..r{n - 1})"
        )
    if extra := [c for c in header if c not in need]:
        raise SnapshotFileError(f"{path}: unknown column {extra[0]!r} (need x, y, z, r0..r{n - 1})")
    rep = np.array([[_number(r[c], f"{path}, line {i + 2}, {c}") for c in "xyz"] for i, r in enumerate(rows)])
    rng = np.array(
        [[_number(r[f"r{j}"], f"{path}, line {i + 2}, r{j}") for j in range(n)] for i, r in enumerate(rows)]
    )
    return {"reported": rep, "ranges": rng}


def read_snapshot(path: str | Path, **noise: Any) -> Snapshot:
    """The snapshot in ``path`` (.json or .csv); ``noise`` (gnss_sigma, range_sigma, ...) fills
    what the file does not give (a JSON file's own values win)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SnapshotFileError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SnapshotFileError(f"{path}: cannot read it ({exc})") from None
    if path.suffix.lower() == ".json":
        try:
            fields = _json_snapshot(path, json.loads(text))
        except json.JSONDecodeError as exc:
            raise SnapshotFileError(f"{path}: not valid JSON ({exc})") from None
    elif path.suffix.lower() == ".csv":
        fields = _csv_snapshot(path, text)
    else:
        raise SnapshotFileError(f"{path}: expected a .json or .csv file")
    given = {k: v for k, v in noise.items() if v is not None}
    try:
        return Snapshot(**{**given, **fields})
    except ValueError as exc:
        raise SnapshotFileError(f"{path}: {str(exc).splitlines()[0]}") from None
