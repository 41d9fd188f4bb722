"""A mission scenario: typed, validated configuration (a TOML file maps onto it one to one).

Drone ids are 1..n everywhere in a scenario (as in the simulator). Defaults come from
docs/scenarios.md: GNSS 1.5/3 m with Gauss-Markov tau 120 s, UWB 0.10 m, drone-grade INS, 10 Hz steps,
5-10 m/s formation flight at 10-30 m spacing, 150-300 ms election timeouts with 10 ms ticks.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from swarmraft.estimation.registry import detector_params, get_detector
from swarmraft.protocol.committee import check_size

#: the fewest drones a swarm flies with: a join or a leave may never leave fewer in it
MIN_SWARM = 3
#: how many drones a scenario has (all of them, those that join later included)
SCENARIO_DRONES = (4, 256)

#: the faults that act on the drone they name: it must be in the swarm at that time
_ONE_DRONE = ("crash", "restart", "pause", "transfer-leader")

#: a scenario's name names its output folder: one path component, no leading dot
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._-]*$"


def shipped_scenarios() -> dict[str, Path]:
    """The scenarios shipped with the package (``swarmraft/scenarios/*.toml``), by name."""
    folder = resources.files("swarmraft") / "scenarios"
    return {
        p.name.removesuffix(".toml"): Path(str(p))
        for p in sorted(folder.iterdir(), key=lambda p: p.name)
        if p.name.endswith(".toml")
    }


def find_scenario(name_or_path: str | Path) -> Path:
    """The file a ``--scenario`` value stands for: an existing file, else the shipped scenario
    of that name (``demo`` or ``demo.toml``), else the path as given (reading it then fails
    naming it)."""
    path = Path(name_or_path)
    if path.is_file() or path.parent != Path("."):
        return path
    return shipped_scenarios().get(path.name.removesuffix(".toml"), path)


def _ids(ids: list[int]) -> str:
    return ", ".join(str(i) for i in ids)


def _repeated(ids: list[int]) -> list[int]:
    """The ids that occur more than once in ``ids``, sorted."""
    return sorted({i for i in ids if ids.count(i) > 1})


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class MotionConfig(_Strict):
    kind: Literal["formation", "static"] = "formation"
    spacing: float = Field(20.0, gt=0, description="m")
    speed: float = Field(7.0, ge=0, description="m/s")
    waypoints: list[tuple[float, float, float]] | None = None
    area_size: float = Field(100.0, gt=0, description="static cube side, m")

    @field_validator("waypoints")
    @classmethod
    def _path(cls, v: list | None) -> list | None:
        if v is not None and len(v) < 2:
            raise ValueError("give at least 2 waypoints (a path from the first to the last)")
        return v


class GNSSTimeConfig(_Strict):
    sigma_h: float = Field(1.5, ge=0)
    sigma_v: float = Field(3.0, ge=0)
    tau_s: float = Field(120.0, gt=0, description="Gauss-Markov correlation time")


class INSConfig(_Strict):
    grade: Literal["consumer", "drone-grade", "industrial", "tactical"] = "drone-grade"


class RangingTimeConfig(_Strict):
    sigma: float = Field(0.10, ge=0)
    max_range: float | None = Field(None, gt=0)
    nlos_prob: float = Field(0.0, ge=0, le=1)
    nlos_mode: Literal["link", "direction"] = Field(
        "link", description="NLOS bias drawn per link (both directions share it) or per direction"
    )


class NetworkConfig(_Strict):
    delay_ms: tuple[float, float] = (1.0, 3.0)
    loss: float = Field(0.0, ge=0, le=1)
    duplicate: float = Field(0.0, ge=0, le=1)
    reorder: float = Field(0.0, ge=0, le=1)

    @field_validator("delay_ms")
    @classmethod
    def _delay(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0 <= v[0] <= v[1]:
            raise ValueError(f"low {v[0]:g} ms is above high {v[1]:g} ms, or negative")
        return v


class RaftTimeConfig(_Strict):
    tick_ms: float = Field(10.0, gt=0)
    election_tick: int = Field(15, ge=2)
    heartbeat_tick: int = Field(5, ge=1)


class ProtocolTimeConfig(_Strict):
    detector: str = "joint"
    detector_params: dict[str, Any] = Field(default_factory=dict)
    deadline_ms: float = Field(60.0, gt=0, description="leader waits for reports this long")
    innovation_window_s: float = Field(5.0, gt=0, description="INS prediction window of the gate")
    innovation_gate: float = Field(25.9, ge=0, description="chi-square 3 dof threshold; 0: off")
    drift_windows: int = Field(
        8, ge=0, le=255, description="drag-off test: past innovation windows a report carries; 0: off"
    )
    drift_false_alarm: float = Field(
        1e-6, gt=0, lt=1, description="drag-off test: per-step probability an honest drone is found dragged"
    )
    drift_suspect: float = Field(
        1e-3, gt=0, lt=1, description="drag-off test: the same for suspect (INS track not re-aligned)"
    )
    committee: int = Field(
        0, ge=0, description="voters (odd, at most 7; the rest are Raft learners); 0: every drone votes"
    )
    committee_dead_after_s: float = Field(
        1.0, gt=0, description="a voter the leader has not heard from this long is replaced"
    )
    audit: bool = Field(True, description="voters audit every record before acknowledging it")
    censor_k: int = Field(10, ge=0, description="censorship: more than k omissions ...")
    censor_m: int = Field(20, ge=1, description="... in the last m records of a term")


class SpoofConfig(_Strict):
    kind: Literal["jump", "drag", "area", "collusion", "enlarge"]
    drones: list[int] = Field(min_length=1)
    start_s: float = Field(ge=0)
    end_s: float | None = None
    magnitude: float = Field(30.0, ge=0, description="jump or area offset, m")
    rate: float = Field(0.5, ge=0, description="drag-off rate, m/s")
    pivots: list[int] = Field(default_factory=list)
    angle_deg: float = 45.0
    tamper_ranges: bool = False
    same_direction: bool = Field(False, description="drag: every victim dragged in the first one's direction")
    enlarge: float = Field(
        0.0, ge=0, description="distance enlargement, m: every range a victim takes part in reads this long"
    )

    @model_validator(mode="after")
    def _enlarge(self) -> SpoofConfig:
        if self.kind == "enlarge" and not self.enlarge > 0:
            raise ValueError("enlarge: kind 'enlarge' needs enlarge > 0 (m)")
        if self.same_direction and self.kind != "drag":
            raise ValueError(f"same_direction: only a drag spoof has a direction to share, not {self.kind!r}")
        return self


class OutageConfig(_Strict):
    drones: list[int] = Field(min_length=1)
    start_s: float = Field(ge=0)
    end_s: float | None = None


class FaultConfig(_Strict):
    kind: Literal[
        "crash",
        "crash-leader",
        "restart",
        "pause",
        "partition",
        "heal",
        "loss",
        "transfer-leader",
        "lying-leader",
        "join",
        "leave",
    ]
    at_s: float = Field(ge=0)
    drone: int | None = None
    mode: Literal["move", "clear", "accuse", "censor"] | None = Field(None, description="lying-leader")
    offset_m: float | None = Field(None, gt=0, description="lying-leader move: shift east, m (None: 10)")
    groups: list[list[int]] = Field(default_factory=list)
    value: float | None = Field(None, ge=0, le=1, description="loss probability")
    for_s: float | None = Field(None, gt=0, description="pause: how long, s")


#: the fields each kind of spoof uses (enlarge and tamper_ranges go with any kind)
_SPOOF_FIELDS = {
    "magnitude": ("jump", "area"),
    "rate": ("drag",),
    "angle_deg": ("collusion",),
    "pivots": ("collusion",),
}
#: the fields each kind of fault uses (mode, offset_m and for_s are checked in `Scenario`)
_FAULT_FIELDS = {
    "drone": ("crash", "restart", "pause", "transfer-leader", "lying-leader", "join", "leave"),
    "groups": ("partition",),
    "value": ("loss",),
}


def _unused(model: BaseModel, uses: dict[str, tuple[str, ...]], kind: str, where: str) -> None:
    """A one-line error for a field of ``model`` set to other than its default that its
    ``kind`` does not use (it was ignored, so the scenario meant something other than it says)."""
    for name, kinds in uses.items():
        default = type(model).model_fields[name].get_default(call_default_factory=True)
        # a default written out (a results folder's scenario.json has every field) is no claim
        if kind not in kinds and getattr(model, name) != default:
            noun = type(model).__name__.removesuffix("Config").lower()
            raise ValueError(f"{where}.{name}: a {kind} {noun} does not use it (only {', '.join(kinds)})")


def _overlap(a: SpoofConfig | OutageConfig, b: SpoofConfig | OutageConfig) -> list[int]:
    """The drones ``a`` and ``b`` both act on at some moment ([start_s, end_s), None: open to
    the mission's end); [] if none."""
    meet = (a.end_s is None or b.start_s < a.end_s) and (b.end_s is None or a.start_s < b.end_s)
    return sorted(set(a.drones) & set(b.drones)) if meet else []


def _span(start: float, end: float | None) -> str:
    return f"from {start:g} s" + ("" if end is None else f" to {end:g} s")


def _check_overlaps(spoofs: list[SpoofConfig], outages: list[OutageConfig]) -> None:
    """No drone spoofed by two spoofs at once (the later one replaced the earlier, which was
    still scored), and none spoofed while an outage leaves it without a GNSS fix (it reported
    INS: nothing was spoofed, and the spoof was scored as missed). Jamming then spoofing is
    an outage that ends when the spoof starts."""
    # an `enlarge` spoof leaves GNSS alone (it lengthens the ranges): it replaces no position
    # spoof and needs no fix, so it may overlap both
    position = [(k, s) for k, s in enumerate(spoofs) if s.kind != "enlarge"]
    for k, s in position:
        for j, t in position:
            if j < k and (both := _overlap(s, t)):
                raise ValueError(
                    f"spoof[{k}].drones: drone {_ids(both)} is spoofed by spoof[{j}] "
                    f"{_span(t.start_s, t.end_s)} already (one spoof of a drone at a time)"
                )
    for k, o in enumerate(outages):
        for j, s in position:
            if both := _overlap(o, s):
                raise ValueError(
                    f"outage[{k}].drones: drone {_ids(both)} has no GNSS fix {_span(o.start_s, o.end_s)} "
                    f"while spoof[{j}] spoofs it {_span(s.start_s, s.end_s)}: a drone without a fix "
                    "has nothing to spoof (to jam, then spoof, end the outage as the spoof starts)"
                )


class Scenario(_Strict):
    name: str = Field("mission", pattern=NAME_PATTERN, description="names the output folder")
    seed: int = Field(1, ge=0)
    drones: int = Field(9, ge=SCENARIO_DRONES[0], le=SCENARIO_DRONES[1])
    duration_s: float = Field(60.0, gt=0)
    dt_s: float = Field(0.1, gt=0, description="step, s (10 Hz)")
    motion: MotionConfig = Field(default_factory=MotionConfig)
    gnss: GNSSTimeConfig = Field(default_factory=GNSSTimeConfig)
    ins: INSConfig = Field(default_factory=INSConfig)
    ranging: RangingTimeConfig = Field(default_factory=RangingTimeConfig)
    network: NetworkConfig = Field(default_factory=NetworkConfig)
    raft: RaftTimeConfig = Field(default_factory=RaftTimeConfig)
    protocol: ProtocolTimeConfig = Field(default_factory=ProtocolTimeConfig)
    spoof: list[SpoofConfig] = Field(default_factory=list)
    outage: list[OutageConfig] = Field(default_factory=list)
    fault: list[FaultConfig] = Field(default_factory=list)
    maps_at_s: list[float] = Field(default_factory=list, description="swarm maps at these times")

    @model_validator(mode="after")
    def _ids(self) -> Scenario:
        def check(ids: list[int], where: str) -> None:
            bad = [i for i in ids if not 1 <= i <= self.drones]
            if bad:
                raise ValueError(f"{where}: drone ids must be in 1..{self.drones}, got {bad}")
            if twice := _repeated(ids):
                raise ValueError(f"{where}: drone {_ids(twice)} twice")

        def timed(start: float, end: float | None, where: str, field: str = "start_s") -> None:
            if start >= self.duration_s:
                raise ValueError(
                    f"{where}.{field}: {start:g} s is not before the mission's end ({self.duration_s:g} s)"
                )
            if end is not None and end <= start:
                raise ValueError(f"{where}.end_s: {end:g} s is not after start_s = {start:g} s")

        if self.dt_s > self.duration_s:
            raise ValueError(
                f"dt_s: a step of {self.dt_s:g} s is longer than the mission ({self.duration_s:g} s)"
            )
        if abs(self.duration_s / self.dt_s - self.steps) > 1e-6:
            raise ValueError(
                f"dt_s: {self.dt_s:g} s does not divide duration_s = {self.duration_s:g} s into whole "
                "steps (the motion and the steps would not share one time grid)"
            )
        for k, s in enumerate(self.spoof):
            timed(s.start_s, s.end_s, f"spoof[{k}]")
            check(s.drones, f"spoof[{k}].drones")
            check(s.pivots, f"spoof[{k}].pivots")
            if both := sorted(set(s.pivots) & set(s.drones)):
                raise ValueError(
                    f"spoof[{k}].pivots: a pivot is an honest drone, and {_ids(both)} is spoofed"
                )
            if s.kind == "collusion" and not 1 <= len(s.pivots) <= 3:
                raise ValueError(f"spoof[{k}].pivots: collusion needs 1 to 3 pivot drones")
            _unused(s, _SPOOF_FIELDS, s.kind, f"spoof[{k}]")
        for k, o in enumerate(self.outage):
            timed(o.start_s, o.end_s, f"outage[{k}]")
            check(o.drones, f"outage[{k}].drones")
        _check_overlaps(self.spoof, self.outage)
        for k, f in enumerate(self.fault):
            timed(f.at_s, None, f"fault[{k}]", "at_s")
            _unused(f, _FAULT_FIELDS, f.kind, f"fault[{k}]")
            if f.kind in ("crash", "restart", "lying-leader", "join", "leave") and f.drone is None:
                raise ValueError(f"fault[{k}].drone: {f.kind} needs a drone")
            if f.kind == "lying-leader" and f.mode is None:
                raise ValueError(f"fault[{k}].mode: lying-leader needs one of move, clear, accuse, censor")
            if f.kind != "lying-leader" and f.mode is not None:
                raise ValueError(f"fault[{k}].mode: only a lying-leader fault has a mode")
            if f.offset_m is not None and f.mode != "move":
                raise ValueError(f"fault[{k}].offset_m: only a lying-leader move has an offset")
            if f.kind == "lying-leader" and not self.protocol.audit:
                raise ValueError(f"fault[{k}].kind: lying-leader needs protocol.audit = true")
            if f.drone is not None:
                check([f.drone], f"fault[{k}].drone")
            if f.kind == "partition":
                if not f.groups:
                    raise ValueError(f"fault[{k}].groups: a partition needs groups")
                for g in f.groups:
                    check(g, f"fault[{k}].groups")
                members = [d for g in f.groups for d in g]
                if twice := _repeated(members):
                    raise ValueError(
                        f"fault[{k}].groups: drone {_ids(twice)} is in two groups (it would bridge them: "
                        "no partition)"
                    )
            if f.kind == "loss" and f.value is None:
                raise ValueError(f"fault[{k}].value: loss needs a value")
            if f.kind == "pause" and f.for_s is None:
                raise ValueError(f"fault[{k}].for_s: pause needs a duration")
            if f.kind != "pause" and f.for_s is not None:
                raise ValueError(f"fault[{k}].for_s: only a pause has a duration")
        if outside := [t for t in self.maps_at_s if not 0 <= t <= self.duration_s]:
            # a negative time drew a map counted from the end, a late one the last step's
            raise ValueError(f"maps_at_s: {outside} outside the mission (0 to {self.duration_s:g} s)")
        k, m = self.protocol.censor_k, self.protocol.censor_m
        if k >= m:
            raise ValueError(f"protocol.censor_k: {k} must be below censor_m = {m}")
        if self.protocol.committee:
            try:
                check_size(self.protocol.committee)
            except ValueError as exc:
                raise ValueError(f"protocol.committee: {exc}") from None
        self._check_membership()
        if sum(f.kind == "lying-leader" for f in self.fault) > 1:
            raise ValueError("fault: at most one lying-leader fault")
        if self.raft.heartbeat_tick >= self.raft.election_tick:
            raise ValueError("raft.heartbeat_tick: must be below election_tick")
        try:
            get_detector(self.protocol.detector)
        except ValueError as exc:
            raise ValueError(f"protocol.{exc}") from None
        try:
            detector_params(self.protocol.detector, **self.protocol.detector_params)
        except ValueError as exc:
            raise ValueError(f"protocol.detector_params: {exc}") from None
        return self

    def _check_membership(self) -> None:
        """Joins and leaves, in time order (faults at the same time in list order): a drone
        with a join is outside the swarm until it; a join is for a drone outside the swarm, a
        leave for one in it (for good: no join after it); at least `MIN_SWARM` drones in the
        swarm at every moment; the faults that act on one drone (crash, restart, pause,
        transfer-leader) name a drone in the swarm at that time."""
        joiners = {f.drone for f in self.fault if f.kind == "join"}
        swarm = set(range(1, self.drones + 1)) - joiners
        if joiners and len(swarm) < MIN_SWARM:
            k = next(k for k, f in enumerate(self.fault) if f.kind == "join")
            raise ValueError(
                f"fault[{k}].drone: with {len(joiners)} drones joining later only {len(swarm)} are in "
                f"the swarm at the start; at least {MIN_SWARM}"
            )
        left: set[int] = set()
        order = sorted(range(len(self.fault)), key=lambda k: self.fault[k].at_s)
        for k in order:
            f = self.fault[k]
            d, at = f.drone, f"{f.at_s:g} s"
            if f.kind == "join":
                if d in left:
                    raise ValueError(f"fault[{k}].drone: drone {d} left the swarm for good before {at}")
                if d in swarm:
                    raise ValueError(
                        f"fault[{k}].drone: drone {d} is in the swarm at {at} already "
                        "(a join is for a drone outside it: one joins once, at most)"
                    )
                swarm.add(d)
            elif f.kind == "leave":
                if d not in swarm:
                    why = "left already" if d in left else "has not joined yet"
                    raise ValueError(f"fault[{k}].drone: drone {d} is not in the swarm at {at} ({why})")
                if len(swarm) - 1 < MIN_SWARM:
                    raise ValueError(
                        f"fault[{k}].drone: after drone {d} leaves at {at} only {len(swarm) - 1} drones "
                        f"are in the swarm; at least {MIN_SWARM} must stay"
                    )
                swarm.discard(d)
                left.add(d)
            elif d is not None and d not in swarm and f.kind in _ONE_DRONE:
                raise ValueError(f"fault[{k}].drone: drone {d} is not in the swarm at {at} ({f.kind})")

    @property
    def joiners(self) -> set[int]:
        """Drones outside the swarm at the start (each joins with a ``join`` fault)."""
        return {f.drone for f in self.fault if f.kind == "join"}

    @property
    def dynamic(self) -> bool:
        """Whether drones join or leave during the mission."""
        return any(f.kind in ("join", "leave") for f in self.fault)

    @property
    def steps(self) -> int:
        return int(round(self.duration_s / self.dt_s))


def with_detector(sc: Scenario, name: str) -> Scenario:
    """``sc`` flown with another detector (the command line's ``--detector``), its parameters
    checked against it; a bad one is a one-line ValueError naming ``--detector``."""
    try:
        detector_params(name, **sc.protocol.detector_params)
    except ValueError as exc:
        raise ValueError(f"--detector: {str(exc).removeprefix('detector: ')}") from None
    return sc.model_copy(update={"protocol": sc.protocol.model_copy(update={"detector": name})})
