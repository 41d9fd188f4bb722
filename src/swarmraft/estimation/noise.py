"""The noise model a statistical detector works with: GNSS covariance and range sigma, taken
from the snapshot (or the detector's parameters), floored so that exact data (the reference
preset) still gives finite weights."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from pydantic import ConfigDict, Field, ValidationInfo, field_validator

from swarmraft.estimation.bounds import gnss_covariance
from swarmraft.estimation.link_params import LinkParams
from swarmraft.estimation.snapshot import SnapshotBatch, sigma_pair


class NoiseParams(LinkParams):
    """Noise parameters shared by the statistical detectors (and the range screening,
    `link_params.LinkParams`). None: take it from the snapshot."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    gnss_sigma: tuple[float, float] | None = Field(None, description="(horizontal, vertical) m")
    range_sigma: float | None = Field(None, ge=0, description="ranging sigma, m")
    min_sigma: float = Field(1e-3, gt=0, description="floor for exact data, m")
    gnss_common: tuple[float, float] | None = Field(
        None, description="(horizontal, vertical) GNSS error common to all drones, m; None: the snapshot's"
    )

    @field_validator("gnss_sigma", "gnss_common")
    @classmethod
    def _pair(cls, v: tuple[float, float] | None, info: ValidationInfo) -> tuple[float, float] | None:
        """Both finite and >= 0, as a snapshot's (a negative sigma was floored to 1 mm, and
        every drone of a verdict flagged)."""
        try:
            return None if v is None else sigma_pair(str(info.field_name), v)
        except ValueError as e:  # the caller names the field
            raise ValueError(str(e).split(": ", 1)[1]) from None


_MEMO: dict[tuple[str, bytes], np.ndarray] = {}


def _memo(kind: str, gnss_cov: np.ndarray, make) -> np.ndarray:  # noqa: ANN001
    key = (kind, np.asarray(gnss_cov, float).tobytes())
    out = _MEMO.get(key)
    if out is None:
        if len(_MEMO) >= 64:
            _MEMO.clear()
        out = _MEMO[key] = make(np.asarray(gnss_cov, float))
        out.flags.writeable = False  # shared by every caller
    return out


def prior_held(prior: np.ndarray | None, prior_sigma: float | None, shape: tuple[int, ...]) -> np.ndarray:
    """(T, n): the drones whose prior counts as information: a finite prior, and a
    ``prior_sigma`` to weigh it (a prior without one is not used)."""
    if prior is None or not prior_sigma:
        return np.zeros(shape, dtype=bool)
    return np.isfinite(prior).all(axis=-1)


def gnss_information(gnss_cov: np.ndarray) -> np.ndarray:
    """gnss_cov^-1 (3, 3), memoised by the covariance's bytes (a detector has one or two;
    the solvers asked for it a dozen times per leader step). Read only."""
    return _memo("information", gnss_cov, np.linalg.inv)


def smallest_information(gnss_cov: np.ndarray) -> float:
    """The smallest eigenvalue of gnss_cov^-1 (the GNSS information along its weakest axis),
    memoised as `gnss_information`."""
    return float(_memo("eigenvalues", gnss_cov, lambda c: np.linalg.eigvalsh(gnss_information(c)))[0])


def gnss_whitener(gnss_cov: np.ndarray) -> np.ndarray:
    """W (3, 3, C-contiguous) with W^T W = gnss_cov^-1: W e is a whitened GNSS error
    (memoised as `gnss_information`). Read only."""
    return _memo("whitener", gnss_cov, _cholesky_whitener)


def _cholesky_whitener(gnss_cov: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.linalg.cholesky(gnss_information(gnss_cov)).T)


@dataclass(frozen=True)
class NoiseModel:
    gnss_cov: np.ndarray  # (3, 3), each drone's own GNSS error
    range_sigma: float
    common_var: np.ndarray | None = None  # (3,) per-axis variance of an error common to all drones

    @classmethod
    def of(cls, batch: SnapshotBatch, p: NoiseParams, detector: str) -> NoiseModel:
        gs = p.gnss_sigma if p.gnss_sigma is not None else batch.gnss_sigma
        rs = p.range_sigma if p.range_sigma is not None else batch.range_sigma
        if rs is None:
            raise ValueError(
                f"{detector}: needs the ranging noise: give the snapshot range_sigma or the "
                "detector parameter range_sigma"
            )
        h, v = gs if gs is not None else (0.0, 0.0)  # no GNSS sigma: exact honest reports
        floor = p.min_sigma
        gc = p.gnss_common if p.gnss_common is not None else batch.gnss_common
        common = None if gc is None else np.array([gc[0] ** 2, gc[0] ** 2, gc[1] ** 2], float)
        return cls(gnss_covariance(max(h, floor), max(v, floor)), max(float(rs), floor), common)

    @cached_property
    def whitener(self) -> np.ndarray:
        """W with W^T W = gnss_cov^-1: W e is a whitened GNSS error (`gnss_whitener`)."""
        return gnss_whitener(self.gnss_cov)

    def los_variance(self, u: np.ndarray) -> np.ndarray:
        """GNSS variance along unit vectors u (..., 3)."""
        return np.einsum("...i,ij,...j->...", u, self.gnss_cov, u)
