"""Inertial navigation drift: position error that grows from accelerometer bias (with the
tilt error folded in, both give a constant acceleration error) and gyro bias (a tilt that
grows linearly, so a horizontal acceleration error g * omega * t):

    e(tau) = 0.5 * b_a * tau^2 + (g / 6) * omega_h * tau^3     (tau: time since the last reset)

Grades give per-axis 1-sigma biases. ``drone-grade`` is set so that the RMS error matches
docs/models.md (0.02 m at 1 s, 1.8 m at 10 s, 68 m at 60 s after alignment); the other grades
are typical datasheet orders of magnitude (consumer MEMS ~10 mg / ~20 deg/h, industrial
~0.3 mg / ~0.3 deg/h, tactical ~0.05 mg / ~0.05 deg/h), not calibrated against a source.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

G = 9.80665


@dataclass(frozen=True)
class InsGrade:
    accel_bias: float  # m/s^2, 1 sigma per axis
    gyro_bias: float  # rad/s, 1 sigma per horizontal axis


INS_GRADES: dict[str, InsGrade] = {
    "consumer": InsGrade(0.1, 1.0e-4),
    "drone-grade": InsGrade(0.0206, 7.7e-6),
    "industrial": InsGrade(0.003, 1.5e-6),
    "tactical": InsGrade(0.0005, 2.5e-7),
}


def ins_grade(name: str) -> InsGrade:
    try:
        return INS_GRADES[name]
    except KeyError:
        raise ValueError(f"INS grade: unknown {name!r}; known: {', '.join(INS_GRADES)}") from None


@dataclass(frozen=True)
class InsDrift:
    """Per-drone biases (drawn once per mission) and the drift they cause."""

    accel: np.ndarray  # (n, 3) m/s^2
    gyro: np.ndarray  # (n, 3) m/s^3 equivalent horizontal (g * omega), vertical 0

    @classmethod
    def draw(cls, rng: np.random.Generator, n: int, grade: InsGrade) -> InsDrift:
        accel = rng.standard_normal((n, 3)) * grade.accel_bias
        gyro = rng.standard_normal((n, 3)) * grade.gyro_bias * G
        gyro[:, 2] = 0.0
        return cls(accel, gyro)

    def error(self, tau: np.ndarray) -> np.ndarray:
        """Position error (..., n, 3) after ``tau`` seconds (..., n) since each drone's last
        reset (many steps at once: a leading axis)."""
        tau = np.asarray(tau, float)[..., None]
        return 0.5 * self.accel * tau**2 + self.gyro * tau**3 / 6.0


def ins_sigma(grade: InsGrade, tau: float) -> float:
    """RMS 3-D drift of a grade after tau seconds (for gates and bounds)."""
    a = 0.5 * grade.accel_bias * tau**2 * np.sqrt(3)
    w = grade.gyro_bias * G * tau**3 / 6.0 * np.sqrt(2)
    return float(np.hypot(a, w))
