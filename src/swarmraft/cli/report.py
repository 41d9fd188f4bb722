"""The report command: a results folder (mission, networked run, sweep or comparison) as one
self-contained HTML file."""

from __future__ import annotations

import shlex
from datetime import UTC, datetime
from pathlib import Path

import click

from swarmraft.cli.app import console, main
from swarmraft.cli.options import OutFile

HTML_SUFFIXES = (".html", ".htm")


def build_report(folder: Path, command: str) -> str:
    """The HTML report of ``folder`` (its kind told from its files); a folder that is no
    results folder, or whose files cannot be read, is a one-line ConfigError naming it."""
    from swarmraft import __version__
    from swarmraft.experiments.results_folder import KINDS, require_kind
    from swarmraft.viz import report

    kind = require_kind(folder, KINDS, "DIR", "`swarmraft report`")
    provenance = [
        ("folder", "folder", str(folder)),
        ("report_version", "report written by swarmraft", __version__),
        ("generated", "generated (UTC)", datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S")),
        ("command", "command", command),
    ]
    figures = report.read_figures(folder)
    if kind in ("mission", "launch"):
        from swarmraft.experiments.mission_folder import read_mission

        m = read_mission(folder)
        scenario = m.log.scenario.model_dump(mode="json")
        return report.mission_report(m.summary, scenario, figures, provenance, kind)
    if kind == "sweep":
        from swarmraft.experiments.sweep import load_results

        cells, _, run = load_results(folder)
        return report.sweep_report(cells, run, figures, provenance, str(folder))
    from swarmraft.experiments.compare import compare_figure_names, read_compare

    table, runs = read_compare(folder)
    return report.compare_report(table, runs, figures, compare_figure_names(table), provenance)


@main.command("report")
@click.argument("folder", metavar="DIR", type=click.Path(path_type=Path))
@click.option(
    "--out", type=OutFile(HTML_SUFFIXES, "HTML"), help="HTML file to write [default DIR/report.html]"
)
def report_cmd(folder: Path, out: Path | None) -> None:
    """Write one self-contained HTML file about a results folder: a mission's or a networked
    run's (`swarmraft mission`, `swarmraft launch`), a sweep's (`swarmraft sweep`) or a detector
    comparison's (`swarmraft compare`); the kind is told from the folder's files.

    It holds every figure of DIR/figures embedded (the expected ones that are missing are
    named), the summary tables (for a mission its checks first: records identical, wrong
    partitions, misleading information, detections, skipped steps, warnings), the scenario
    or config, the seed and version, and the command and time that made it. It loads nothing
    from elsewhere: it reads the same offline, mailed, or archived."""
    command = (
        "swarmraft report " + shlex.quote(str(folder)) + (f" --out {shlex.quote(str(out))}" if out else "")
    )
    text = build_report(folder, command)
    target = out or folder / "report.html"
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(target.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(target)
    console.print(f"wrote {target} ({len(text.encode()) / 1e6:.1f} MB)", soft_wrap=True)
