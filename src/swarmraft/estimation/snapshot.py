"""What the leader sees at one step (`Snapshot`) and what it decides (`Verdict`).

Batches of snapshots with the same swarm size travel as `SnapshotBatch` / `VerdictBatch`:
arrays with a leading trial axis, so sweeps verify thousands of trials in one call.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STATUSES = ("ok", "unidentifiable", "insufficient")
SOURCES = ("gnss", "ins", "none")


def _as_float_array(name: str, value: object, shape_hint: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a numeric array {shape_hint}") from exc
    return arr


@dataclass(frozen=True)
class Snapshot:
    """One step's reports.

    reported: (n, 3) reported positions, metres, local ENU.
    ranges: (n, n); ``ranges[i, j]`` is the distance drone i measured to drone j, ``nan`` where
        not measured. The diagonal is ignored.
    gnss_sigma: optional (horizontal, vertical) GNSS sigma per axis, metres.
    range_sigma: optional ranging sigma, metres.
    source: optional (n,) of "gnss", "ins" or "none": where each report came from.
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

    def __post_init__(self) -> None:
        rep = _as_float_array("reported", self.reported, "(n, 3)")
        if rep.ndim != 2 or rep.shape[1] != 3 or rep.shape[0] < 1:
            raise ValueError(f"reported: expected shape (n, 3) with n >= 1, got {rep.shape}")
        if not np.isfinite(rep).all():
            raise ValueError("reported: positions must be finite")
        n = rep.shape[0]
        rng = _as_float_array("ranges", self.ranges, "(n, n)")
        if rng.shape != (n, n):
            raise ValueError(f"ranges: expected shape ({n}, {n}) to match reported, got {rng.shape}")
        off = ~np.eye(n, dtype=bool)
        vals = rng[off]
        if np.isinf(vals).any() or (vals[~np.isnan(vals)] < 0).any():
            raise ValueError("ranges: measured distances must be finite and >= 0 (nan = unmeasured)")
        if self.gnss_sigma is not None:
            gs = tuple(float(v) for v in self.gnss_sigma)
            if len(gs) != 2 or min(gs) < 0:
                raise ValueError("gnss_sigma: expected (horizontal, vertical), both >= 0")
            object.__setattr__(self, "gnss_sigma", gs)
        if self.range_sigma is not None and not float(self.range_sigma) >= 0:
            raise ValueError("range_sigma: must be >= 0")
        if self.source is not None:
            src = np.asarray(self.source, dtype=object)
            if src.shape != (n,) or not set(src.tolist()) <= set(SOURCES):
                raise ValueError(f"source: expected ({n},) of {', '.join(SOURCES)}")
            object.__setattr__(self, "source", src)
        if self.prior is not None:
            pr = _as_float_array("prior", self.prior, "(n, 3)")
            if pr.shape != (n, 3) or np.isinf(pr).any():
                raise ValueError(f"prior: expected shape ({n}, 3) of finite values or nan rows")
            object.__setattr__(self, "prior", pr)
        if self.prior_sigma is not None and not float(self.prior_sigma) > 0:
            raise ValueError("prior_sigma: must be > 0")
        object.__setattr__(self, "reported", rep)
        object.__setattr__(self, "ranges", rng)

    @property
    def n(self) -> int:
        return int(self.reported.shape[0])


@dataclass(frozen=True)
class Verdict:
    """The leader's decision for one snapshot.

    positions: (n, 3) verified positions; faulty: (n,) flags; status: "ok",
    "unidentifiable" or "insufficient"; diagnostics: per-drone arrays (votes, anchors used,
    deviation of the recovered position from the report, ...).
    """

    positions: np.ndarray
    faulty: np.ndarray
    status: str
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class SnapshotBatch:
    """T snapshots of the same swarm size: reported (T, n, 3), ranges (T, n, n)."""

    reported: np.ndarray
    ranges: np.ndarray
    gnss_sigma: tuple[float, float] | None = None
    range_sigma: float | None = None
    prior: np.ndarray | None = None  # (T, n, 3), nan rows for none
    prior_sigma: float | None = None

    @classmethod
    def of(cls, snapshot: Snapshot) -> SnapshotBatch:
        return cls(
            reported=snapshot.reported[None],
            ranges=snapshot.ranges[None],
            gnss_sigma=snapshot.gnss_sigma,
            range_sigma=snapshot.range_sigma,
            prior=None if snapshot.prior is None else snapshot.prior[None],
            prior_sigma=snapshot.prior_sigma,
        )

    @property
    def shape(self) -> tuple[int, int]:
        T, n, _ = self.reported.shape
        return T, n


@dataclass(frozen=True)
class VerdictBatch:
    """Verdicts of a batch: positions (T, n, 3), faulty (T, n), status (T,) of str."""

    positions: np.ndarray
    faulty: np.ndarray
    status: np.ndarray
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)

    def item(self, t: int) -> Verdict:
        return Verdict(
            positions=self.positions[t],
            faulty=self.faulty[t],
            status=str(self.status[t]),
            diagnostics={k: v[t] for k, v in self.diagnostics.items()},
        )
