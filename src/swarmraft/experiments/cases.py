"""Single worked trials: the data behind the paper's recovery picture."""

from __future__ import annotations

import numpy as np

from swarmraft.estimation import verify_batch
from swarmraft.experiments.calibration import detector_settings
from swarmraft.experiments.config import SweepConfig
from swarmraft.experiments.trials import chunk_seed, draw, snapshot_batch

PAPER_CASES = ((6, 2), (11, 5), (16, 7))


def recovery_cases(
    config: SweepConfig, cases: tuple[tuple[int, int], ...] = PAPER_CASES
) -> list[dict[str, np.ndarray]]:
    """One trial per (n, f), drawn with the seed of that cell (chunk 0) from the
    config's world and seed and verified with its detector (calibrated as the sweep would)."""
    out = []
    for n, f in cases:
        if not 1 <= f <= n:
            raise ValueError(f"case ({n}, {f}): need 1 <= f <= n")
        rng = np.random.default_rng(chunk_seed(config.seed, n, f, 0))
        d = draw(config, rng, 1, n, f)
        params, _ = detector_settings(config, n)
        v = verify_batch(snapshot_batch(config, d), config.detector, **params)
        out.append(
            {
                "truth": d.truth[0],
                "reported": d.reported[0],
                "verified": v.positions[0],
                "attackers": d.attackers[0],
                "faulty": v.faulty[0],
            }
        )
    return out
