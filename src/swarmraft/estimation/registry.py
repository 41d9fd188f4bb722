"""Detectors by name: ``verify(snapshot, detector="paper", **params)`` for one snapshot and
``verify_batch(batch, detector, **params)`` for many; sweeps, missions and the live protocol
select a detector the same way.

A detector is a function ``(SnapshotBatch, params) -> VerdictBatch`` with a pydantic model of
its parameters (unknown or out-of-range parameters are a one-line ``ValueError``), registered
with the decorator ``@register(name, ParamsModel, summary)``. Detectors from other packages
are found through the entry-point group ``swarmraft.detectors`` (each entry a module that
registers its detectors when imported), loaded the first time a name is not known or the
names are listed, in every process: the command line and a sweep's workers see them too.
docs/detectors.md, "Writing a detector".
"""

from __future__ import annotations

import difflib
import importlib.metadata
import math
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ValidationError

from swarmraft.estimation.blas import one_blas_thread
from swarmraft.estimation.integrity import IntegrityParams, given_set, given_set_fields
from swarmraft.estimation.links import run_screened
from swarmraft.estimation.snapshot import Snapshot, SnapshotBatch, Verdict, VerdictBatch

DetectorFn = Callable[[SnapshotBatch, Any], VerdictBatch]


@dataclass(frozen=True)
class Detector:
    name: str
    run: DetectorFn
    params: type[BaseModel]
    summary: str


_REGISTRY: dict[str, Detector] = {}


PLUGIN_GROUP = "swarmraft.detectors"
_plugins_loaded: set[str] = set()  # the entry-point groups imported in this process


def register(name: str, params: type[BaseModel], summary: str) -> Callable[[DetectorFn], DetectorFn]:
    """Decorator: register a batch detector under ``name``::

        @register("mine", MyParams, "one line on what it does")
        def mine(batch: SnapshotBatch, p: MyParams) -> VerdictBatch: ...

    ``params`` must refuse unknown fields (``extra="forbid"``, as `IntegrityParams` and
    `LinkParams` do), so that a misspelt parameter is an error rather than ignored."""
    if params.model_config.get("extra") != "forbid":
        raise ValueError(
            f"detector {name!r}: {params.__name__} must refuse unknown parameters: derive it from "
            "IntegrityParams or LinkParams, or set model_config = ConfigDict(extra='forbid')"
        )

    def wrap(fn: DetectorFn) -> DetectorFn:
        old = _REGISTRY.get(name)
        if old is not None and not same_function(old.run, fn):
            raise ValueError(f"detector {name!r} is already registered (by {old.run.__module__})")
        _REGISTRY[name] = Detector(name=name, run=fn, params=params, summary=summary)
        return fn

    return wrap


def load_plugins(group: str = PLUGIN_GROUP, what: str = "detector") -> None:
    """Import every module of the entry-point group ``group`` once per process (each module
    registers what it holds when imported: ``swarmraft.detectors``, ``swarmraft.attacks``); a
    plugin that fails to import is a one-line ValueError naming it."""
    if group in _plugins_loaded:
        return
    _plugins_loaded.add(group)
    for ep in importlib.metadata.entry_points(group=group):
        try:
            ep.load()
        except Exception as exc:  # noqa: BLE001 - any import error of a plugin is reported as its own
            raise ValueError(f"{what} plugin {ep.name} ({ep.value}): {type(exc).__name__}: {exc}") from None


def same_function(a: Callable, b: Callable) -> bool:
    """Whether two registered functions are one (a module imported twice, as a script's
    __main__ and by name, registers it twice: no conflict)."""
    return (a.__module__, a.__qualname__) == (b.__module__, b.__qualname__)


def detector_names() -> list[str]:
    load_plugins()
    return sorted(_REGISTRY)


def get_detector(name: str) -> Detector:
    if name not in _REGISTRY:
        load_plugins()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"detector: unknown name {name!r}; known: {', '.join(detector_names())}") from None


def one_line(
    exc: ValidationError, prefix: str, model: type[BaseModel] | None = None, brackets: bool = True
) -> str:
    """A pydantic error as one line naming the field: 'prefix.field[k].field: message' (a list
    item by its index, as the project's own checks name it; with ``brackets`` off, 'field.k',
    as a TOML table keyed by integers is spelt). With ``model`` (the model that raised), an
    unknown key gets a close spelling of a key it has: '(did you mean X?)'."""
    parts = []
    for err in exc.errors():
        loc = "".join(f"[{p}]" if isinstance(p, int) and brackets else f".{p}" for p in err["loc"]).lstrip(
            "."
        )
        where = f"{prefix}.{loc}" if prefix and loc else (prefix or loc)
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown parameter" + _close_key(model, err["loc"])
        parts.append(f"{where}: {msg}" if where else msg)
    return "; ".join(parts)


def _close_key(model: type[BaseModel] | None, loc: tuple) -> str:
    """' (did you mean X?)' for the unknown key at ``loc`` of ``model``, if one is close (two
    equally close: both)."""
    if model is None or not loc or isinstance(loc[-1], int):
        return ""
    models = [model]
    for key in loc[:-1]:  # down to the models that may hold the key
        if isinstance(key, int) or str(key).isdigit():  # a list index, or a table keyed by id
            continue
        fields = [m.model_fields[str(key)] for m in models if str(key) in m.model_fields]
        if fields:
            models = [m for f in fields for m in _models_in(f.annotation)]
        else:  # a tagged union's tag: the member it names, if one does
            models = [m for m in models if str(key) in _tags(m)] or models
        if not models:
            return ""
    names = list(dict.fromkeys(name for m in models for name in m.model_fields))
    scores = {n: difflib.SequenceMatcher(None, str(loc[-1]), n).ratio() for n in names}
    best = max(scores.values(), default=0.0)
    close = [n for n, r in scores.items() if r == best and r >= 0.6]
    return f" (did you mean {' or '.join(close)}?)" if close else ""


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation holds (itself, or inside list[...], dict[..., X],
    X | None, a union of models ...)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in typing.get_args(annotation) for m in _models_in(arg)]


def _tags(model: type[BaseModel]) -> tuple:
    """The values a tagged union's members tell themselves apart by (their Literal fields)."""
    return tuple(
        v
        for f in model.model_fields.values()
        if typing.get_origin(f.annotation) is typing.Literal
        for v in typing.get_args(f.annotation)
    )


def _unknown_hint(name: str, unknown: list[str]) -> str:
    """What a user who gave ``name`` parameters it does not have meant, as a suffix of the
    error line: the detectors that have them (a parameter for another detector than the one
    chosen, `sweep`'s default being ``paper``), or a close spelling of one it has."""
    if not unknown:
        return ""
    key = unknown[0]
    others = [d for d in detector_names() if d != name and key in get_detector(d).params.model_fields]
    if others:
        return f" ({key} is a parameter of {', '.join(others)}: choose one of them as the detector)"
    return _close_key(get_detector(name).params, (key,))


def detector_params(name: str, **params: Any) -> BaseModel:
    """Validate a detector's parameters; a bad one is a one-line ValueError naming it. Valid
    ones are remembered (a leader and every auditor validate the swarm's same parameters each
    step: 15-40 us of pydantic): the same model object again, which no caller changes."""
    try:
        key = (name, tuple(sorted((k, type(v), v) for k, v in params.items())))
        kept = _VALID.get(key)
    except TypeError:  # a value that cannot be a key (a list): validated each time
        key, kept = None, None
    if kept is not None and get_detector(name).params is type(kept):
        return kept
    model = _validated(name, params)
    if key is not None:
        if len(_VALID) >= 256:
            _VALID.clear()
        _VALID[key] = model
    return model


_VALID: dict[tuple, BaseModel] = {}


def _validated(name: str, params: dict[str, Any]) -> BaseModel:
    det = get_detector(name)
    try:
        model = det.params(**params)
    except ValidationError as exc:
        unknown = [str(e["loc"][0]) for e in exc.errors() if e["type"] == "extra_forbidden" and e["loc"]]
        raise ValueError(one_line(exc, name) + _unknown_hint(name, unknown)) from None
    for key, value in model.model_dump().items():
        values = value if isinstance(value, tuple | list) else (value,)
        if any(isinstance(v, float) and not math.isfinite(v) for v in values):
            raise ValueError(f"{name}.{key}: must be finite, got {value}")
    return model


def verify_batch(
    batch: SnapshotBatch, detector: str = "paper", check: bool = True, **params: Any
) -> VerdictBatch:
    """Verify a batch with a registered detector, on ranges screened for bad links first
    where its parameters ask for it (`links.run_screened`). The batch is checked first
    (`SnapshotBatch.checked`: a one-line ValueError for bad input); ``check=False`` skips
    it for a batch the caller built itself (a drone's step, from decoded reports)."""
    return _verify_batch(batch.checked() if check else batch, detector, **params)


def _verify_batch(batch: SnapshotBatch, detector: str, **params: Any) -> VerdictBatch:
    p = detector_params(detector, **params)
    with one_blas_thread():
        return run_screened(get_detector(detector).run, batch, p)


def check_known_set(detector: str, params: dict[str, Any] | None = None) -> None:
    """A one-line ValueError unless ``detector`` has a noise model to estimate with when its
    trusted set is given (`verify_given`): its parameters are `IntegrityParams`; and where
    ``params`` holds one of its detection parameters, which a given set does not use."""
    if not issubclass(get_detector(detector).params, IntegrityParams):
        known = ", ".join(n for n in detector_names() if issubclass(get_detector(n).params, IntegrityParams))
        raise ValueError(f"known_set: detector {detector!r} has no noise model to estimate with; use {known}")
    unused = sorted(set(params or {}) - given_set_fields())
    if unused:
        what = "is a detection parameter" if len(unused) == 1 else "are detection parameters"
        raise ValueError(
            f"known_set: {', '.join(unused)} {what} of {detector}, not used with the true honest set given"
        )


def verify_given(batch: SnapshotBatch, trusted: Any, detector: str = "joint", **params: Any) -> VerdictBatch:
    """The verdicts of a batch with its trusted set (T, n) given instead of detected: the
    robust estimate and assessment of a statistical detector (`integrity.given_set`), with
    its parameters, on ranges screened as the detector screens them. A detector without a
    noise model (``paper``) is a one-line ValueError."""
    check_known_set(detector, params)
    batch = batch.checked()
    p = detector_params(detector, **params)
    given = np.asarray(trusted)
    if given.dtype != bool and not np.isin(given, (0, 1)).all():
        raise ValueError(
            "known_set: the trusted set is a mask (T, n) of booleans (or 0/1), not drone indices"
        )
    trusted = given.astype(bool)
    want = np.shape(batch.reported)[:2]
    if trusted.shape != want:
        raise ValueError(f"known_set: trusted set of shape {trusted.shape}, the batch has {want}")
    with one_blas_thread():
        return run_screened(lambda b, q: given_set(b, q, trusted), batch, p)


def verify(snapshot: Snapshot, detector: str = "paper", **params: Any) -> Verdict:
    """Verify one snapshot with a registered detector; returns its `Verdict`."""
    return _verify_batch(SnapshotBatch.of(snapshot), detector, **params).item(0)  # a Snapshot checks itself
