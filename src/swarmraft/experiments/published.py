"""The paper's published results (docs/models.md: the authors' saved results for n = 2f+1,
10,000 trials each) and a comparison of a sweep against them."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

#: n -> (f, recovered mean m, baseline mean m): docs/models.md, "The paper and the numbers ...".
PUBLISHED: dict[int, tuple[int, float, float]] = {
    3: (1, 19.00, 28.7),
    5: (2, 5.50, 28.9),
    7: (3, 2.29, 28.8),
    9: (4, 1.23, 28.8),
    11: (5, 0.85, 28.9),
    13: (6, 0.52, 28.8),
    15: (7, 0.41, 28.8),
    17: (8, 0.287, 28.8),
}
MAX_Z = 3.0  # recovered mean within 3 standard errors
MAX_BASELINE_GAP = 0.3  # baseline mean within 0.3 m


def compare_published(cells: Mapping[str, np.ndarray]) -> list[dict[str, object]]:
    """One row per published cell present in ``cells``: our mean, its standard error, the
    published mean, z = (ours - published) / our SEM, and whether both criteria hold."""
    rows = []
    for i, n in enumerate(np.asarray(cells["n"]).tolist()):
        f = int(cells["f"][i])
        if n not in PUBLISHED or PUBLISHED[n][0] != f:
            continue
        _, pub_rec, pub_base = PUBLISHED[n]
        rec, se = float(cells["recovered_mean"][i]), float(cells["recovered_sem"][i])
        base = float(cells["baseline_mean"][i])
        z = (rec - pub_rec) / se if se > 0 else float("inf")
        rows.append(
            {
                "n": n,
                "f": f,
                "trials": int(cells["trials"][i]),
                "recovered": rec,
                "sem": se,
                "published": pub_rec,
                "z": z,
                "baseline": base,
                "published_baseline": pub_base,
                "ok": abs(z) <= MAX_Z and abs(base - pub_base) <= MAX_BASELINE_GAP,
            }
        )
    return rows


#: what a reference sweep may change and still be the paper's experiment: which cells, how
#: many trials, the seed, and how the work is cut
_FREE = ("n", "f", "diagonal", "trials", "seed", "chunk_size", "calibration_trials")


def not_the_papers(config: dict) -> list[str]:
    """How a sweep's config (run.json's ``config``) differs from the paper's experiment (the
    reference preset with its defaults), as ``key is X (the paper's: Y)``; [] if it does not.
    Its published numbers grade only that experiment: another attack, detector or parameter
    would be graded against numbers it was never meant to reproduce."""
    from swarmraft.experiments.config import build_config

    papers = build_config("reference").model_dump(mode="json")
    out = []
    for key, want in papers.items():
        if key in _FREE:
            continue
        have = config.get(key)
        if isinstance(want, dict) and isinstance(have, dict) and set(have) == set(want):
            out += [
                f"{key}.{k} is {have.get(k)!r} (the paper's: {v!r})"
                for k, v in want.items()
                if have.get(k) != v
            ]
        elif have != want:
            out.append(f"{key} is {have!r} (the paper's: {want!r})")
    return out
