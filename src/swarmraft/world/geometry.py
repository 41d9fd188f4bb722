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


def flat_layer(
    rng: np.random.Generator, trials: int, n: int, size: float = 100.0, thickness: float = 0.5
) -> np.ndarray:
    """n drones uniform in a square of side ``size`` and a layer ``thickness`` m thick: the
    anchors of any drone are near-coplanar, so ranges leave a mirror image across the layer."""
    if n < 1 or trials < 1 or not size > 0 or thickness < 0:
        raise ValueError("flat_layer: need n >= 1, trials >= 1, size > 0, thickness >= 0")
    xy = rng.uniform(0.0, size, size=(trials, n, 2))
    return np.concatenate([xy, rng.uniform(0.0, thickness, size=(trials, n, 1))], axis=2)


def near_line(
    rng: np.random.Generator, trials: int, n: int, length: float = 100.0, radius: float = 1.0
) -> np.ndarray:
    """n drones along a line of ``length`` m, each within ``radius`` m of it (uniform in the
    disc across the line): near-collinear anchors, which leave a rotation about the line."""
    if n < 1 or trials < 1 or not length > 0 or radius < 0:
        raise ValueError("near_line: need n >= 1, trials >= 1, length > 0, radius >= 0")
    along = rng.uniform(0.0, length, size=(trials, n))
    r = radius * np.sqrt(rng.uniform(size=(trials, n)))
    phi = rng.uniform(0.0, 2 * np.pi, size=(trials, n))
    return np.stack([along, r * np.cos(phi), 50.0 + r * np.sin(phi)], axis=2)


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


_DIFF_FLOATS = 8_000_000  # per block of `true_distances`' (T, n, n, 3) differences (64 MB)


def true_distances(positions: np.ndarray) -> np.ndarray:
    """Pairwise Euclidean distances (T, n, n) of positions (T, n, 3), in blocks of trials
    (each distance is computed alike, so the result is the same bit for bit: 2000 snapshots
    of 256 drones held 3 GB of differences at once)."""
    T, n, _ = positions.shape
    out = np.empty((T, n, n))
    step = max(1, _DIFF_FLOATS // (3 * n * n))
    for lo in range(0, T, step):
        p = positions[lo : lo + step]
        diff = p[:, :, None, :] - p[:, None, :, :]
        out[lo : lo + step] = np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
    return out
