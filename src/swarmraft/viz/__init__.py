"""Figures drawn from results (tables and recovery cases), never from internals."""

from swarmraft.viz.figures import compare, distribution, recovery, scaling

__all__ = ["compare", "distribution", "recovery", "scaling"]
