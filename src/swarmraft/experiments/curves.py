"""Detection curves: ROC curves (detection rate against false-alarm rate as a detector's
threshold moves) and detection probability against spoof offset at a fixed false-alarm rate.

False alarms are honest drones flagged, detections attacked drones flagged, both counted on
the same trials. Every point of a detector uses the same draws (same seeds)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from swarmraft.estimation import verify_batch
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.config import SweepConfig
from swarmraft.experiments.trials import chunk_seed, draw, snapshot_batch

#: detector -> (threshold parameter, values from permissive to strict ... any order)
THRESHOLDS: dict[str, tuple[str, np.ndarray]] = {
    "paper": ("tau", np.geomspace(1.0, 60.0, 14)),
    "clique": ("k", np.geomspace(0.5, 20.0, 14)),
    "fde": ("p_fa", np.geomspace(1e-12, 0.5, 14)),
    "joint": ("flag_chi2", np.geomspace(1.0, 1000.0, 14)),
}


#: the columns of curves.csv, one row per CurvePoint
CURVE_COLUMNS = ("detector", "kind", "parameter", "threshold", "offset", "false_alarm", "detection")


@dataclass(frozen=True)
class CurvePoint:
    detector: str
    kind: str  # "roc" or "offset"
    parameter: str  # the detector's threshold parameter that is swept (THRESHOLDS)
    threshold: float
    offset: float  # spoof offset, m
    false_alarm: float
    detection: float


#: attacks whose size the curves sweep: a spoof offset (jump), a distance enlargement (enlarge)
CURVE_ATTACKS = ("jump", "enlarge")


def _sized(attack: str, offset: float) -> dict:
    """The attack settings of one curve point: ``offset`` m of spoof or of enlargement."""
    if attack == "enlarge":
        return {"name": "enlarge", "enlarge_low": offset, "enlarge_high": offset}
    return {"name": "jump", "jump": "shell", "low": offset, "high": offset}


def _rates(
    config: SweepConfig,
    detector: str,
    params: dict,
    n: int,
    f: int,
    trials: int,
    offset: float | None,
    salt: int,
    attack: str = "jump",
) -> tuple[float, float]:
    cfg = config
    if offset is not None:
        cfg = config.model_copy(update={"attack": config.attack.model_copy(update=_sized(attack, offset))})
    d = draw(cfg, np.random.default_rng(chunk_seed(config.seed, n, f, 10_000 + salt)), trials, n, f)
    v = verify_batch(snapshot_batch(cfg, d), detector, **params)
    return float(v.faulty[~d.attackers].mean()), float(v.faulty[d.attackers].mean())


def detection_curves(
    config: SweepConfig,
    detectors: Sequence[str],
    n: int,
    f: int,
    trials: int,
    offsets: Sequence[float],
    false_alarm: float,
    roc_offset: float = 10.0,
    tick: Callable[[int], None] | None = None,
    attack: str = "jump",
) -> list[CurvePoint]:
    """ROC points per detector over its threshold, with spoofs of ``roc_offset`` m (where
    detectors differ; large jumps are caught by all), then, at the threshold with the best
    detection among those whose false-alarm rate is at most ``false_alarm``, the detection
    rate for each spoof offset. ``attack``: ``jump`` (the offset is the spoof's) or
    ``enlarge`` (the offset is each attacker's distance enlargement, GNSS honest)."""
    if attack not in CURVE_ATTACKS:
        raise ValueError(f"curves: attack must be one of {', '.join(CURVE_ATTACKS)}, got {attack!r}")
    points: list[CurvePoint] = []
    for det in detectors:
        if det not in THRESHOLDS:
            raise ValueError(
                f"curves: no threshold parameter known for detector {det!r}; known: {', '.join(THRESHOLDS)}"
            )
        name, values = THRESHOLDS[det]
        base, _ = detector_settings(config.model_copy(update={"detector": det}), n)
        roc = []
        for th in values:
            fa, pd = _rates(config, det, {**base, name: float(th)}, n, f, trials, roc_offset, 0, attack)
            roc.append((float(th), fa, pd))
            points.append(CurvePoint(det, "roc", name, float(th), roc_offset, fa, pd))
            if tick:
                tick(1)
        allowed = [r for r in roc if r[1] <= false_alarm]
        th = max(allowed, key=lambda r: (r[2], -r[1]))[0] if allowed else min(roc, key=lambda r: r[1])[0]
        for off in offsets:
            fa, pd = _rates(config, det, {**base, name: th}, n, f, trials, float(off), 1, attack)
            points.append(CurvePoint(det, "offset", name, th, float(off), fa, pd))
            if tick:
                tick(1)
    return points
