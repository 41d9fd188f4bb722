"""The leader's verification as pure functions on arrays: detectors, multilateration,
threshold calibration. Nothing here knows about Raft or networks."""

from swarmraft.estimation import clique as _clique  # noqa: F401  (registers "clique")
from swarmraft.estimation import fde as _fde  # noqa: F401  (registers "fde")
from swarmraft.estimation import gnc as _gnc  # noqa: F401  (registers "joint")
from swarmraft.estimation import paper as _paper  # noqa: F401  (registers "paper")
from swarmraft.estimation import shape as _shape  # noqa: F401  (registers "shape")
from swarmraft.estimation.paper import PaperParams
from swarmraft.estimation.registry import (
    detector_names,
    detector_params,
    get_detector,
    register,
    verify,
    verify_batch,
    verify_given,
)
from swarmraft.estimation.snapshot import Snapshot, SnapshotBatch, Verdict, VerdictBatch

__all__ = [
    "PaperParams",
    "Snapshot",
    "SnapshotBatch",
    "Verdict",
    "VerdictBatch",
    "detector_names",
    "detector_params",
    "get_detector",
    "register",
    "verify",
    "verify_batch",
    "verify_given",
]
