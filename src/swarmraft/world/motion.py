"""Ground-truth motion over time: a formation following waypoints (docs/models.md: 5-10 m/s,
10-30 m spacing, 10 Hz steps), or a static swarm (the paper's cube)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarmraft.world.geometry import formation, uniform_cube


@dataclass(frozen=True)
class Trajectory:
    """Positions (steps, n, 3) and velocities (steps, n, 3) at times ``t`` (steps,)."""

    t: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else 0.0


def waypoint_path(waypoints: np.ndarray, speed: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre position and velocity (steps, 3) moving at constant ``speed`` along the
    polyline ``waypoints`` (k, 3), stopping at the last one."""
    wp = np.asarray(waypoints, float)
    seg = np.diff(wp, axis=0)
    length = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = np.minimum(speed * t, cum[-1])
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = np.where(length[i] > 0, (s - cum[i]) / np.where(length[i] > 0, length[i], 1.0), 0.0)
    pos = wp[i] + frac[:, None] * seg[i]
    moving = (speed * t < cum[-1])[:, None]
    direction = seg[i] / np.where(length[i] > 0, length[i], 1.0)[:, None]
    return pos, np.where(moving, direction * speed, 0.0)


def formation_flight(
    rng: np.random.Generator,
    n: int,
    duration: float,
    dt: float = 0.1,
    spacing: float = 20.0,
    speed: float = 7.0,
    waypoints: np.ndarray | None = None,
    jitter: float = 1.0,
) -> Trajectory:
    """n drones in a two-layer grid formation (random heading, per-drone offsets fixed) whose
    centre follows ``waypoints`` at ``speed``; default: a 600 m square at 100 m altitude."""
    if not dt > 0 or not duration > 0:
        raise ValueError("formation_flight: dt and duration must be > 0")
    t = np.arange(0.0, duration + 1e-9, dt)
    if waypoints is None:
        waypoints = np.array([[0, 0, 100], [600, 0, 100], [600, 600, 100], [0, 600, 100], [0, 0, 100.0]])
    centre, vel = waypoint_path(np.asarray(waypoints, float), speed, t)
    offsets = formation(rng, 1, n, spacing, jitter, altitude=0.0)[0]
    offsets -= offsets.mean(axis=0)
    pos = centre[:, None, :] + offsets[None]
    return Trajectory(t=t, positions=pos, velocities=np.repeat(vel[:, None, :], n, axis=1))


def static_swarm(
    rng: np.random.Generator, n: int, duration: float, dt: float = 0.1, size: float = 100.0
) -> Trajectory:
    """The paper's setting: n drones uniform in a cube, not moving."""
    t = np.arange(0.0, duration + 1e-9, dt)
    p = uniform_cube(rng, 1, n, size)[0]
    return Trajectory(t=t, positions=np.repeat(p[None], len(t), axis=0), velocities=np.zeros((len(t), n, 3)))
