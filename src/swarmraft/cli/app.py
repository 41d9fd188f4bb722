"""The `swarmraft` command group and what its commands share: consoles, one-line errors,
exit statuses (2 for bad input, 1 for a numerical failure inside the estimators, 130 on
Ctrl-C), progress bars and printing a table with its legend. Shared options are in
`swarmraft.cli.options`, the tables in `swarmraft.cli.tables`."""

from __future__ import annotations

import re
import sys
from collections.abc import Callable
from typing import Any

import click
import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.rule import Rule
from rich.table import Table
from rich.text import Text

# Wide tables even when the output is a pipe or a log file (rich would assume 80 columns).
_WIDTH = None if sys.stdout.isatty() else 130
console = Console(highlight=False, width=_WIDTH)
err_console = Console(stderr=True, highlight=False, width=_WIDTH)
#: prose (summary lines, headings) wraps here, or at the terminal's width if that is narrower
TEXT_WIDTH = 100


def _fail(message: str) -> None:
    # the message is text, not markup: "pip install 'swarmraft[live]'" keeps its brackets
    err_console.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True, markup=True)
    sys.exit(2)


def _param_name(exc: click.BadParameter) -> str | None:
    """The option or argument a BadParameter is about, as the user typed it (--out, RESULTS)."""
    if exc.param_hint is not None:
        hint = exc.param_hint if isinstance(exc.param_hint, str) else " / ".join(exc.param_hint)
    elif isinstance(exc.param, click.Argument):
        hint = (exc.param.name or "").upper()
    elif exc.param is not None:
        hint = " / ".join(exc.param.opts)
    else:
        return None
    return hint.replace("'", "").replace('"', "") or None


class _Group(click.Group):
    """Turns expected errors, and click's usage errors, into one line on stderr."""

    def main(self, *args: Any, **kwargs: Any) -> Any:
        try:
            return super().main(*args, standalone_mode=False, **kwargs)
        except click.exceptions.NoArgsIsHelpError as exc:
            click.echo(exc.ctx.get_help() if exc.ctx else exc.format_message())
            sys.exit(0)
        except click.UsageError as exc:
            hint = f" (see `{exc.ctx.command_path} --help`)" if exc.ctx else ""
            text = exc.format_message()
            bad_value = isinstance(exc, click.BadParameter) and not isinstance(exc, click.MissingParameter)
            if bad_value and (name := _param_name(exc)):
                text = f"{name}: {exc.message}"  # '--out: ...', as the config errors read
            _fail(" ".join(f"{text}{hint}".split()))
        except click.exceptions.Abort as exc:
            if isinstance(exc.__cause__, KeyboardInterrupt):
                err_console.print("interrupted", soft_wrap=True)
                sys.exit(130)
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
            first = text.splitlines()[0] if text else type(exc).__name__
            if isinstance(exc, np.linalg.LinAlgError):
                # a numerical failure inside the estimators, not the user's input (a ValueError
                # to Python): said so, with exit status 1, so it is reported rather than "fixed"
                err_console.print(
                    f"[bold red]internal error:[/] {escape(first)} (a numerical failure, not bad "
                    "input: please report the command and its input files)",
                    soft_wrap=True,
                    markup=True,
                )
                sys.exit(1)
            _fail(first)


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


def heading(title: str, to: Console | None = None) -> None:
    """A section heading: a rule of at most TEXT_WIDTH with ``title`` in it, or, when the
    title would be cut there (a long output path), a plain rule with the title whole on the
    line under it."""
    out = to or console
    width = min(out.width, TEXT_WIDTH)
    if Text.from_markup(title).cell_len + 6 <= width:
        out.print(Rule(title), width=width)
    else:
        out.print(Rule(), width=width)
        out.print(title, soft_wrap=True)


# a number and its unit stay on one line: the space between them is this while wrapping
_GLUE = "\u2423"
_NUMBER_UNIT = re.compile(r"(?<=\d) (?=(?:m|s|ms)\b)")


def print_wrapped(markup: str, indent: int = 0, to: Console | None = None) -> None:
    """One statement of prose, indented by ``indent`` spaces and wrapped between words at
    TEXT_WIDTH (or the terminal's width), each continuation line 4 spaces deeper, so a log
    reads well at 80 columns and a wrapped line is never mistaken for a new one; a number
    is not parted from its unit. Not for lines that print a path (those are never wrapped:
    `soft_wrap`)."""
    out = to or console
    hang = 4
    width = max(min(out.width, TEXT_WIDTH) - indent - hang, 20)
    text = Text.from_markup(_NUMBER_UNIT.sub(_GLUE, markup))
    for k, line in enumerate(text.wrap(out, width)):
        line.rstrip()
        line = Text(line.plain.replace(_GLUE, " "), style=line.style, spans=line.spans)
        out.print(Text(" " * (indent + (hang if k else 0))) + line, soft_wrap=True)


def print_table(table_and_legend: tuple[Table, str], to: Console | None = None) -> None:
    """A table from `swarmraft.cli.tables` with its legend under it."""
    table, legend = table_and_legend
    out = to or console
    out.print(table)
    out.print(f"[dim]{legend}[/]", width=min(out.width, 80))


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="swarmraft")
def main() -> None:
    """SwarmRaft: verify drone-swarm positions against inter-drone ranges.

    Run `swarmraft COMMAND --help` for each command's options.
    """
