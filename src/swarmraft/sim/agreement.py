"""Whether every drone applied the same record for each step, in memory bounded over any
length of mission (issue 12, item 4).

`RecordAgreement` is told every record a drone applies (its step, its digest and the Raft
index of its entry). For each step still *open* it keeps the first digest applied and the
entry's index; a record whose digest differs from the step's first is a disagreement, kept in
full. A step is closed (forgotten) once no drone can apply it again: the host decides that
with `prune` (`sim.mission` asks the Raft storages; see `Mission._prune_agreement`), so what
is held is bounded by the Raft logs' size, not by the mission's length. The verdict is that of
comparing every drone's full list of (step, digest): a record for a closed step could only
come from an entry no storage holds any more, which no drone can apply.

Per drone it also counts the records applied and those whose step was not above the highest
the drone had applied (a replay after a restart, or records out of order).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Disagreement:
    """Drone ``node`` applied ``digest`` for ``step`` where the step's first record was ``first``."""

    step: int
    node: int
    digest: str
    first: str


@dataclass
class RecordAgreement:
    """The identical-records check over every record applied (see the module's text)."""

    open: dict[int, tuple[str, int]] = field(default_factory=dict)  # step -> (first digest, index)
    disagreements: list[Disagreement] = field(default_factory=list)
    applied: dict[int, int] = field(default_factory=dict)  # node -> records applied
    repeats: dict[int, int] = field(default_factory=dict)  # node -> records not above its highest step
    highest: dict[int, int] = field(default_factory=dict)  # node -> highest step it applied
    closed_max: int = -1  # the highest step closed (-1: none yet)
    checked: int = 0  # records compared with their step's first

    def note(self, node: int, step: int, digest: str, index: int = 0) -> None:
        """Drone ``node`` applied ``digest`` for ``step`` from the entry at ``index``."""
        self.applied[node] = self.applied.get(node, 0) + 1
        if step <= self.highest.get(node, -1):
            self.repeats[node] = self.repeats.get(node, 0) + 1
        else:
            self.highest[node] = step
        first = self.open.get(step)
        if first is None:
            if step <= self.closed_max:
                # Drones apply the same records in the same order (a drone given a snapshot
                # skips some), so a step's first record comes before any later step's: one
                # below a closed step was closed, and only an entry no storage held could
                # bring it back. The host's prune was wrong: loud, never a silent pass.
                raise AssertionError(
                    f"agreement: drone {node} applied a record for step {step}, closed already"
                )
            self.open[step] = (digest, index)
            return
        self.checked += 1
        if digest != first[0]:
            self.disagreements.append(Disagreement(step, node, digest, first[0]))
        if index > first[1]:
            self.open[step] = (first[0], index)

    def prune(self, can_apply: Callable[[int, int], bool]) -> int:
        """Close every open step for which ``can_apply(step, index)`` is False (no drone can
        apply a record of that step from the entry at that index any more); returns how many
        were closed."""
        gone = [step for step, (_, index) in self.open.items() if not can_apply(step, index)]
        for step in gone:
            del self.open[step]
        self.closed_max = max(gone, default=self.closed_max)
        return len(gone)

    @property
    def identical(self) -> bool:
        """True when every drone applied the same record for every step both applied."""
        return not self.disagreements

    def held(self) -> int:
        """Items kept (open steps, disagreements, per-drone counters): constant in a long
        mission once the logs are compacted."""
        per_drone = len(self.applied) + len(self.repeats) + len(self.highest)
        return len(self.open) + len(self.disagreements) + per_drone
