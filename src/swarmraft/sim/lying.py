"""The `lying-leader` fault's lies (docs/audit.md): what a compromised leader does to its
records (`falsify`) and to the reports it receives (`drops_report`). Shared by the simulator's
missions (`sim.mission`) and the networked runtime (`net.node`), so a lie is the same in both."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from swarmraft.protocol import Report, StepRecord
from swarmraft.sim.scenario import FaultConfig

#: how far a `move` lie shifts its drone east, m, where the fault gives no ``offset_m``
MOVE_OFFSET_M = 10.0


def move_offset(fault: FaultConfig) -> float | None:
    """The east shift of a `move` lie, m (the fault's, or the default); None for other modes."""
    return (fault.offset_m or MOVE_OFFSET_M) if fault.mode == "move" else None


def falsify(rec: StepRecord, fault: FaultConfig) -> StepRecord | None:
    """The lying leader's record in place of the honest ``rec`` (None where the mode changes
    nothing: clearing a drone that is not flagged, accusing one that is; censoring is done on
    receipt, `drops_report`)."""
    d = fault.drone - 1
    if fault.mode == "move":
        pos = rec.positions.copy()
        pos[d] = np.where(np.isfinite(pos[d]), pos[d], 0.0) + [move_offset(fault), 0.0, 0.0]
        return replace(rec, positions=pos)
    if fault.mode in ("clear", "accuse") and bool(rec.faulty[d]) == (fault.mode == "clear"):
        flags = rec.faulty.copy()
        flags[d] = fault.mode == "accuse"
        return replace(rec, faulty=flags)
    return None


def drops_report(fault: FaultConfig, report: Report) -> bool:
    """Whether the lying leader drops ``report`` on receipt (mode ``censor``: the named
    drone's reports)."""
    return fault.mode == "censor" and report.drone == fault.drone - 1
