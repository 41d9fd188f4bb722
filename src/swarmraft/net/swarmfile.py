"""The swarm file (``swarm.toml``): everything a drone process needs to join its swarm, as one
validated model, `SwarmFile`; `load_swarm(path)` reads it, every error one line naming the
field (`SwarmFileError`).

Per drone id (1..n): the address it binds its UDP socket to and the address its peers send
to (separate, for NAT and for binding 0.0.0.0), and its private key file; for the swarm: the
public keys file, the scenario (a shipped name or a path) with an optional seed and step
length overriding the scenario's, the Raft tick in ms, the wall-clock time step 0 starts, and
the folder each drone writes its files to. Relative paths are relative to the swarm file's
folder. See docs/net.md for an example.

Per drone, optionally, where its sensor readings come from (``[drones.N.source]``, `SourceConfig`:
the scenario's model, a recorded log, or MAVLink; docs/records.md), and for MAVLink sources the
swarm's geodetic ``[origin]``, the point the local ENU frame starts from.
"""

from __future__ import annotations

import ipaddress
import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from swarmraft.estimation.registry import one_line
from swarmraft.net.tomlfile import read_toml

FORMAT_VERSION = 1

Address = tuple[str, int]


class SwarmFileError(ValueError):
    """A swarm file that is missing, not TOML or invalid; one line naming the file and field."""


def drone_file(folder: str | Path, drone: int, kind: str) -> Path:
    """A drone's file in the swarm's ``out`` folder: ``drone-<id>.<kind>``, kind one of
    ``sqlite``, ``steps.jsonl``, ``events.jsonl``, ``sent.csv``, ``log`` (docs/net.md)."""
    return Path(folder) / f"drone-{drone}.{kind}"


def _bind_address(v: str) -> str:
    parse_address(v, bind=True)
    return v


def _peer_address(v: str) -> str:
    parse_address(v, bind=False)
    return v


#: host:port text, checked as an address to bind (the any-address allowed) or to send to.
BindAddress = Annotated[str, AfterValidator(_bind_address)]
PeerAddress = Annotated[str, AfterValidator(_peer_address)]


def parse_address(text: str, *, bind: bool) -> Address:
    """``host:port`` (``[v6]:port`` for IPv6) with a numeric IP host and a port in 1..65535;
    ``bind`` allows the any-address (0.0.0.0, ::), which cannot be sent to."""
    host, sep, port_text = str(text).rpartition(":")
    if not sep or not host:
        raise ValueError(f"{text!r} is not host:port")
    host = host.removeprefix("[").removesuffix("]")
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        raise ValueError(f"{host!r} is not a numeric IP address (no names: no send waits on DNS)") from None
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"port {port_text!r} is not in 1..65535")
    if ip.is_unspecified and not bind:
        raise ValueError(f"{host} is the any-address: peers cannot send to it")
    return str(ip), int(port_text)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class ScenarioSourceConfig(_Strict):
    kind: Literal["scenario"] = Field("scenario", description="readings computed from the scenario (default)")


class ReplaySourceConfig(_Strict):
    kind: Literal["replay"] = Field(description="readings replayed from a recorded log")
    log: Path = Field(description="the sensor log (CSV, docs/records.md)")
    max_age_s: float = Field(1.0, gt=0, description="a drone's last line older than this gives no reading, s")


class MavlinkSourceConfig(_Strict):
    kind: Literal["mavlink"] = Field(description="a live fix over MAVLink, ranges over UDP lines")
    connect: str = Field(min_length=1, description="pymavlink connection string, e.g. udpin:0.0.0.0:14550")
    ranges: BindAddress = Field(description="host:port the range lines arrive at (UDP)")
    max_age_s: float = Field(1.0, gt=0, description="a fix or range older than this is not used, s")

    @property
    def ranges_address(self) -> Address:
        return parse_address(self.ranges, bind=True)


SourceConfig = Annotated[
    ScenarioSourceConfig | ReplaySourceConfig | MavlinkSourceConfig, Field(discriminator="kind")
]


class GeodeticOrigin(_Strict):
    lat_deg: float = Field(ge=-90, le=90, description="WGS84 latitude of the local frame's origin, degrees")
    lon_deg: float = Field(ge=-180, le=180, description="WGS84 longitude, degrees")
    alt_m: float = Field(0.0, description="altitude of the origin, m (the datum GPS_RAW_INT's alt uses: MSL)")


class DroneEntry(_Strict):
    bind: BindAddress = Field(description="host:port its UDP socket binds (0.0.0.0:port: every interface)")
    advertise: PeerAddress = Field(description="host:port its peers send to")
    key: Path = Field(description="its private key file (drone-<id>.key, mode 0600)")
    source: SourceConfig = Field(default_factory=ScenarioSourceConfig, description="its sensor readings")

    @property
    def bind_address(self) -> Address:
        return parse_address(self.bind, bind=True)

    @property
    def advertise_address(self) -> Address:
        return parse_address(self.advertise, bind=False)


class SwarmFile(_Strict):
    version: int = Field(FORMAT_VERSION, description="format version")
    scenario: str = Field(min_length=1, description="a shipped scenario's name or a scenario file")
    seed: int | None = Field(None, ge=0, description="overrides the scenario's seed")
    step_s: float | None = Field(None, gt=0, description="step length, s; overrides the scenario's dt_s")
    tick_ms: float = Field(10.0, ge=1, le=1000, description="Raft tick, ms (the scenario's raft.tick_ms)")
    start_unix_s: float = Field(gt=0, description="wall-clock time (Unix, s) at which step 0 starts")
    public_keys: Path = Field(description="swarm-keys.toml, every drone's public key")
    out: Path = Field(Path("."), description="folder for each drone's SQLite, step and event files")
    drones: dict[int, DroneEntry] = Field(min_length=1)
    origin: GeodeticOrigin | None = Field(None, description="geodetic origin of the local ENU frame")
    code_sha256: str | None = Field(
        None,
        description="SHA-256 of the swarmraft source files every drone must run (`swarmraft launch` "
        "writes the one it runs; a node with other code refuses to start); unset: not checked",
    )

    @field_validator("version")
    @classmethod
    def _version(cls, v: int) -> int:
        if v != FORMAT_VERSION:
            raise ValueError(f"version {v}; this program reads version {FORMAT_VERSION}")
        return v

    @field_validator("code_sha256")
    @classmethod
    def _code(cls, v: str | None) -> str | None:
        if v is not None and not re.fullmatch(r"[0-9a-f]{64}", v):
            raise ValueError(f"{v!r} is not a SHA-256 (64 lowercase hex digits)")
        return v

    @model_validator(mode="after")
    def _ids(self) -> SwarmFile:
        ids = sorted(self.drones)
        if ids != list(range(1, len(ids) + 1)):
            raise ValueError(f"drones: ids must be 1..{len(ids)}, got {', '.join(map(str, ids))}")
        seen: dict[Address, int] = {}
        for i in ids:
            addr = self.drones[i].advertise_address
            if addr in seen:
                raise ValueError(
                    f"drones.{i}.advertise: {self.drones[i].advertise} is drone {seen[addr]}'s too"
                )
            seen[addr] = i
            if self.drones[i].source.kind == "mavlink" and self.origin is None:
                raise ValueError(
                    f"drones.{i}.source: a mavlink source needs the swarm's [origin] "
                    "(lat_deg, lon_deg, alt_m of the local frame's origin)"
                )
        return self

    def resolved(self, base: Path) -> SwarmFile:
        """The same swarm with its relative paths (keys, out, a scenario file) made relative to
        ``base`` (the swarm file's folder). A scenario is a file when its value has a folder or
        ends in .toml."""
        base = Path(base)

        def at(p: Path) -> Path:
            return p if p.is_absolute() else base / p

        scenario = self.scenario
        if "/" in scenario or scenario.endswith(".toml"):
            scenario = str(at(Path(scenario)))

        def entry(d: DroneEntry) -> DroneEntry:
            src = d.source
            if isinstance(src, ReplaySourceConfig):
                src = src.model_copy(update={"log": at(src.log)})
            return d.model_copy(update={"key": at(d.key), "source": src})

        drones = {i: entry(d) for i, d in self.drones.items()}
        return self.model_copy(
            update={
                "public_keys": at(self.public_keys),
                "out": at(self.out),
                "scenario": scenario,
                "drones": drones,
            }
        )

    def peers(self, own: int) -> dict[int, Address]:
        """Every other drone's advertised address, by id."""
        return {i: d.advertise_address for i, d in self.drones.items() if i != own}


def load_swarm(path: str | Path) -> SwarmFile:
    """The swarm file at ``path``, validated, its relative paths resolved against its folder."""
    path = Path(path)
    data = read_toml(path, SwarmFileError)
    # TOML keys are strings: drone ids must be integers
    drones = data.get("drones")
    if isinstance(drones, dict):
        bad = [k for k in drones if not str(k).isdigit()]
        if bad:
            raise SwarmFileError(f"{path}: drones.{bad[0]}: a drone id is an integer >= 1")
        data["drones"] = {int(k): v for k, v in drones.items()}
    try:
        swarm = SwarmFile.model_validate(data)
    except ValidationError as exc:
        # drones are a table keyed by id ([drones.1]), named as the file spells them
        raise SwarmFileError(
            f"{path}: {_source_paths(one_line(exc, '', SwarmFile, brackets=False))}"
        ) from None
    return swarm.resolved(path.parent)


def _source_paths(text: str) -> str:
    """A source's fields named as the file spells them (pydantic puts the kind in the path)."""
    text = re.sub(r"\.source\.(scenario|replay|mavlink)\.", ".source.", text)
    text = text.replace(
        "Unable to extract tag using discriminator 'kind'", "no kind (scenario, replay or mavlink)"
    )
    return re.sub(
        r"Input tag ('[^']*') found using 'kind' does not match any of the expected tags: [^;]*",
        r"kind: \1 is not scenario, replay or mavlink",
        text,
    )


def swarm_file_text(swarm: SwarmFile) -> str:
    """``swarm`` as a swarm.toml (paths as they are held: give relative ones for a portable file)."""

    def q(v: object) -> str:
        return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'

    lines = [
        "# A SwarmRaft swarm: `swarmraft node --id I --swarm THIS_FILE` runs drone I (docs/net.md).",
        f"version = {swarm.version}",
        f"scenario = {q(swarm.scenario)}",
    ]
    if swarm.seed is not None:
        lines.append(f"seed = {swarm.seed}")
    if swarm.step_s is not None:
        lines.append(f"step_s = {swarm.step_s!r}")
    lines += [
        f"tick_ms = {swarm.tick_ms!r}",
        f"start_unix_s = {swarm.start_unix_s!r}",
        f"public_keys = {q(swarm.public_keys)}",
        f"out = {q(swarm.out)}",
    ]
    if swarm.code_sha256 is not None:
        lines.append(f"code_sha256 = {q(swarm.code_sha256)}  # the swarmraft code every drone must run")
    if swarm.origin is not None:
        o = swarm.origin
        lines += [
            "",
            "[origin]",
            f"lat_deg = {o.lat_deg!r}",
            f"lon_deg = {o.lon_deg!r}",
            f"alt_m = {o.alt_m!r}",
        ]
    for i, d in sorted(swarm.drones.items()):
        lines += [
            "",
            f"[drones.{i}]",
            f"bind = {q(d.bind)}",
            f"advertise = {q(d.advertise)}",
            f"key = {q(d.key)}",
        ]
        if d.source.kind != "scenario":
            lines += ["", f"[drones.{i}.source]"]
            for name, value in d.source.model_dump().items():
                lines.append(f"{name} = {q(value) if isinstance(value, str | Path) else repr(value)}")
    return "\n".join(lines) + "\n"
