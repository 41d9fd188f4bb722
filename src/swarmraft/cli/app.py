"""The `swarmraft` command group and what its commands share: consoles, one-line errors,
progress bars, option types and the sweep-config builder."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import Any

import click
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

# Wide tables even when the output is a pipe or a log file (rich would assume 80 columns).
_WIDTH = None if sys.stdout.isatty() else 130
console = Console(highlight=False, width=_WIDTH)
err_console = Console(stderr=True, highlight=False, width=_WIDTH)


def _fail(message: str) -> None:
    err_console.print(f"[bold red]error:[/] {message}", soft_wrap=True, markup=True)
    sys.exit(2)


class _Group(click.Group):
    """Turns expected errors, and click's usage errors, into one line on stderr."""

    def main(self, *args: Any, **kwargs: Any) -> Any:
        try:
            return super().main(*args, standalone_mode=False, **kwargs)
        except click.UsageError as exc:
            hint = f" (see `{exc.ctx.command_path} --help`)" if exc.ctx else ""
            _fail(" ".join(f"{exc.format_message()}{hint}".split()))
        except click.exceptions.Abort:
            _fail("aborted")
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except (ValueError, RuntimeError, FileNotFoundError, KeyError) as exc:
            if isinstance(exc, click.ClickException | click.exceptions.Exit):
                raise
            text = str(exc).strip()
            _fail(text.splitlines()[0] if text else type(exc).__name__)


def _int_list(text: str | None, name: str) -> tuple[int, ...] | None:
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
                out += list(range(lo, hi + 1, int(step) if step else 1))
            elif part:
                out.append(int(part))
    except ValueError:
        raise click.BadParameter(
            f"expected integers like 3,5,7 or 3-17:2, got {text!r}", param_hint=name
        ) from None
    if not out:
        raise click.BadParameter("no values given", param_hint=name)
    return tuple(out)


def _params(items: tuple[str, ...]) -> dict[str, Any]:
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


def progress_bar(
    label: str, unit: str = "trials"
) -> tuple[Progress, Callable[[int, int], Callable[[int], None]]]:
    """A progress bar, and the ``progress(total, cells[, name])`` callback factory sweeps
    take; each call adds a bar, labelled ``name`` if given."""
    prog = Progress(
        TextColumn("[bold]{task.description}[/]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn(unit),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=err_console,
        transient=False,
    )

    def start(total: int, cells: int, name: str | None = None) -> Callable[[int], None]:
        task = prog.add_task(f"{label} {name}" if name else label, total=total)
        return lambda k: prog.advance(task, k)

    return prog, start


def _summary_table(cells: dict, title: str) -> Table:
    t = Table(title=title, title_justify="left")
    for col in (
        "n",
        "f",
        "trials",
        "baseline m",
        "recovered mean m",
        "+/- sem",
        "median m",
        "p99 m",
        ">1 m",
        "honest m",
        "detect",
        "false pos",
    ):
        t.add_column(col, justify="right")
    for i in range(len(cells["n"])):
        t.add_row(
            str(cells["n"][i]),
            str(cells["f"][i]),
            str(cells["trials"][i]),
            f"{cells['baseline_mean'][i]:.2f}",
            f"{cells['recovered_mean'][i]:.3g}",
            f"{cells['recovered_sem'][i]:.2g}",
            f"{cells['recovered_median'][i]:.2g}",
            f"{cells['recovered_p99'][i]:.3g}",
            f"{cells['frac_over_1m'][i]:.1%}",
            f"{cells['honest_mean'][i]:.3g}",
            f"{cells['detection_rate'][i]:.1%}",
            f"{cells['false_positive_rate'][i]:.1%}",
        )
    return t


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="swarmraft")
def main() -> None:
    """SwarmRaft: verify drone-swarm positions against inter-drone ranges.

    Run `swarmraft COMMAND --help` for each command's options.
    """


def _sweep_config(preset, config_file, n_text, f_text, diagonal, trials, seed, extra: dict[str, Any]):
    """A validated SweepConfig from a preset, an optional TOML file and command-line flags
    (flags override the file, the file overrides the preset)."""
    from swarmraft.experiments import build_config
    from swarmraft.experiments.config import read_toml

    settings: dict[str, Any] = {}
    if config_file is not None:
        settings = read_toml(config_file, "--config")
        preset = settings.pop("preset", preset)
    overrides = {
        "n": _int_list(n_text, "--n"),
        "f": _int_list(f_text, "--f"),
        "diagonal": diagonal or None,
        "trials": trials,
        "seed": seed,
        **extra,
    }
    return build_config(preset, **{**settings, **{k: v for k, v in overrides.items() if v is not None}})


PRESET = click.Choice(["reference", "realistic"])
ATTACK_NAMES = ["jump", "range-tamper", "range-bias", "collusion-1", "collusion-2", "collusion-3", "area"]
WORKERS = click.option("--workers", type=int, help="local worker processes [default: all cores]")
SCHEDULER = click.option("--scheduler", help="Dask scheduler tcp://HOST:PORT, or 'local' for a LocalCluster.")
