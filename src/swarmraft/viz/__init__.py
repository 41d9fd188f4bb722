"""Figures drawn from results (tables and recovery cases), never from internals."""

from swarmraft.viz.figures import compare, detection_vs_offset, distribution, recovery, roc, scaling
from swarmraft.viz.integrity import stanford

__all__ = ["compare", "detection_vs_offset", "distribution", "recovery", "roc", "scaling", "stanford"]
