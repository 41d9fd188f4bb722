"""Swarm geometry for snapshots: where the drones truly are.

Every function takes a batch size T and returns (T, n, 3) positions in metres (local ENU),
drawing only from the generator passed in.
"""

from __future__ import annotations

import numpy as np


def uniform_cube(rng: np.random.Generator, trials: int, n: int, size: float = 100.0) -> np.ndarray:
    """n drones uniform in the cube [0, size]^3, as the paper (size 100 m, docs/models.md)."""
    if n < 1 or trials < 1 or not size > 0:
        raise ValueError("uniform_cube: need n >= 1, trials >= 1, size > 0")
    return rng.uniform(0.0, size, size=(trials, n, 3))


def formation(
    rng: np.random.Generator,
    trials: int,
    n: int,
    spacing: float = 20.0,
    jitter: float = 0.0,
    altitude: float = 50.0,
    layers: int = 2,
) -> np.ndarray:
    """A grid formation: n drones on a near-square grid with the given spacing (docs/models.md:
    10-30 m), in ``layers`` altitude layers one spacing apart (two layers keep the geometry
    three-dimensional), plus uniform jitter of +/- ``jitter`` m per axis, and a random heading.
    """
    if n < 1 or trials < 1 or not spacing > 0 or jitter < 0 or layers < 1:
        raise ValueError("formation: need n >= 1, trials >= 1, spacing > 0, jitter >= 0, layers >= 1")
    per_layer = int(np.ceil(n / layers))
    side = int(np.ceil(np.sqrt(per_layer)))
    idx = np.arange(n)
    layer, k = idx % layers, idx // layers
    base = np.stack([(k % side) * spacing, (k // side) * spacing, altitude + layer * spacing], axis=1)
    base[:, :2] -= base[:, :2].mean(axis=0)
    heading = rng.uniform(0, 2 * np.pi, size=trials)
    c, s = np.cos(heading), np.sin(heading)
    rot = np.zeros((trials, 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1
    pos = np.einsum("tij,nj->tni", rot, base)
    if jitter > 0:
        pos = pos + rng.uniform(-jitter, jitter, size=pos.shape)
    return pos


def true_distances(positions: np.ndarray) -> np.ndarray:
    """Pairwise Euclidean distances (T, n, n) of positions (T, n, 3)."""
    diff = positions[:, :, None, :] - positions[:, None, :, :]
    return np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
