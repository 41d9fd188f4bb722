"""What SwarmRaft drones exchange: signed `Report`s to the leader, and the `StepRecord` the
leader proposes to the Raft log. Both encode to compact binary (a fixed header, float64
arrays, length-prefixed parts; no pickle). A record carries everything its verification
read (the signed reports, the detector's parameters, the prior) and the leader's signature,
so any drone can re-run the verification and check it (`swarmraft.protocol.audit`)."""

from __future__ import annotations

import hashlib
import json
import struct
from dataclasses import dataclass

import numpy as np

from swarmraft.estimation.snapshot import MAX_M, distances_ok

_SOURCES = ("gnss", "ins")
#: verdicts a record's successor must not build on (docs/detectors.md, Statuses)
UNSETTLED = frozenset({"alarm", "unidentifiable"})


def verified_nothing(rec: StepRecord) -> bool:
    """Whether a record verified no drone: `degenerate`, and either made from one report
    (whatever the detector: a lone report is checked against nothing) or with protection
    levels computed and none finite (every drone not protected, or without a report). A
    leader alone with its own report makes one: its position unflagged, checked against
    nothing. Such a record is carried on neither as a prior nor as an INS alignment
    (`settled`), or a spoofed leader's own fix becomes every later step's anchor (found by a
    review: 30 m for 0.4 s; `paper`, whose levels are nan, passed the level test until a
    review of 2026-12-05)."""
    if rec.status != "degenerate":
        return False
    if (~np.asarray(rec.missing, bool)).sum() <= 1:
        return True
    if rec.hpl is None:
        return False
    return bool(np.isinf(rec.hpl).any() and not np.isfinite(rec.hpl).any())


def carried_positions(rec: StepRecord) -> np.ndarray:
    """The positions a record passes on as the next step's prior: its own, but nan for a drone
    it did not protect (a level inf) whose position is its own prior's, carried, not
    estimated (withheld under the alert limits). Carried on, that position went on as the
    prior, step after step, while the drone moved: 0.7 m off, then 8.6 m at step 12 and
    19.7 m at step 28 of a review's swarm at 7 m/s, with the prior's 3 m sigma pulling later
    verdicts (honest steps `unidentifiable` that were `ok` without the limits). So a withheld
    drone's position is at most one step old, then nan."""
    pos = np.array(rec.positions, dtype=float)
    if rec.hpl is None or rec.prior_positions is None:
        return pos
    unprotected = np.isinf(rec.hpl) | (np.isinf(rec.vpl) if rec.vpl is not None else False)
    carried = unprotected & (pos == np.asarray(rec.prior_positions, float)).all(axis=1)
    pos[carried] = np.nan
    return pos


def settled(rec: StepRecord) -> bool:
    """Whether a record's verdict can be carried on (as the next steps' prior, and to align
    the INS tracks): not `alarm` or `unidentifiable` (what the data could not settle), and
    not a record that verified no drone (`verified_nothing`)."""
    return rec.status not in UNSETTLED and not verified_nothing(rec)


_REPORT_HEAD = struct.Struct("<iiBBH")  # step, drone, source, parts (bit 0 innovation, 1 drift, 2 ins), n
_U8 = struct.Struct("<B")
_RECORD_HEAD = struct.Struct("<iqHiiH")  # step, term, n, leader, prior step, reports
_LEN16 = struct.Struct("<H")
_LEN32 = struct.Struct("<I")


@dataclass(frozen=True)
class Report:
    """Drone ``drone``'s report for ``step``: its position (GNSS fix, or INS estimate when
    GNSS is lost), the source, its ranges to every drone (nan = not measured) and its
    GNSS-minus-INS innovation (None without a fix). ``drift`` (M, 3): the innovations of the
    last M windows, newest first (nan rows: no fix then), the drag-off test's input
    (`swarmraft.protocol.drift`); ``ins`` (3,): the drone's INS track, its dead reckoning from
    the last committed position it was allowed to align to (`drift.realigns`). Both None when
    the host does not give them. ``signature`` (Ed25519, 64 bytes) covers everything else.
    Encoded as little-endian binary: a header, then float64 arrays (a report without drift
    and ins encodes as it always did)."""

    step: int
    drone: int  # 0-based index
    position: np.ndarray  # (3,)
    source: str  # "gnss" or "ins"
    ranges: np.ndarray  # (n,)
    innovation: np.ndarray | None
    signature: bytes = b""
    drift: np.ndarray | None = None
    ins: np.ndarray | None = None

    def malformed(self, n: int) -> str | None:
        """Why this report cannot be a drone's honest reading in a swarm of n (None: it can):
        a position not 3 numbers within MAX_M (10,000 km) of the origin, ranges not n values
        each nan or a distance in [0, MAX_M], an innovation, drift window or INS track with a
        value beyond MAX_M (nan allowed). A signature does not make it so: a compromised
        drone signs what it likes, and one nan position or a short range row raised inside
        the leader's detector (a LinAlgError, a broadcast error) and stopped its step, as
        did a finite position of 1e154 m (the solver's squares overflowed)."""
        pos = np.asarray(self.position, float)
        if pos.shape != (3,) or not all(abs(v) <= MAX_M for v in pos.tolist()):
            return f"position is not 3 numbers within {MAX_M:g} m"
        rng = np.asarray(self.ranges, float)
        if rng.shape != (n,):
            return f"{rng.size} ranges in a swarm of {n}"
        if not distances_ok(rng):
            return f"a range that is not a distance in [0, {MAX_M:g}] m"
        # (small arrays: Python's floats, a microsecond, where numpy's calls cost several each)
        for name in ("innovation", "drift", "ins"):
            value = getattr(self, name)
            if value is not None and any(abs(v) > MAX_M for v in np.ravel(value).tolist()):
                return f"an {name} value beyond {MAX_M:g} m"
        return None

    def body(self) -> bytes:
        """The signed bytes, encoded on the first call and kept: a report is a value (its
        arrays are not changed once it is made; `dataclasses.replace` makes a new one). A
        voter's audit reads them about 50 times a step (digest, signatures, memo keys)."""
        kept = self.__dict__.get("_body")
        if kept is None:
            kept = self._encode_body()
            object.__setattr__(self, "_body", kept)
        return kept

    def _encode_body(self) -> bytes:
        inn, drift, ins = self.innovation is not None, self.drift is not None, self.ins is not None
        parts = inn | drift << 1 | ins << 2
        head = _REPORT_HEAD.pack(self.step, self.drone, _SOURCES.index(self.source), parts, len(self.ranges))
        arrays = [np.asarray(self.position, "<f8"), np.asarray(self.ranges, "<f8")]
        if inn:
            arrays.append(np.asarray(self.innovation, "<f8"))
        body = head + b"".join(a.tobytes() for a in arrays)
        if drift:
            rows = np.asarray(self.drift, "<f8").reshape(-1, 3)
            body += _U8.pack(len(rows)) + rows.tobytes()
        if ins:
            body += np.asarray(self.ins, "<f8").tobytes()
        return body

    def encode(self) -> bytes:
        return self.body() + self.signature

    @staticmethod
    def head(data: bytes) -> tuple[int, int]:
        """The step and drone of an encoded report, without decoding the rest."""
        step, drone, _, _, _ = _REPORT_HEAD.unpack_from(data)
        return step, drone

    @classmethod
    def decode(cls, data: bytes) -> Report:
        step, drone, src, parts, n = _REPORT_HEAD.unpack_from(data)
        inn = parts & 1
        size = _REPORT_HEAD.size + 8 * (3 + n + 3 * inn)
        vals = np.frombuffer(data, "<f8", count=3 + n + 3 * inn, offset=_REPORT_HEAD.size)
        drift = ins = None
        if parts & 2:
            (m,) = _U8.unpack_from(data, size)
            drift = np.frombuffer(data, "<f8", count=3 * m, offset=size + 1).reshape(m, 3).copy()
            size += 1 + 24 * m
        if parts & 4:
            ins = np.frombuffer(data, "<f8", count=3, offset=size).copy()
            size += 24
        report = cls(
            step,
            drone,
            vals[:3].copy(),
            _SOURCES[src],
            vals[3 : 3 + n].copy(),
            vals[3 + n :].copy() if inn else None,
            bytes(data[size:]),
            drift,
            ins,
        )
        if not parts & ~7:  # no part this decoder ignores: the bytes are `body`'s encoding
            object.__setattr__(report, "_body", bytes(data[:size]))
        return report


def well_formed(reports: tuple[Report, ...] | list[Report], n: int) -> bool:
    """True only if no report is `Report.malformed` in a swarm of n: every check at once, for
    a record's reports (an audit read 17 reports one by one, 55 us a step); False where some
    check fails or the arrays do not stack (ask each report then, for the reason)."""
    try:
        pos = np.array([r.position for r in reports], float)
        rng = np.array([r.ranges for r in reports], float)
    except (ValueError, TypeError):
        return False
    if pos.shape != (len(reports), 3) or rng.shape != (len(reports), n):
        return False
    if not (np.abs(pos) <= MAX_M).all() or not distances_ok(rng):
        return False
    extra = [np.ravel(v) for r in reports for v in (r.innovation, r.drift, r.ins) if v is not None]
    return not extra or not (np.abs(np.concatenate(extra).astype(float)) > MAX_M).any()


@dataclass(frozen=True)
class StepRecord:
    """The replicated entry of one step: verified positions (n, 3) (nan = missing or not
    determined), flags, which drones were missing (no report), the verdict status, the
    detector, the leader's term, the digest of the reports it was computed from, and each
    drone's horizontal and vertical protection level hpl, vpl (n,) in m (nan where the
    detector gives none, inf where the position is not protected).

    The evidence (docs/audit.md): ``leader`` (the proposer's 0-based index, -1 if unsigned),
    ``params`` (the detector's parameters as canonical JSON), the prior the verification
    used (``prior_step``, -1 for none, with that record's positions and flags), the signed
    ``reports`` themselves, in drone order, and ``signature``, the leader's Ed25519 signature
    over `body`."""

    step: int
    term: int
    positions: np.ndarray
    faulty: np.ndarray
    missing: np.ndarray
    status: str
    detector: str
    digest: str
    hpl: np.ndarray | None = None
    vpl: np.ndarray | None = None
    leader: int = -1
    params: str = "{}"
    prior_step: int = -1
    prior_positions: np.ndarray | None = None
    prior_faulty: np.ndarray | None = None
    reports: tuple[Report, ...] = ()
    signature: bytes = b""

    def body(self) -> bytes:
        """Every byte but the signature (what the leader signs)."""
        n = len(self.faulty)
        nan = np.full(n, np.nan)
        hpl = nan if self.hpl is None else self.hpl
        vpl = nan if self.vpl is None else self.vpl
        prior = np.full((n, 3), np.nan) if self.prior_positions is None else self.prior_positions
        prior_faulty = np.zeros(n, bool) if self.prior_faulty is None else self.prior_faulty
        text = json.dumps([self.status, self.detector, self.digest, self.params]).encode()
        parts = [
            _RECORD_HEAD.pack(self.step, self.term, n, self.leader, self.prior_step, len(self.reports)),
            np.asarray(self.positions, "<f8").tobytes(),
            np.packbits(self.faulty).tobytes(),
            np.packbits(self.missing).tobytes(),
            np.asarray(hpl, "<f8").tobytes(),
            np.asarray(vpl, "<f8").tobytes(),
            np.asarray(prior, "<f8").tobytes(),
            np.packbits(prior_faulty).tobytes(),
        ]
        for r in self.reports:
            data = r.encode()
            parts += [_LEN16.pack(len(data)), data]
        parts += [_LEN32.pack(len(text)), text]
        return b"".join(parts)

    def encode(self) -> bytes:
        return self.body() + self.signature

    @classmethod
    def decode(cls, data: bytes) -> StepRecord:
        """The record in ``data``; a malformed one raises ValueError (or struct.error)."""
        step, term, n, leader, prior_step, count = _RECORD_HEAD.unpack_from(data)
        off = _RECORD_HEAD.size
        pos = np.frombuffer(data, "<f8", count=3 * n, offset=off).reshape(n, 3).copy()
        off += 24 * n
        nb = (n + 7) // 8
        faulty = np.unpackbits(np.frombuffer(data, np.uint8, count=nb, offset=off))[:n].astype(bool)
        missing = np.unpackbits(np.frombuffer(data, np.uint8, count=nb, offset=off + nb))[:n].astype(bool)
        off += 2 * nb
        hpl = np.frombuffer(data, "<f8", count=n, offset=off).copy()
        vpl = np.frombuffer(data, "<f8", count=n, offset=off + 8 * n).copy()
        off += 16 * n
        prior = np.frombuffer(data, "<f8", count=3 * n, offset=off).reshape(n, 3).copy()
        off += 24 * n
        prior_faulty = np.unpackbits(np.frombuffer(data, np.uint8, count=nb, offset=off))[:n].astype(bool)
        off += nb
        reports = []
        for _ in range(count):
            (size,) = _LEN16.unpack_from(data, off)
            off += _LEN16.size
            if off + size > len(data):
                raise ValueError("record: a report runs past the end")
            reports.append(Report.decode(data[off : off + size]))
            off += size
        (size,) = _LEN32.unpack_from(data, off)
        off += _LEN32.size
        if off + size > len(data):
            raise ValueError("record: the text runs past the end")
        status, detector, digest, params = json.loads(data[off : off + size])
        return cls(
            step,
            term,
            pos,
            faulty,
            missing,
            status,
            detector,
            digest,
            hpl,
            vpl,
            leader,
            params,
            prior_step,
            prior if prior_step >= 0 else None,
            prior_faulty if prior_step >= 0 else None,
            tuple(reports),
            bytes(data[off + size :]),
        )


def canonical_params(params: dict) -> str:
    """A detector's parameters as canonical JSON (sorted keys, no spaces): the same
    parameters give the same bytes on every drone."""
    return json.dumps(params, sort_keys=True, separators=(",", ":"))


def reports_digest(reports: list[Report]) -> str:
    """SHA-256 over the reports' signed bodies, in drone order."""
    h = hashlib.sha256()
    for r in sorted(reports, key=lambda r: r.drone):
        h.update(r.body())
        h.update(r.signature)
    return h.hexdigest()[:32]
