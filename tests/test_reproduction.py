"""A reduced reproduction of the paper's published numbers (the full one is
`swarmraft sweep --preset reference --diagonal --trials 10000` + `swarmraft check`)."""

import numpy as np

from swarmraft.experiments import build_config, run_sweep
from swarmraft.experiments.published import PUBLISHED, compare_published


def test_reference_preset_matches_published_means(tmp_path):
    cfg = build_config("reference", n=(5, 7, 17), diagonal=True, trials=3000, seed=11)
    res = run_sweep(cfg, tmp_path, workers=1)
    rows = compare_published(res.cells)
    assert [r["n"] for r in rows] == [5, 7, 17]
    for r in rows:
        # The published mean has its own sampling error (10,000 trials): compare with the
        # combined standard error.
        pub_se = r["sem"] * np.sqrt(3000 / 10000)
        z = (r["recovered"] - r["published"]) / np.hypot(r["sem"], pub_se)
        assert abs(z) < 3.5, r
        assert abs(r["baseline"] - PUBLISHED[r["n"]][2]) < 0.6
    med = dict(zip(res.cells["n"].tolist(), res.cells["recovered_median"].tolist(), strict=True))
    assert med[7] < 1e-6 and med[17] < 1e-6  # FACTS.md: median about 1e-8 m for n >= 5
