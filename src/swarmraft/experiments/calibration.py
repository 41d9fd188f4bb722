"""Calibrate a sweep's thresholds from honest-only simulations of its noise model
(the paper's section III.E: T = mu_e + 3 sigma_e)."""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmraft.estimation import get_detector
from swarmraft.estimation.calibration import Calibration, calibrate
from swarmraft.experiments.config import SweepConfig
from swarmraft.experiments.trials import chunk_seed, draw, snapshot_batch

CALIBRATED = ("tau", "epsilon")


def calibrate_cell(config: SweepConfig, n: int, trials: int | None = None) -> Calibration:
    """Honest-only snapshots of swarm size n (no attackers), seeded by (seed, n, 0, 0): f = 0
    is never a sweep cell, so this stream is disjoint from every trial's."""
    rng = np.random.default_rng(chunk_seed(config.seed, n, 0, 0))
    d = draw(config, rng, trials or config.calibration_trials, n, 0)
    return calibrate(snapshot_batch(config, d))


def detector_settings(config: SweepConfig, n: int) -> tuple[dict[str, Any], dict[str, float]]:
    """The detector parameters for swarm size n: the user's, plus calibrated tau/epsilon where
    the config asks for calibration and the user did not set them. Also returns the
    calibration record (empty when none ran)."""
    params = dict(config.detector_params)
    fields = get_detector(config.detector).params.model_fields
    wanted = [k for k in CALIBRATED if k in fields and k not in params]
    if not (config.calibrate and wanted):
        return params, {}
    cal = calibrate_cell(config, n)
    params.update({k: getattr(cal, k) for k in wanted})
    return params, cal.as_dict()
