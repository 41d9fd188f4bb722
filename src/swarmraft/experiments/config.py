"""Typed, validated sweep configuration and the two presets of docs/models.md.

Bad input is a one-line ``ConfigError`` naming the field (``gnss.sigma_h: ...``).
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from swarmraft.estimation.integrity import IntegrityParams, resolve_f_max
from swarmraft.estimation.registry import (
    check_known_set,
    detector_params,
    get_detector,
    load_plugins,
    one_line,
    same_function,
)
from swarmraft.world import (
    AreaSpoof,
    Attack,
    DistanceEnlargement,
    ExactRanging,
    GNSSModel,
    Jump,
    RangeTamper,
    RigidCollusion,
    RSSIRanging,
    UWBRanging,
)

PRESETS = ("reference", "realistic")
#: the built-in attacks; more register with `register_attack` (docs/models.md, "Writing an attack")
ATTACKS = (
    "jump",
    "range-tamper",
    "range-bias",
    "collusion-1",
    "collusion-2",
    "collusion-3",
    "area",
    "enlarge",
    "enlarge-jump",
)


class ConfigError(ValueError):
    """A configuration problem, as one line naming the field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class GNSSConfig(_Strict):
    """Honest GNSS error per axis, m (docs/models.md realistic: 1.5 m horizontal, 3 m vertical)."""

    sigma_h: float = Field(1.5, ge=0)
    sigma_v: float = Field(3.0, ge=0)
    common_h: float = Field(0.0, ge=0, description="component common to all drones")
    common_v: float = Field(0.0, ge=0)

    def model(self) -> GNSSModel:
        return GNSSModel(self.sigma_h, self.sigma_v, self.common_h, self.common_v)


class RangingConfig(_Strict):
    """Ranging: ``exact`` (reference code), ``uwb`` (docs/models.md: 0.10 m) or ``rssi``."""

    kind: Literal["exact", "uwb", "rssi"] = "uwb"
    sigma: float = Field(0.10, ge=0, description="UWB sigma, m")
    max_range: float | None = Field(None, gt=0, description="no range beyond, m")
    nlos_prob: float = Field(0.0, ge=0, le=1)
    nlos_bias: tuple[float, float] = (0.3, 1.0)
    nlos_mode: Literal["link", "direction"] = Field(
        "link", description="NLOS bias drawn per link (both directions share it) or per direction"
    )
    symmetric: bool = False
    shadowing_db: float = Field(6.0, ge=0, description="RSSI shadowing, dB")
    exponent: float = Field(2.5, gt=0, description="RSSI path-loss exponent")

    def model(self) -> ExactRanging | UWBRanging | RSSIRanging:
        if self.kind == "exact":
            return ExactRanging(self.max_range)
        if self.kind == "uwb":
            return UWBRanging(
                self.sigma, self.max_range, self.nlos_prob, self.nlos_bias, self.symmetric, self.nlos_mode
            )
        return RSSIRanging(self.shadowing_db, self.exponent, self.max_range, self.symmetric)

    @property
    def sigma_for_snapshot(self) -> float | None:
        return {"exact": 0.0, "uwb": self.sigma}.get(self.kind)


ATTACK_PLUGIN_GROUP = "swarmraft.attacks"


@dataclass(frozen=True)
class AttackPlugin:
    """A registered attack: ``make(config) -> Attack`` from the sweep's `AttackConfig` (its
    fields, and ``params`` for the attack's own settings), and how many honest drones it
    needs (a collusion's pivots)."""

    make: Callable[[AttackConfig], Attack]
    min_honest: int


_ATTACK_PLUGINS: dict[str, AttackPlugin] = {}


def register_attack(name: str, min_honest: int = 0) -> Callable[[Callable], Callable]:
    """Decorator: a function ``(AttackConfig) -> world.Attack`` becomes the attack ``name`` of
    every sweep, comparison and ``--attack``; its source counts in a sweep's code hash.
    From Python once its module is imported, from the command line and a sweep's workers
    through the entry-point group ``swarmraft.attacks``."""
    if name in ATTACKS:
        raise ValueError(f"attack {name!r} is built in")

    def wrap(make: Callable) -> Callable:
        old = _ATTACK_PLUGINS.get(name)
        if old is not None and not same_function(old.make, make):
            raise ValueError(f"attack {name!r} is already registered (by {old.make.__module__})")
        _ATTACK_PLUGINS[name] = AttackPlugin(make, min_honest)
        return make

    return wrap


def attack_plugin(name: str) -> AttackPlugin | None:
    """The registered attack ``name`` (None for a built-in one), loading the plugins first."""
    if name in ATTACKS:
        return None
    load_plugins(ATTACK_PLUGIN_GROUP, "attack")
    return _ATTACK_PLUGINS.get(name)


def attack_names() -> list[str]:
    """The built-in attacks, then the registered ones."""
    load_plugins(ATTACK_PLUGIN_GROUP, "attack")
    return [*ATTACKS, *sorted(_ATTACK_PLUGINS)]


class AttackConfig(_Strict):
    """Which attack and its parameters. ``jump``: independent jumps (``box`` half width or
    ``shell`` low-high magnitude); ``range-tamper``: jumps plus ranges consistent with the
    fake reports; ``range-bias``: jumps plus a bias on the attackers' ranges;
    ``collusion-k``: rigid motion about k honest pivots (every attacker moved at least
    ``min_move`` m); ``area``: all report one point;
    ``enlarge``: distance enlargement of ``enlarge_low``-``enlarge_high`` m per attacker (every
    range it takes part in reads long), its GNSS honest; ``enlarge-jump``: the same plus jumps."""

    name: str = "jump"
    jump: Literal["box", "shell"] = "box"
    half_width: float = Field(30.0, ge=0)
    low: float = Field(10.0, ge=0)
    high: float = Field(100.0, ge=0)
    bias: float = 5.0
    angle_deg: tuple[float, float] = (20.0, 90.0)
    min_move: float = Field(0.0, ge=0, description="collusion-k: every attacker moved at least this far, m")
    enlarge_low: float = Field(2.0, ge=0, description="distance enlargement per attacker, low end, m")
    enlarge_high: float = Field(10.0, ge=0, description="distance enlargement per attacker, high end, m")
    params: dict[str, Any] = Field(default_factory=dict, description="a registered attack's own settings")

    @field_validator("name")
    @classmethod
    def _known(cls, name: str) -> str:
        if name not in ATTACKS and attack_plugin(name) is None:
            raise ValueError(f"unknown attack {name!r}; known: {', '.join(attack_names())}")
        return name

    @model_validator(mode="after")
    def _order(self) -> AttackConfig:
        if self.params and self.name in ATTACKS:  # settings nothing would read
            raise ValueError(f"params: the built-in attack {self.name!r} takes none")
        if self.high < self.low:
            raise ValueError("high must be >= low")
        if self.enlarge_high < self.enlarge_low:
            raise ValueError("enlarge_high must be >= enlarge_low")
        return self

    def model(self) -> Attack:
        plugin = attack_plugin(self.name)
        if plugin is not None:
            attack = plugin.make(self)
            if not isinstance(attack, Attack):
                raise ValueError(
                    f"attack {self.name!r}: its function returned {type(attack).__name__}, not an Attack"
                )
            return attack
        jump = Jump(self.jump, self.half_width, self.low, self.high)
        if self.name == "jump":
            return Attack(jump)
        if self.name == "range-tamper":
            return Attack(jump, RangeTamper("consistent"))
        if self.name == "range-bias":
            return Attack(jump, RangeTamper("bias", self.bias))
        if self.name == "area":
            return Attack(AreaSpoof(self.low, self.high))
        if self.name.startswith("enlarge"):
            delay = DistanceEnlargement(self.enlarge_low, self.enlarge_high)
            return Attack(jump if self.name == "enlarge-jump" else None, enlargement=delay)
        return Attack(RigidCollusion(int(self.name[-1]), self.angle_deg, self.min_move))  # type: ignore[arg-type]

    @property
    def min_honest(self) -> int:
        plugin = attack_plugin(self.name)
        if plugin is not None:
            return plugin.min_honest
        return int(self.name[-1]) if self.name.startswith("collusion") else 0


class SweepConfig(_Strict):
    """A Monte Carlo sweep over swarm size n and attacker count f."""

    preset: Literal[PRESETS] = "reference"  # type: ignore[valid-type]
    n: tuple[int, ...] = Field((3, 5, 7, 9, 11, 13, 15, 17), min_length=1)
    f: tuple[int, ...] | None = Field(None, description="attacker counts; default every f")
    diagonal: bool = Field(False, description="only n = 2f+1")
    trials: int = Field(10_000, ge=1)
    seed: int = Field(2025, ge=0)
    detector: str = "paper"
    detector_params: dict[str, Any] = Field(default_factory=dict)
    attack: AttackConfig = Field(default_factory=AttackConfig)
    gnss: GNSSConfig | None = Field(None, description="None: honest reports are exact")
    ranging: RangingConfig = Field(default_factory=lambda: RangingConfig(kind="exact"))
    geometry: Literal["cube", "formation", "flat", "line"] = Field(
        "cube",
        description="uniform cube, a grid formation, a flat layer (thickness m thick) or within "
        "line_radius m of a line (both area_size across)",
    )
    thickness: float = Field(0.5, ge=0, description="flat layer: vertical spread, m")
    line_radius: float = Field(1.0, ge=0, description="line: largest distance from the line, m")
    area_size: float = Field(100.0, gt=0, description="cube side, m (paper: 100 m)")
    spacing: float = Field(20.0, gt=0, description="formation spacing, m (docs/models.md: 10-30 m)")
    jitter: float = Field(2.0, ge=0, description="formation jitter per axis, m")
    calibrate: bool = Field(False, description="set tau/epsilon by calibration (III.E)")
    calibration_trials: int = Field(2000, ge=10)
    chunk_size: int = Field(1000, ge=1, description="trials per task (fixes the seeds)")
    known_set: bool = Field(
        False,
        description="give the detector's estimator the true honest set instead of detecting it "
        "(its robust estimate and assessment): what it achieves with perfect detection",
    )

    @model_validator(mode="after")
    def _check(self) -> SweepConfig:
        if min(self.n) < 3:
            small = ", ".join(str(n) for n in sorted(set(self.n)) if n < 3)
            raise ValueError(f"n: every swarm size must be >= 3 (one attacker needs 3 drones), got {small}")
        if self.f is not None and min(self.f) < 1:
            raise ValueError("f: every attacker count must be >= 1")
        if self.f is not None and self.diagonal:
            raise ValueError("f: give either f or diagonal, not both")
        if not self.cells():
            raise ValueError("n/f: no cell with 1 <= f <= (n-1)/2 in this grid")
        get_detector(self.detector)  # an unknown name is its own error, not a parameter's
        try:
            model = detector_params(self.detector, **self.detector_params)
            # f_max against every swarm size now, not when the cell runs (by then run.json
            # was written, and a corrected re-run into the folder refused)
            if isinstance(model, IntegrityParams):
                for n in sorted({n for n, _ in self.cells()}):
                    resolve_f_max(model, n, self.detector)
        except ValueError as exc:
            raise ValueError(f"detector_params: {exc}") from None
        if self.known_set:
            check_known_set(self.detector, self.detector_params)
        return self

    def cells(self) -> list[tuple[int, int]]:
        """(n, f) pairs: every f <= (n-1)/2 (and in ``f`` if given), or only n = 2f+1."""
        out = []
        for n in sorted(set(self.n)):
            fmax = (n - 1) // 2
            if fmax - self.attack.min_honest < 0:
                continue
            fs = range(1, fmax + 1)
            if self.diagonal:
                fs = [fmax] if n % 2 == 1 and fmax >= 1 else []
            elif self.f is not None:
                fs = [f for f in fs if f in set(self.f)]
            out += [(n, f) for f in fs if n - f >= self.attack.min_honest]
        return out


def read_toml(path: Path, flag: str) -> dict[str, Any]:
    """A TOML file's contents; a missing or malformed file is a one-line ConfigError naming
    the command-line flag that gave it."""
    try:
        return tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(f"{flag}: no file {path}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{flag} {path}: not a text file ({exc.encoding}: {exc.reason})") from None
    except OSError as exc:
        raise ConfigError(f"{flag} {path}: unreadable ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{flag} {path}: not valid TOML ({exc})") from None


def preset_defaults(preset: str) -> dict[str, Any]:
    """The preset's settings (docs/models.md). ``reference``: the paper's code; ``realistic``: GNSS
    1.5/3 m, UWB 0.10 m, jumps 10-100 m, thresholds calibrated from honest runs."""
    if preset == "reference":
        return {
            "preset": "reference",
            "gnss": None,
            "ranging": {"kind": "exact"},
            "attack": {"jump": "box", "half_width": 30.0},
            "calibrate": False,
        }
    if preset == "realistic":
        return {
            "preset": "realistic",
            "gnss": {"sigma_h": 1.5, "sigma_v": 3.0},
            "ranging": {"kind": "uwb", "sigma": 0.10},
            "attack": {"jump": "shell", "low": 10.0, "high": 100.0},
            "calibrate": True,
        }
    raise ConfigError(f"preset: unknown {preset!r}; known: {', '.join(PRESETS)}")


def merged(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``overrides`` merged in: a table (dict) merges one level, so an override
    sets its own keys of it, not the whole table; None overrides nothing."""
    data = dict(base)
    for key, val in overrides.items():
        if val is None:
            continue
        if isinstance(val, dict) and isinstance(data.get(key), dict):
            data[key] = {**data[key], **val}
        else:
            data[key] = val
    return data


def build_config(preset: str = "reference", **overrides: Any) -> SweepConfig:
    """Preset defaults with overrides merged in (`merged`)."""
    data = merged(preset_defaults(preset), overrides)
    try:
        return SweepConfig(**data)
    except ValidationError as exc:
        raise ConfigError(one_line(exc, "", SweepConfig)) from None
