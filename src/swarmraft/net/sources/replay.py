"""Recorded sensor logs (docs/records.md): reading one (`read_sensor_log`, every error one
line naming the file, the line and the field), writing one (`write_sensor_log`), recording a
scenario's sensors into one (`record_world`), and replaying one as a drone's `SensorSource`
(`ReplaySource`).

A log is a CSV file, one line per drone per time stamp: ``t_s`` (seconds from step 0),
``drone`` (id 1..n), the GNSS fix ``gnss_x, gnss_y, gnss_z`` (all three empty: no fix), the
INS's dead-reckoned position ``ins_x, ins_y, ins_z`` (aligned once at the start, never
realigned: the replay uses its increments), optionally the navigation filter's innovation
``innov_x, innov_y, innov_z`` (empty: none), and ``range_1 .. range_n`` (empty: not measured).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarmraft.net.sources import Reading
from swarmraft.sim.sensing import ScenarioWorld

XYZ = ("x", "y", "z")
GNSS = tuple(f"gnss_{a}" for a in XYZ)
INS = tuple(f"ins_{a}" for a in XYZ)
INNOV = tuple(f"innov_{a}" for a in XYZ)
#: a row is held from its time stamp on; this much slack absorbs decimal time stamps
TIME_TOLERANCE_S = 1e-6


class SensorLogError(ValueError):
    """A sensor log that cannot be replayed; one line: ``file:line: field: problem``."""


@dataclass(frozen=True)
class SensorLog:
    """A log's R lines in file order, for n drones (indexes 0..n-1)."""

    t_s: np.ndarray  # (R,) s from step 0, non-decreasing
    drone: np.ndarray  # (R,) int: drone index (id - 1)
    gnss: np.ndarray  # (R, 3) m, nan rows: no fix
    ins: np.ndarray  # (R, 3) m, the INS's dead reckoning from its start
    innovation: np.ndarray | None  # (R, 3) m, nan rows: none; None: the log has no innovation columns
    ranges: np.ndarray  # (R, n) m, nan: not measured
    line: np.ndarray  # (R,) int: the line each row came from (1 is the header)

    @property
    def drones(self) -> int:
        return self.ranges.shape[1]

    def columns(self) -> list[str]:
        inn = list(INNOV) if self.innovation is not None else []
        return ["t_s", "drone", *GNSS, *INS, *inn, *(f"range_{j}" for j in range(1, self.drones + 1))]


def _number(text: str, where: str, field: str, *, empty_ok: bool, nan_ok: bool = False) -> float:
    text = text.strip()
    if not text:
        if empty_ok:
            return math.nan
        raise SensorLogError(f"{where}: {field}: empty; a number is required")
    try:
        v = float(text)
    except ValueError:
        raise SensorLogError(f"{where}: {field}: {text!r} is not a number") from None
    if math.isnan(v) and not nan_ok:
        hint = " (leave it empty where there is none)" if empty_ok else ""
        raise SensorLogError(f"{where}: {field}: nan is not allowed{hint}")
    if math.isinf(v):
        raise SensorLogError(f"{where}: {field}: {text} is not finite")
    return v


def _triple(cells: dict[str, str], names: tuple[str, ...], where: str, *, optional: bool) -> list[float]:
    """Three coordinates: all given, or (``optional``) all empty (nan)."""
    given = [bool(cells[c].strip()) for c in names]
    if optional and not any(given):
        return [math.nan] * 3
    if optional and not all(given):
        missing = names[given.index(False)]
        raise SensorLogError(
            f"{where}: {missing}: empty while {names[given.index(True)]} is given "
            f"(leave all of {', '.join(names)} empty for none)"
        )
    return [_number(cells[c], where, c, empty_ok=False) for c in names]


def read_sensor_log(path: str | Path, drones: int | None = None) -> SensorLog:
    """The log at ``path``, checked whole; ``drones`` (n), when given, must match its range
    columns. Any problem raises SensorLogError: ``path:line: field: what is wrong``."""
    path = Path(path)
    try:
        f = path.open(newline="")
    except OSError as exc:
        raise SensorLogError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    with f:
        try:
            return _parse(csv.reader(f), path, drones)
        except UnicodeDecodeError:
            raise SensorLogError(f"{path}: not a text file (UTF-8)") from None
        except csv.Error as exc:
            raise SensorLogError(f"{path}: not CSV ({exc})") from None


def _parse(reader, path: Path, drones: int | None) -> SensorLog:  # noqa: ANN001 (a csv reader)
    header = next(reader, None)
    if header is None:
        raise SensorLogError(f"{path}:1: header: the file is empty")
    header = [h.strip() for h in header]
    at = f"{path}:1: header"
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise SensorLogError(f"{at}: column {dup!r} appears twice")
    range_cols = [h for h in header if h.startswith("range_")]
    n = len(range_cols)
    want_ranges = [f"range_{j}" for j in range(1, n + 1)]
    if n == 0 or sorted(range_cols, key=lambda c: (len(c), c)) != want_ranges:
        raise SensorLogError(
            f"{at}: range columns must be range_1 .. range_n, got {', '.join(range_cols) or 'none'}"
        )
    if drones is not None and n != drones:
        raise SensorLogError(
            f"{at}: {n} range columns (range_1 .. range_{n}); the scenario has {drones} drones"
        )
    has_innov = any(h in INNOV for h in header)
    required = ["t_s", "drone", *GNSS, *INS, *(INNOV if has_innov else ())]
    for c in required:
        if c not in header:
            raise SensorLogError(f"{at}: no column {c!r} (docs/records.md lists the columns)")
    if unknown := [h for h in header if h not in required and h not in want_ranges]:
        raise SensorLogError(f"{at}: unknown column {unknown[0]!r} (docs/records.md lists the columns)")
    t_s, drone, gnss, ins, innov, ranges, lines = [], [], [], [], [], [], []
    last_t, last_line = -math.inf, 0
    seen_at: dict[tuple[int, float], int] = {}
    for fields in reader:
        line = reader.line_num
        where = f"{path}:{line}"
        if not fields or all(not x.strip() for x in fields):
            continue
        if len(fields) != len(header):
            raise SensorLogError(f"{where}: {len(fields)} fields; the header has {len(header)}")
        cells = dict(zip(header, fields, strict=True))
        t = _number(cells["t_s"], where, "t_s", empty_ok=False)
        if t < 0:
            raise SensorLogError(f"{where}: t_s: {t:g} is negative (seconds from step 0)")
        if t < last_t:
            raise SensorLogError(
                f"{where}: t_s: {t:g} is before line {last_line}'s {last_t:g} (the log must be in time order)"
            )
        text = cells["drone"].strip()
        if not text.isdigit() or not 1 <= int(text) <= n:
            raise SensorLogError(f"{where}: drone: no drone {text!r} (the range columns name drones 1..{n})")
        d = int(text)
        if (d, t) in seen_at:
            raise SensorLogError(
                f"{where}: t_s: drone {d} has a line at {t:g} s already (line {seen_at[d, t]})"
            )
        seen_at[d, t] = line
        gnss.append(_triple(cells, GNSS, where, optional=True))
        ins.append(_triple(cells, INS, where, optional=False))
        if has_innov:
            innov.append(_triple(cells, INNOV, where, optional=True))
        row = []
        for c in want_ranges:
            r = _number(cells[c], where, c, empty_ok=True, nan_ok=True)
            if r < 0:
                raise SensorLogError(f"{where}: {c}: {r:g} is negative")
            row.append(r)
        ranges.append(row)
        t_s.append(t)
        drone.append(d - 1)
        lines.append(line)
        last_t, last_line = t, line
    if not t_s:
        raise SensorLogError(f"{path}:2: the log has a header and no lines")
    return SensorLog(
        np.array(t_s),
        np.array(drone, int),
        np.array(gnss, float).reshape(-1, 3),
        np.array(ins, float).reshape(-1, 3),
        np.array(innov, float).reshape(-1, 3) if has_innov else None,
        np.array(ranges, float).reshape(-1, n),
        np.array(lines, int),
    )


def _cell(v: float) -> str:
    return repr(float(v)) if math.isfinite(v) else ""


def write_sensor_log(path: str | Path, log: SensorLog) -> None:
    """``log`` as a CSV file at ``path``; each number in its shortest form that reads back to
    the same float, so a replay sees exactly the recorded values."""
    with Path(path).open("w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(log.columns())
        for r in range(len(log.t_s)):
            row = [repr(float(log.t_s[r])), str(int(log.drone[r]) + 1)]
            row += [_cell(v) for v in log.gnss[r]] + [_cell(v) for v in log.ins[r]]
            if log.innovation is not None:
                row += [_cell(v) for v in log.innovation[r]]
            row += [_cell(v) for v in log.ranges[r]]
            w.writerow(row)


def record_world(world: ScenarioWorld, seconds: float | None = None) -> SensorLog:
    """What every drone's sensors give in the scenario, step by step (the first ``seconds``
    s, or all): its receiver's fix (spoofed where spoofed; none in an outage), its INS's dead
    reckoning from its alignment at the true start position (never realigned), the world's
    innovation, and its row of ranges (a tampering drone's as tampered, against the positions
    the drones show: their fixes, or their INS dead reckoning without one)."""
    sc = world.sc
    n = sc.drones
    steps = sc.steps if seconds is None else min(sc.steps, int(math.floor(seconds / sc.dt_s + 1e-9)))
    S = steps + 1
    t_s, gnss, ins, innov, ranges = [], [], [], [], []
    start_t, start_pos = np.zeros(n), world.traj.positions[0]
    for k in range(S):
        dead = world.ins_estimate(k, start_t, start_pos)
        rows = world.measured_ranges(k, dead)
        t_s.append(np.full(n, round(k * sc.dt_s, 9)))
        gnss.append(world.gnss_output(k))
        ins.append(dead)
        innov.append([_or_nan(world.innovation(k, i)) for i in range(n)])
        ranges.append(rows)
    return SensorLog(
        np.concatenate(t_s),
        np.tile(np.arange(n), S),
        np.concatenate(gnss),
        np.concatenate(ins),
        np.array(innov, float).reshape(-1, 3),
        np.concatenate(ranges),
        np.arange(2, 2 + S * n),
    )


def _or_nan(v: np.ndarray | None) -> np.ndarray:
    return np.full(3, np.nan) if v is None else np.asarray(v, float)


class ReplaySource:
    """Drone ``index``'s readings from a recorded log. Step k (at ``k * dt_s`` s) uses the
    drone's last line at or before that time, if it is at most ``max_age_s`` old (else no
    reading): its fix (or, without one, its INS estimate), its ranges, and its innovation: the
    log's, or without innovation columns the fix's change over the last ``window_s`` less the
    INS's; with ``windows``, the innovations of the lines held at the end of each of the last
    ``windows`` windows (the drag-off test's input). Its INS estimate is the log's dead
    reckoning until the first realignment, then the verified position plus the log's INS
    increments since."""

    def __init__(
        self,
        log: SensorLog,
        index: int,
        dt_s: float,
        window_s: float,
        max_age_s: float = 1.0,
        windows: int = 0,
    ):
        mine = log.drone == index
        self.t_s, self.gnss, self.ins = log.t_s[mine], log.gnss[mine], log.ins[mine]
        self.innov = None if log.innovation is None else log.innovation[mine]
        self.ranges = log.ranges[mine]
        self.dt_s, self.window_s, self.max_age_s = dt_s, window_s, max_age_s
        self.windows = windows  # past windows a report carries (`Report.drift`); 0: none
        self._base: tuple[np.ndarray, np.ndarray] | None = None  # (INS then, verified position)

    def _row(self, t: float) -> int:
        """The last row at or before ``t`` s; -1 if none."""
        return int(np.searchsorted(self.t_s, t + TIME_TOLERANCE_S, side="right")) - 1

    def _ins(self, j: int) -> np.ndarray:
        if self._base is None:
            return self.ins[j].copy()
        then, pos = self._base
        return pos + (self.ins[j] - then)

    def reading(self, k: int) -> Reading | None:
        t = k * self.dt_s
        j = self._row(t)
        if j < 0 or t - self.t_s[j] > self.max_age_s + TIME_TOLERANCE_S:
            return None
        ins = self._ins(j)
        fix = self.gnss[j]
        if not np.isfinite(fix).all():
            return Reading(ins, "ins", self.ranges[j].copy(), None, ins)
        return Reading(fix.copy(), "gnss", self.ranges[j].copy(), self._innovation(j, t), ins, self._drift(t))

    def _drift(self, t: float) -> np.ndarray | None:
        """The innovations of the last ``windows`` windows, newest first (nan: none then), as
        the innovation of the line held at the end of each."""
        if not self.windows:
            return None
        rows = []
        for m in range(self.windows):
            tm = t - m * self.window_s
            j = self._row(tm)
            v = None if j < 0 or not np.isfinite(self.gnss[j]).all() else self._innovation(j, tm)
            rows.append(np.full(3, np.nan) if v is None else v)
        return np.array(rows)

    def _innovation(self, j: int, t: float) -> np.ndarray | None:
        if self.innov is not None:
            v = self.innov[j]
            return v.copy() if np.isfinite(v).all() else None
        j0 = self._row(t - self.window_s)
        if j0 < 0 or j0 == j or not np.isfinite(self.gnss[j0]).all():
            return None
        return (self.gnss[j] - self.gnss[j0]) - (self.ins[j] - self.ins[j0])

    def realign(self, k: int, position: np.ndarray) -> None:
        j = self._row(k * self.dt_s)
        if j >= 0:
            self._base = (self.ins[j].copy(), np.asarray(position, float).copy())

    def close(self) -> None:
        pass
