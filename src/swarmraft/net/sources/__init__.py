"""Where a drone process's sensor readings come from: one interface, `SensorSource`, and its
implementations. Each step k the host asks its source for a `Reading` (its position fix or,
without one, its INS estimate; the source kind; its row of ranges to the other drones; its
GNSS-minus-INS innovation; its INS estimate) and tells it when its INS is realigned to a
verified position.

- `ScenarioSource`: computed from the swarm's scenario (`sim.sensing.ScenarioWorld`), the
  same draws the simulator makes (what every node did before sources existed);
- `replay.ReplaySource`: a recorded sensor log (docs/records.md);
- `mavlink.MavlinkSource`: a live GNSS fix over MAVLink (``GPS_RAW_INT``, pymavlink, the
  ``mavlink`` extra) and ranges over a small UDP line format.

A source never blocks: `reading` returns at once with what it has (a live source reads its
inputs in threads of its own). Positions are metres in the scenario's local ENU frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from swarmraft.net.swarmfile import SwarmFile
from swarmraft.sim.sensing import ScenarioWorld

Kind = Literal["gnss", "ins"]


@dataclass(frozen=True)
class Reading:
    """What one drone reports at one step."""

    position: np.ndarray  # (3,) m: its GNSS fix, or its INS estimate when kind is "ins"
    kind: Kind  # "gnss" or "ins": what ``position`` is
    ranges: np.ndarray  # (n,) m: its measured range to each drone, nan where not measured
    innovation: np.ndarray | None  # (3,) m: GNSS-minus-INS over the innovation window, or None
    ins: np.ndarray  # (3,) m: its INS estimate (equal to ``position`` when kind is "ins")
    drift: np.ndarray | None = None  # (M, 3) m: innovations of its last M windows (`Report.drift`)


class SensorSource(Protocol):
    """A drone's sensors as its host sees them."""

    def reading(self, k: int) -> Reading | None:
        """Step k's reading, or None when the source has nothing to report (no data yet, or
        none recent). Returns at once."""
        ...

    def realign(self, k: int, position: np.ndarray) -> None:
        """The drone's INS is realigned to ``position`` (3,) m, its verified position at step k."""
        ...

    def close(self) -> None:
        """Release what the source holds (threads, sockets, files)."""
        ...


class ScenarioSource:
    """Drone ``index``'s readings computed from the scenario's world: its fix (receiver output,
    spoofed where spoofed) or, in an outage, its INS estimate; its row of the UWB ranges (a
    tampering drone's row as tampered); the world's innovation. The INS of every drone starts
    aligned to its true position; only this drone's is realigned (a process knows no other
    drone's verified alignments), as the host did before sources existed."""

    def __init__(self, world: ScenarioWorld, index: int) -> None:
        self.world, self.index = world, index
        self.base_t = np.zeros(world.sc.drones)
        self.base_pos = world.traj.positions[0].copy()

    def reading(self, k: int) -> Reading:
        w, i = self.world, self.index
        ins = w.ins_estimate(k, self.base_t, self.base_pos)
        ranges = w.measured_ranges(k, ins)[i]
        if w.has_fix[k, i]:
            return Reading(w.fix[k, i], "gnss", ranges, w.innovation(k, i), ins[i], w.innovations(k, i))
        return Reading(ins[i], "ins", ranges, None, ins[i])

    def realign(self, k: int, position: np.ndarray) -> None:
        self.base_t[self.index] = self.world.traj.t[k]
        self.base_pos[self.index] = position

    def close(self) -> None:
        pass


class SourceError(ValueError):
    """A source that cannot be opened (a bad log, a missing package, a busy port); one line."""


def open_source(swarm: SwarmFile, drone_id: int, world: ScenarioWorld) -> SensorSource:
    """Drone ``drone_id``'s source as its swarm file entry selects it (``[drones.N.source]``;
    the scenario's model by default). A source that cannot be opened raises SourceError."""
    config = swarm.drones[drone_id].source
    index, sc = drone_id - 1, world.sc
    if config.kind == "scenario":
        return ScenarioSource(world, index)
    if config.kind == "replay":
        from swarmraft.net.sources.replay import ReplaySource, SensorLogError, read_sensor_log

        try:
            log = read_sensor_log(config.log, sc.drones)
        except SensorLogError as exc:
            raise SourceError(str(exc)) from None
        windows = sc.protocol.drift_windows if world.protocol.drift is not None else 0
        return ReplaySource(log, index, sc.dt_s, world.window_steps * sc.dt_s, config.max_age_s, windows)
    from swarmraft.net.sources.mavlink import MavlinkSource

    assert swarm.origin is not None  # the swarm file requires it for a mavlink source
    return MavlinkSource.open(config, swarm.origin, drone_id, sc.drones)
