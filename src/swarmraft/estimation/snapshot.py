"""What the leader sees at one step (`Snapshot`) and what it decides (`Verdict`).

Batches of snapshots with the same swarm size travel as `SnapshotBatch` / `VerdictBatch`:
arrays with a leading trial axis, so sweeps verify thousands of trials in one call.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

# One vocabulary for every detector (README, docs/detectors.md):
#   ok             the final fit passes its own consistency test and the geometry fixes every
#                  position it returns
#   alarm          the data are inconsistent and exclusion is exhausted: do not use
#   unidentifiable two or more trusted sets explain the data equally well
#   degenerate     the geometry does not fix some position, or its protection level is above
#                  the alert limits (that drone: prior or nan)
STATUSES = ("ok", "alarm", "unidentifiable", "degenerate")
SOURCES = ("gnss", "ins", "none")


def _as_float_array(name: str, value: object, shape_hint: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a numeric array {shape_hint}") from exc
    return arr


def _finite_nonnegative(v: object) -> bool:
    try:
        f = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return bool(np.isfinite(f) and f >= 0)


#: The largest coordinate or distance a snapshot or a drone's report may hold, m (10,000 km:
#: nothing of a swarm's local frame). Finite is not enough: a signed report at 1e154 m made
#: every detector's solver overflow and raise, and stopped the leader's steps.
MAX_M = 1e7


def distances_ok(d: np.ndarray) -> bool:
    """Whether every measured distance in ``d`` is a number in [0, MAX_M] (nan: not
    measured): the rule for ranges in a snapshot, a batch and a drone's report. Two
    reductions, so a report's 17 ranges cost microseconds and a batch's 300,000 little more."""
    d = np.asarray(d, float)
    return bool(
        np.fmin.reduce(d, axis=None, initial=0.0) >= 0 and np.fmax.reduce(d, axis=None, initial=0.0) <= MAX_M
    )


def coordinates_ok(x: np.ndarray) -> bool:
    """Whether every value of ``x`` is a number within MAX_M of 0 (nan fails)."""
    return bool(np.all(np.abs(np.asarray(x, float)) <= MAX_M))


def _checked_fields(snap: Snapshot | SnapshotBatch, batch: bool) -> dict[str, Any]:
    """The noise and array fields of a snapshot (``batch``: a batch, each array with a leading
    T axis) as floats and pairs, checked: reported (n, 3) within MAX_M of the origin, n >= 1;
    ranges (n, n) whose off-diagonal entries are nan or a distance in [0, MAX_M]; sigmas
    finite and >= 0; prior (n, 3) within MAX_M or nan rows; prior_sigma finite and > 0. A
    one-line ValueError for the first that fails."""
    lead = "T, " if batch else ""
    rep = _as_float_array("reported", snap.reported, f"({lead}n, 3)")
    if rep.ndim != 2 + batch or rep.shape[-1] != 3 or rep.shape[-2] < 1:
        raise ValueError(f"reported: expected shape ({lead}n, 3) with n >= 1, got {rep.shape}")
    if not coordinates_ok(rep):
        raise ValueError(f"reported: positions must be finite, within {MAX_M:g} m of the origin")
    n = rep.shape[-2]
    rng = _as_float_array("ranges", snap.ranges, f"({lead}n, n)")
    if rng.shape != (*rep.shape[:-1], n):
        raise ValueError(f"ranges: expected shape {(*rep.shape[:-1], n)} to match reported, got {rng.shape}")
    if not distances_ok(rng[..., ~np.eye(n, dtype=bool)]):
        raise ValueError(f"ranges: measured distances must be in [0, {MAX_M:g}] m (nan = unmeasured)")
    out: dict[str, Any] = {"reported": rep, "ranges": rng}
    for name in ("gnss_sigma", "gnss_common"):
        value = getattr(snap, name)
        out[name] = None if value is None else sigma_pair(name, value)
    if snap.range_sigma is not None and not _finite_nonnegative(snap.range_sigma):
        raise ValueError("range_sigma: expected a finite number >= 0, m")
    out["range_sigma"] = snap.range_sigma
    out["prior"] = None
    if snap.prior is not None:
        pr = _as_float_array("prior", snap.prior, f"({lead}n, 3)")
        if pr.shape != rep.shape or np.any(np.abs(pr) > MAX_M):
            raise ValueError(f"prior: expected shape {rep.shape} of values within {MAX_M:g} m or nan rows")
        out["prior"] = pr
    if snap.prior_sigma is not None and not (_finite_nonnegative(snap.prior_sigma) and snap.prior_sigma > 0):
        raise ValueError("prior_sigma: expected a finite number > 0, m")
    out["prior_sigma"] = snap.prior_sigma
    return out


def sigma_pair(name: str, value: object) -> tuple[float, float]:
    """A (horizontal, vertical) pair of sigmas, m; anything else is a one-line ValueError."""
    try:
        pair = tuple(float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected (horizontal, vertical) in m, got {value!r}") from None
    if len(pair) != 2 or not all(np.isfinite(v) and v >= 0 for v in pair):
        raise ValueError(f"{name}: expected (horizontal, vertical), both finite and >= 0, got {value!r}")
    return pair  # type: ignore[return-value]


@dataclass(frozen=True)
class Snapshot:
    """One step's reports.

    reported: (n, 3) reported positions, metres, local ENU.
    ranges: (n, n); ``ranges[i, j]`` is the distance drone i measured to drone j, ``nan`` where
        not measured. The diagonal is ignored.
    gnss_sigma: optional (horizontal, vertical) GNSS sigma per axis, metres.
    gnss_common: optional (horizontal, vertical) sigma of a GNSS error common to all drones.
    range_sigma: optional ranging sigma, metres.
    source: optional (n,) of "gnss", "ins" or "none": where each report came from; checked
        and kept for the caller, read by no detector (each weighs every report as a GNSS fix).
    prior: optional (n, 3) prior positions (previous verified position or INS), nan rows for
        none; with ``prior_sigma`` (m) it resolves the mirror ambiguity of 3 anchors.
    """

    reported: np.ndarray
    ranges: np.ndarray
    gnss_sigma: tuple[float, float] | None = None
    range_sigma: float | None = None
    source: np.ndarray | None = None
    prior: np.ndarray | None = None
    prior_sigma: float | None = None
    gnss_common: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        fields = _checked_fields(self, batch=False)
        n = fields["reported"].shape[0]
        if self.source is not None:
            src = np.asarray(self.source, dtype=object)
            if src.shape != (n,) or not set(src.tolist()) <= set(SOURCES):
                raise ValueError(f"source: expected ({n},) of {', '.join(SOURCES)}")
            object.__setattr__(self, "source", src)
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    @property
    def n(self) -> int:
        return int(self.reported.shape[0])


@dataclass(frozen=True)
class Verdict:
    """The leader's decision for one snapshot.

    positions: (n, 3) verified positions (nan, or the prior, where not determined or withheld
    for a level above the alert limits); faulty: (n,) flags; status: one of `STATUSES`;
    drone_status: (n,) the status per drone (``degenerate`` for a drone whose position is not
    determined or withheld, else the verdict's);
    hpl, vpl: (n,) horizontal and vertical protection levels, m (inf where not determined or withheld,
    nan for a detector without a noise model); diagnostics: per-drone arrays (votes, anchors
    used, ...).
    """

    positions: np.ndarray
    faulty: np.ndarray
    status: str
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)
    drone_status: np.ndarray | None = None
    hpl: np.ndarray | None = None
    vpl: np.ndarray | None = None


@dataclass(frozen=True)
class SnapshotBatch:
    """T snapshots of the same swarm size: reported (T, n, 3), ranges (T, n, n)."""

    reported: np.ndarray
    ranges: np.ndarray
    gnss_sigma: tuple[float, float] | None = None
    range_sigma: float | None = None
    prior: np.ndarray | None = None  # (T, n, 3), nan rows for none
    prior_sigma: float | None = None
    gnss_common: tuple[float, float] | None = None

    @classmethod
    def of(cls, snapshot: Snapshot) -> SnapshotBatch:
        if not isinstance(snapshot, Snapshot):
            raise ValueError(
                f"verify: expected a Snapshot(reported=..., ranges=...), got {type(snapshot).__name__}"
            )
        return cls(
            reported=snapshot.reported[None],
            ranges=snapshot.ranges[None],
            gnss_sigma=snapshot.gnss_sigma,
            range_sigma=snapshot.range_sigma,
            prior=None if snapshot.prior is None else snapshot.prior[None],
            prior_sigma=snapshot.prior_sigma,
            gnss_common=snapshot.gnss_common,
        )

    def checked(self) -> SnapshotBatch:
        """This batch, after the checks `Snapshot` makes of one snapshot (`_checked_fields`):
        a one-line ValueError for the first that fails. For batches from outside; the
        detectors' own batches (`of`, `subset`) need none."""
        return SnapshotBatch(**_checked_fields(self, batch=True))

    def subset(self, rows: np.ndarray) -> SnapshotBatch:
        """The snapshots selected by ``rows`` (a boolean mask or indices)."""
        return SnapshotBatch(
            self.reported[rows],
            self.ranges[rows],
            self.gnss_sigma,
            self.range_sigma,
            None if self.prior is None else self.prior[rows],
            self.prior_sigma,
            self.gnss_common,
        )

    @property
    def shape(self) -> tuple[int, int]:
        T, n, _ = self.reported.shape
        return T, n


def merged_rows(whole: np.ndarray, rows: np.ndarray, part: np.ndarray) -> np.ndarray:
    """A copy of ``whole`` with ``rows`` replaced by ``part``; strings kept whole whatever
    their length (an array of str comes back as objects)."""
    out = whole.astype(object) if whole.dtype.kind == "U" else whole.copy()
    out[rows] = part
    return out


@dataclass(frozen=True)
class VerdictBatch:
    """Verdicts of a batch: positions (T, n, 3), faulty (T, n), status (T,) of str,
    drone_status (T, n) of str (default: the verdict's status), hpl and vpl (T, n) in m
    (default nan: no protection level)."""

    positions: np.ndarray
    faulty: np.ndarray
    status: np.ndarray
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)
    drone_status: np.ndarray | None = None
    hpl: np.ndarray | None = None
    vpl: np.ndarray | None = None

    def __post_init__(self) -> None:
        status = np.asarray(self.status).astype("<U14")  # wide enough for every status
        unknown = set(status.tolist()) - set(STATUSES)
        if unknown:
            raise ValueError(f"status: {sorted(unknown)} not in {STATUSES}")
        object.__setattr__(self, "status", status)
        T, n = self.faulty.shape
        if self.drone_status is None:
            object.__setattr__(self, "drone_status", np.repeat(status[:, None], n, axis=1))
        else:
            object.__setattr__(self, "drone_status", np.asarray(self.drone_status).astype("<U14"))
        for name in ("hpl", "vpl"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full((T, n), np.nan))

    def with_rows(self, rows: np.ndarray, other: VerdictBatch, take: np.ndarray) -> VerdictBatch:
        """This batch with its verdicts ``rows`` (indices) replaced by ``other``'s verdicts
        ``take``: every field, and each diagnostic both hold (strings kept whole); a
        diagnostic only this batch has keeps its old rows."""

        def merged(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            a = np.asarray(a)
            out = merged_rows(a, rows, np.asarray(b)[take])
            return out.astype(str) if a.dtype.kind == "U" else out

        fields = ("positions", "faulty", "status", "drone_status", "hpl", "vpl")
        new = {name: merged(getattr(self, name), getattr(other, name)) for name in fields}
        diag = dict(self.diagnostics)
        for key in diag.keys() & other.diagnostics.keys():
            diag[key] = merged(diag[key], other.diagnostics[key])
        return replace(self, diagnostics=diag, **new)

    def subset(self, rows: np.ndarray) -> VerdictBatch:
        """The verdicts selected by ``rows`` (a boolean mask or indices)."""
        return VerdictBatch(
            self.positions[rows],
            self.faulty[rows],
            self.status[rows],
            {k: np.asarray(v)[rows] for k, v in self.diagnostics.items()},
            self.drone_status[rows],
            self.hpl[rows],
            self.vpl[rows],
        )

    def item(self, t: int) -> Verdict:
        return Verdict(
            positions=self.positions[t],
            faulty=self.faulty[t],
            status=str(self.status[t]),
            diagnostics={k: v[t] for k, v in self.diagnostics.items()},
            drone_status=self.drone_status[t],
            hpl=self.hpl[t],
            vpl=self.vpl[t],
        )
