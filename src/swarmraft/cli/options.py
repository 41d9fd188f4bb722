"""Options the `swarmraft` commands share and the checks on their values: output folders,
integer lists, KEY=VALUE parameters, workers, schedulers, detector and attack lists, and the
sweep-config builder. Each bad value is a click.BadParameter naming its option, raised while
the command line is parsed, so nothing has started or been written."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from swarmraft.experiments.config import ATTACKS

PRESET = click.Choice(["reference", "realistic"])
ATTACK_NAMES = list(ATTACKS)


class OutFolder(click.ParamType):
    """A folder to write into: not empty, not a file, with no file on its way."""

    name = "folder"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Path:
        from swarmraft.experiments.config import ConfigError
        from swarmraft.experiments.sweep import check_out_folder

        flag = param.opts[0] if param is not None and param.opts else "--out"
        try:
            return check_out_folder(Path(value), flag)
        except ConfigError as exc:
            self.fail(str(exc).removeprefix(f"{flag}: ").removeprefix(f"{flag} "), param, ctx)


IMAGE_SUFFIXES = (".png", ".pdf", ".svg")


class OutFile(click.ParamType):
    """A file to write: a name ending in one of ``suffixes``, not a folder, with no file on its
    way; ``kind`` names what it holds in the error ("give an image file name ending in ...")."""

    name = "file"

    def __init__(self, suffixes: tuple[str, ...], kind: str) -> None:
        self.suffixes, self.kind = suffixes, kind

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Path:
        path = Path(value)
        ends = " or ".join(filter(None, [", ".join(self.suffixes[:-1]), self.suffixes[-1]]))
        article = "an" if self.kind[:1].lower() in "aeiou" or self.kind.isupper() else "a"
        want = f"give {article} {self.kind} file name ending in {ends}"
        if not str(value):
            self.fail(want, param, ctx)
        if path.suffix.lower() not in self.suffixes:
            self.fail(f"{value}: {want}", param, ctx)
        if path.is_dir():
            self.fail(f"{value} is a folder", param, ctx)
        for p in path.parents:
            if p.exists():
                if not p.is_dir():
                    self.fail(f"{p} is a file, not a folder", param, ctx)
                break
        return path


def ImageFile(suffixes: tuple[str, ...] = IMAGE_SUFFIXES) -> OutFile:  # noqa: N802 (a type, as click's)
    """A figure file to write (.png, .pdf or .svg by default)."""
    return OutFile(suffixes, "image")


def _check_scheduler(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    from swarmraft.experiments.executors import check_executor

    try:
        check_executor(None, value)
    except ValueError as exc:
        raise click.BadParameter(str(exc).removeprefix("--scheduler: "), ctx, param) from None
    return value


WORKERS = click.option(
    "--workers", type=click.IntRange(min=1), help="local worker processes [default: all cores]"
)
SCHEDULER = click.option(
    "--scheduler",
    callback=_check_scheduler,
    help="Dask scheduler tcp://HOST:PORT, or 'local' for a LocalCluster.",
)


def int_list(text: str | None, name: str) -> tuple[int, ...] | None:
    """'3,5,7' or '3-17' or '3-17:2' -> ints."""
    if text is None:
        return None
    out: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part:
                rng, _, step = part.partition(":")
                lo, hi = (int(v) for v in rng.split("-"))
                if step and int(step) < 1:
                    raise ValueError
                out += list(range(lo, hi + 1, int(step) if step else 1))
            elif part:
                out.append(int(part))
    except ValueError:
        raise click.BadParameter(
            f"expected integers like 3,5,7 or 3-17:2, got {text!r}", param_hint=name
        ) from None
    if not out:
        raise click.BadParameter(f"no values in {text!r}", param_hint=name)
    return tuple(out)


def _at_least(
    values: tuple[int, ...] | None, minimum: int, what: str, name: str, why: str = ""
) -> tuple[int, ...] | None:
    """``values`` if each is at least ``minimum``; else a BadParameter naming the option and
    the values below it (the config's rule, checked here so the error names the option)."""
    low = sorted({v for v in values or () if v < minimum})
    if low:
        got = ", ".join(str(v) for v in low)
        raise click.BadParameter(f"every {what} must be >= {minimum}{why}, got {got}", param_hint=name)
    return values


def swarm_sizes(text: str | None, name: str = "--n") -> tuple[int, ...] | None:
    """Swarm sizes from an integer list, each 3 or more (one attacker needs 3 drones)."""
    return _at_least(int_list(text, name), 3, "swarm size", name, " (one attacker needs 3 drones)")


def attacker_counts(text: str | None, name: str = "--f") -> tuple[int, ...] | None:
    """Attacker counts from an integer list, each 1 or more."""
    return _at_least(int_list(text, name), 1, "attacker count", name)


def name_list(text: str, name: str, known: list[str], noun: str) -> list[str]:
    """'paper,clique' -> names, each one of ``known`` (each a ``noun``); an empty list is an
    error."""
    names = [v.strip() for v in text.split(",") if v.strip()]
    if not names:
        raise click.BadParameter(f"no names in {text!r}; known: {', '.join(known)}", param_hint=name)
    for v in names:
        if v not in known:
            raise click.BadParameter(f"unknown {noun} {v!r}; known: {', '.join(known)}", param_hint=name)
    if twice := repeated(names):
        # the same trials run and tabled twice
        raise click.BadParameter(f"{', '.join(twice)} given more than once", param_hint=name)
    return names


def repeated(values: list) -> list:
    """The values given more than once in ``values``, sorted (an option's list that names one
    thing twice runs and tables it twice)."""
    return sorted({v for v in values if values.count(v) > 1})


def key_values(items: tuple[str, ...]) -> dict[str, Any]:
    """('tau=0.3', ...) from repeated --param options -> {'tau': 0.3}."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise click.BadParameter(f"expected KEY=VALUE, got {item!r}", param_hint="--param")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def typed(name: str) -> bool:
    """Whether the running command's option ``name`` (its Python name) was given on the
    command line or in the environment, not left at its default: a default must not pass
    for a typed flag where a --config file sets the same thing."""
    ctx = click.get_current_context(silent=True)
    if ctx is None:  # called from Python, not from a command: nothing was typed
        return False
    source = ctx.get_parameter_source(name)
    return source not in (None, click.core.ParameterSource.DEFAULT, click.core.ParameterSource.DEFAULT_MAP)


def sweep_config(preset, config_file, n_text, f_text, diagonal, trials, seed, extra: dict[str, Any]):
    """A validated SweepConfig from a preset, an optional TOML file and command-line flags
    (flags typed override the file, the file overrides the preset; an option left at its
    default, --preset, --n or --trials, does not override what the file sets)."""
    from swarmraft.experiments import ConfigError, build_config
    from swarmraft.experiments.config import merged, read_toml

    settings: dict[str, Any] = {}
    if config_file is not None:
        settings = read_toml(config_file, "--config")
        file_preset = settings.pop("preset", None)
        if file_preset is not None and not typed("preset"):
            preset = file_preset
        n_text = None if "n" in settings and not typed("n_text") else n_text
        trials = None if "trials" in settings and not typed("trials") else trials
    overrides = {
        "n": swarm_sizes(n_text),
        "f": attacker_counts(f_text),
        "diagonal": diagonal or None,
        "trials": trials,
        "seed": seed,
        **extra,
    }
    flags = {k: v for k, v in overrides.items() if v is not None}
    try:  # a flag sets its own keys of a file's table, not the whole table
        return build_config(preset, **merged(settings, flags))
    except ConfigError as exc:
        # a field the file set (and no flag overrode) is named with the file it came from; one
        # a flag set, with the flag
        where, _, what = str(exc).partition(":")
        field = where.split(".", 1)[0]
        if config_file is not None and field in settings and field not in flags:
            raise ConfigError(f"--config {config_file}: {exc}") from None
        if field in flags and field in _FLAG_OF and what:
            raise click.BadParameter(what.strip(), param_hint=_FLAG_OF[field]) from None
        raise


# the sweep's config fields the command line sets, and the option that sets each
_FLAG_OF = {
    "n": "--n",
    "f": "--f",
    "trials": "--trials",
    "seed": "--seed",
    "detector": "--detector",
    "detector_params": "--param",
    "attack": "--attack",
    "known_set": "--known-set",
}
