"""Tidy CSV tables: columns of numpy arrays in, CSV out, and back. Floats are written with
17 significant digits so a table read back is bit-identical to the one written."""

from __future__ import annotations

import csv
import json
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
    try:
        with tmp.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(columns)
            for row in rows:
                w.writerow([_fmt(row[c]) for c in columns])
    except BaseException:  # an interrupt mid-table: no half-written .tmp left beside it
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)


def write_text(path: Path, text: str) -> None:
    """Write a text file atomically (temporary file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json(path: Path, data: object) -> None:
    """Write JSON atomically (`write_text`), keys sorted."""
    write_text(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def write_columns(path: Path, data: Mapping[str, np.ndarray], columns: Sequence[str]) -> None:
    length = len(data[columns[0]])
    write_rows(path, columns, ({c: data[c][i] for c in columns} for i in range(length)))


class TableError(ValueError):
    """A table that cannot be read as written: one line naming the file, line and column."""


def read_table(path: Path, required: Sequence[str] = (), text: Iterable[str] = ()) -> dict[str, np.ndarray]:
    """Columns of a CSV as arrays: numeric where every value parses as a number.

    ``required`` columns must be present and every one not in ``text`` numeric; a missing
    file, a missing column, a row cut short or a value that is not a number is a one-line
    TableError naming the file (and the line and column)."""
    path = Path(path)
    try:
        with path.open(newline="") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise TableError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise TableError(f"{path}: unreadable ({exc})") from None
    if not rows:
        raise TableError(f"{path}: empty table")
    header, body = rows[0], rows[1:]
    missing = [c for c in required if c not in header]
    if missing and not body and not path.read_bytes().endswith(b"\n"):
        # every table written ends with a newline: one cut inside its header is not another
        # version's (a new-user review: a cut header was called a folder from another version)
        raise TableError(f"{path}: the file ends inside its header (a truncated or corrupt file)")
    if missing:
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        raise TableError(
            f"{path}: not a table this version of swarmraft wrote (no column "
            f"{', '.join(missing[:3])}{more}; a folder from another version: run it again)"
        )
    for k, row in enumerate(body):
        if len(row) != len(header):
            raise TableError(
                f"{path}, line {k + 2}: {len(row)} values where the header has {len(header)} "
                "(a truncated or corrupt file)"
            )
    numeric = set(required) - set(text)
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
            if name in numeric:
                k, v = next((k, v) for k, v in enumerate(col) if not _is_number(v))
                raise TableError(f"{path}, line {k + 2}, column {name}: {v!r} is not a number") from None
            out[name] = np.array(col, dtype=object)
    return out


def _is_number(v: str) -> bool:
    try:
        float(v)
    except ValueError:
        return False
    return True
