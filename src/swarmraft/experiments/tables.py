"""Tidy CSV tables: columns of numpy arrays in, CSV out, and back. Floats are written with
17 significant digits so a table read back is bit-identical to the one written."""

from __future__ import annotations

import csv
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np


def _fmt(v: object) -> str:
    if isinstance(v, bool | np.bool_):
        return "1" if v else "0"
    if isinstance(v, float | np.floating):
        return "nan" if np.isnan(v) else format(float(v), ".17g")
    return str(v)


def write_rows(path: Path, columns: Sequence[str], rows: Iterable[Mapping[str, object]]) -> None:
    """Write rows atomically (temporary file, then rename), so a crash never leaves half a
    table where a finished one is expected."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for row in rows:
            w.writerow([_fmt(row[c]) for c in columns])
    os.replace(tmp, path)


def write_columns(path: Path, data: Mapping[str, np.ndarray], columns: Sequence[str]) -> None:
    length = len(data[columns[0]])
    write_rows(path, columns, ({c: data[c][i] for c in columns} for i in range(length)))


def read_table(path: Path) -> dict[str, np.ndarray]:
    """Columns of a CSV as arrays: numeric where every value parses as a number."""
    with Path(path).open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path}: empty table")
    header, body = rows[0], rows[1:]
    out: dict[str, np.ndarray] = {}
    for i, name in enumerate(header):
        col = [r[i] for r in body]
        try:
            arr = np.array([float(v) for v in col])
            if (
                arr.size
                and np.all(np.isfinite(arr) & (arr == np.round(arr)))
                and not any("." in v or "e" in v.lower() for v in col)
            ):
                arr = arr.astype(int)
            out[name] = arr
        except ValueError:
            out[name] = np.array(col, dtype=object)
    return out
