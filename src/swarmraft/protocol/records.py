"""What SwarmRaft drones exchange: signed `Report`s to the leader, and the `StepRecord` the
leader proposes to the Raft log. Both encode to compact JSON bytes; a record carries the
digest of the reports it was computed from."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

import numpy as np


def _floats(a: np.ndarray | None) -> list | None:
    if a is None:
        return None
    return [None if not np.isfinite(v) else float(v) for v in np.asarray(a, float).ravel()]


def _array(v: list | None, shape: tuple[int, ...]) -> np.ndarray | None:
    if v is None:
        return None
    return np.array([np.nan if x is None else x for x in v], dtype=float).reshape(shape)


@dataclass(frozen=True)
class Report:
    """Drone ``drone``'s report for ``step``: its position (GNSS fix, or INS estimate when
    GNSS is lost), the source, its ranges to every drone (nan = not measured) and its
    GNSS-minus-INS innovation (None without a fix). ``signature`` covers everything else."""

    step: int
    drone: int  # 0-based index
    position: np.ndarray  # (3,)
    source: str  # "gnss" or "ins"
    ranges: np.ndarray  # (n,)
    innovation: np.ndarray | None
    signature: bytes = b""

    def body(self) -> bytes:
        """The signed bytes."""
        return json.dumps(
            {
                "k": self.step,
                "d": self.drone,
                "p": _floats(self.position),
                "s": self.source,
                "r": _floats(self.ranges),
                "i": _floats(self.innovation),
            },
            separators=(",", ":"),
        ).encode()

    def encode(self) -> bytes:
        return self.body() + b"|" + self.signature.hex().encode()

    @classmethod
    def decode(cls, data: bytes) -> Report:
        body, _, sig = data.rpartition(b"|")
        d = json.loads(body)
        n = len(d["r"])
        return cls(
            d["k"],
            d["d"],
            _array(d["p"], (3,)),
            d["s"],
            _array(d["r"], (n,)),
            _array(d["i"], (3,)),
            bytes.fromhex(sig.decode()),
        )


@dataclass(frozen=True)
class StepRecord:
    """The replicated entry of one step: verified positions (n, 3) (nan = missing), flags,
    which drones were missing (no report), the verdict status, the detector, the leader's
    term, and the digest of the reports it was computed from."""

    step: int
    term: int
    positions: np.ndarray
    faulty: np.ndarray
    missing: np.ndarray
    status: str
    detector: str
    digest: str

    def encode(self) -> bytes:
        n = len(self.faulty)
        return json.dumps(
            {
                "k": self.step,
                "t": self.term,
                "p": _floats(self.positions),
                "f": [bool(x) for x in self.faulty],
                "m": [bool(x) for x in self.missing],
                "s": self.status,
                "det": self.detector,
                "h": self.digest,
                "n": n,
            },
            separators=(",", ":"),
        ).encode()

    @classmethod
    def decode(cls, data: bytes) -> StepRecord:
        d = json.loads(data)
        return cls(
            d["k"],
            d["t"],
            _array(d["p"], (d["n"], 3)),
            np.array(d["f"], bool),
            np.array(d["m"], bool),
            d["s"],
            d["det"],
            d["h"],
        )


def reports_digest(reports: list[Report]) -> str:
    """SHA-256 over the reports' signed bodies, in drone order."""
    h = hashlib.sha256()
    for r in sorted(reports, key=lambda r: r.drone):
        h.update(r.body())
        h.update(r.signature)
    return h.hexdigest()[:32]
