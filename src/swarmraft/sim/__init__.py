"""Deterministic discrete-event simulation: virtual clock, radio network model, crashes and
restarts, and Raft invariant checks after every event."""

from swarmraft.sim.invariants import InvariantChecker, InvariantViolation
from swarmraft.sim.network import LinkModel, Network
from swarmraft.sim.runtime import Cluster, EventLoop

__all__ = ["Cluster", "EventLoop", "InvariantChecker", "InvariantViolation", "LinkModel", "Network"]
