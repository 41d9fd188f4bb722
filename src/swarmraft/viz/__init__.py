"""Figures drawn from results (tables and recovery cases), never from internals."""

from swarmraft.viz.figures import distribution, recovery, scaling

__all__ = ["distribution", "recovery", "scaling"]
