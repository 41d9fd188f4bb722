"""The HTML report of a results folder: one self-contained file (figures embedded as data:
URIs, the style sheet inline, no script, a content security policy that lets the page fetch
nothing), readable offline. Built from what the folder's files hold, read by
`swarmraft.experiments`; every text taken from them is escaped. Plain string building with
`html.escape`: the report is a few tables, no template engine needed."""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: media type of each figure file a report embeds; other files in figures/ are listed, not shown
MEDIA_TYPES = {
    ".png": "image/png",
    ".gif": "image/gif",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".svg": "image/svg+xml",
}
#: the figures each kind of folder should hold, in the order a report shows them
MISSION_FIGURES = ("error_over_time.png", "swarm_maps.png", "consensus_latency.png", "messages_per_step.png")
SWEEP_FIGURES = ("scaling.png", "distribution.png", "recovery.png")

_CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; padding: 0 1em;
  color: #222; line-height: 1.4; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; } h2 { font-size: 1.2em; margin-top: 2em;
  border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
th, td { border: 1px solid #ddd; padding: 0.2em 0.5em; text-align: left; vertical-align: top; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
thead th { background: #f3f3f3; position: sticky; top: 0; }
.wide { overflow-x: auto; max-width: 100%; }
ul.checks { list-style: none; padding: 0; font-size: 1.05em; }
ul.checks li { margin: 0.3em 0; padding: 0.4em 0.6em; border-left: 6px solid; }
ul.checks li.fail { border-color: #c0392b; background: #fdecea; }
ul.checks li.warn { border-color: #d68910; background: #fef5e7; }
ul.checks li.ok { border-color: #1e8449; background: #e9f7ef; }
.badge { display: inline-block; min-width: 3.5em; font-weight: bold; }
li.fail .badge { color: #c0392b; } li.warn .badge { color: #b9770e; } li.ok .badge { color: #1e8449; }
.missing { border: 2px solid #c0392b; background: #fdecea; padding: 0.5em 0.8em; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { font-size: 0.9em; color: #555; }
pre { background: #f7f7f7; padding: 0.8em; overflow-x: auto; font-size: 0.85em; }
.meta th { width: 14em; background: #fafafa; } .meta td.num { text-align: left; }
"""


@dataclass(frozen=True)
class Figure:
    """A file of a folder's figures/: embedded as a data: URI, or why it is not."""

    name: str
    data_uri: str | None
    size_px: tuple[int, int] | None
    problem: str | None = None


def read_figures(folder: Path) -> list[Figure]:
    """Every file in ``folder/figures`` (sorted by name), each image embedded; a file that is
    not an image it can show, or an image that cannot be read, carries its problem instead."""
    from PIL import Image, UnidentifiedImageError

    out = []
    fig_dir = Path(folder) / "figures"
    for path in sorted(fig_dir.iterdir()) if fig_dir.is_dir() else []:
        if not path.is_file():
            continue
        media = MEDIA_TYPES.get(path.suffix.lower())
        if media is None:
            out.append(Figure(path.name, None, None, f"not shown: a {path.suffix or 'suffix-less'} file"))
            continue
        data = path.read_bytes()
        size = None
        if media == "image/svg+xml":
            if b"<svg" not in data[:4096]:
                out.append(Figure(path.name, None, None, "unreadable: not an SVG image"))
                continue
        else:
            try:
                with Image.open(path) as im:
                    size = im.size
                    im.verify()
                with Image.open(path) as im:
                    im.load()  # verify() does not decode the pixels; a truncated file fails here
            except (OSError, UnidentifiedImageError, SyntaxError, ValueError) as exc:
                out.append(Figure(path.name, None, None, f"unreadable: {exc}"))
                continue
        uri = f"data:{media};base64,{base64.b64encode(data).decode('ascii')}"
        out.append(Figure(path.name, uri, size))
    return out


def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def fmt(value: Any) -> str:
    """A value as the report prints it: numbers to 6 significant digits, nan as 'nan', null
    as 'n/a', booleans as yes/no, lists comma-separated."""
    if value is None:
        return "n/a"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return "nan" if math.isnan(value) else format(float(value), ".6g")
    if isinstance(value, list | tuple):
        return ", ".join(fmt(v) for v in value) or "none"
    if isinstance(value, dict):
        return ", ".join(f"{k} {fmt(v)}" for k, v in sorted(value.items())) or "none"
    return str(value)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


def _td(value: Any, col: str | None = None) -> str:
    cls = ' class="num"' if _is_number(value) else ""
    data = f' data-col="{esc(col)}"' if col else ""
    return f"<td{cls}{data}>{esc(fmt(value))}</td>"


def key_table(rows: Iterable[tuple[str, str, Any]], table_id: str, css: str = "") -> str:
    """A two-column table, one row per (key, label, value); each row carries data-key."""
    body = "".join(f'<tr data-key="{esc(k)}"><th>{esc(label)}</th>{_td(v)}</tr>' for k, label, v in rows)
    cls = f' class="{css}"' if css else ""
    return f'<table id="{esc(table_id)}"{cls}><tbody>{body}</tbody></table>'


def row_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[tuple[str, str]], table_id: str) -> str:
    """One row per mapping; ``columns`` are (key, header); each cell carries data-col."""
    if not rows:
        return f'<p id="{esc(table_id)}">none</p>'
    head = "".join(f"<th>{esc(h)}</th>" for _, h in columns)
    body = "".join(
        f'<tr data-row="{i}">' + "".join(_td(r.get(k), k) for k, _ in columns) + "</tr>"
        for i, r in enumerate(rows)
    )
    return (
        f'<div class="wide"><table id="{esc(table_id)}"><thead><tr>{head}</tr></thead>'
        f"<tbody>{body}</tbody></table></div>"
    )


def columns_rows(table: Mapping[str, np.ndarray]) -> list[dict[str, Any]]:
    """A table of columns (as `swarmraft.experiments.tables.read_table` returns) as rows."""
    names = list(table)
    length = len(table[names[0]]) if names else 0
    return [
        {c: table[c][i].item() if hasattr(table[c][i], "item") else table[c][i] for c in names}
        for i in range(length)
    ]


def checks_list(checks: Sequence[tuple[str, str]]) -> str:
    """Failures, then warnings, then what passed, each a line with its badge, all one size."""
    order = {"fail": 0, "warn": 1, "ok": 2}
    badge = {"fail": "FAIL", "warn": "WARN", "ok": "OK"}
    items = "".join(
        f'<li class="{level}" data-level="{level}"><span class="badge">{badge[level]}</span> {esc(text)}</li>'
        for level, text in sorted(checks, key=lambda c: order[c[0]])
    )
    counts = {lv: sum(1 for c in checks if c[0] == lv) for lv in order}
    head = (
        f'<p id="check-counts"><b>{counts["fail"]} failed, {counts["warn"]} warnings, '
        f"{counts['ok']} passed</b></p>"
    )
    return f'{head}<ul class="checks" id="checks">{items}</ul>'


def figures_section(figures: Sequence[Figure], expected: Sequence[str], how_to_draw: str) -> str:
    """Every figure embedded; the expected ones that are absent, and the files that could not
    be shown, named in a box above them."""
    names = {f.name for f in figures}
    missing = [name for name in expected if name not in names]
    parts = ["<h2>Figures</h2>"]
    if missing:
        parts.append(
            f'<div class="missing" id="missing-figures"><b>Missing figures</b> (expected in figures/, '
            f"not there): {esc(', '.join(missing))}. {esc(how_to_draw)}</div>"
        )
    bad = [f for f in figures if f.data_uri is None]
    if bad:
        items = "".join(f"<li>figures/{esc(f.name)}: {esc(f.problem)}</li>" for f in bad)
        parts.append(f'<div class="missing" id="unshown-figures"><b>Not shown</b><ul>{items}</ul></div>')
    shown = [f for f in figures if f.data_uri is not None]
    order = {name: k for k, name in enumerate(expected)}
    shown.sort(key=lambda f: (order.get(f.name, len(order)), f.name))
    if not shown:
        parts.append("<p>No figure to show.</p>")
    for f in shown:
        size = f", {f.size_px[0]} x {f.size_px[1]} px" if f.size_px else ""
        parts.append(
            f'<figure><img src="{f.data_uri}" alt="{esc(f.name)}" data-name="{esc(f.name)}">'
            f"<figcaption>figures/{esc(f.name)}{esc(size)}</figcaption></figure>"
        )
    return "\n".join(parts)


def page(title: str, meta: Sequence[tuple[str, str, Any]], sections: Sequence[str]) -> str:
    """The whole document: title, the provenance table, then the sections in order."""
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{esc(title)}</title><style>{_STYLE}</style></head><body>\n"
        f"<h1>{esc(title)}</h1>\n"
        + key_table(meta, "provenance", "meta")
        + "\n"
        + "\n".join(sections)
        + "\n</body></html>\n"
    )


def pretty_json(data: Any, indent: int = 0) -> str:
    """JSON with keys sorted, an object's members one a line, and lists of plain values on one
    line (a scenario's drone lists and ranges stay readable)."""
    pad = "  " * (indent + 1)
    if isinstance(data, dict) and data:
        items = [f"{pad}{json.dumps(str(k))}: {pretty_json(v, indent + 1)}" for k, v in sorted(data.items())]
        return "{\n" + ",\n".join(items) + "\n" + "  " * indent + "}"
    if isinstance(data, list | tuple) and any(isinstance(v, dict | list | tuple) for v in data):
        items = [pad + pretty_json(v, indent + 1) for v in data]
        return "[\n" + ",\n".join(items) + "\n" + "  " * indent + "]"
    return json.dumps(data, default=str)


def _json_block(data: Any, block_id: str) -> str:
    return f'<pre id="{esc(block_id)}">{esc(pretty_json(data))}</pre>'


# -- missions ---------------------------------------------------------------------------------------


def mission_checks(summary: Mapping[str, Any]) -> list[tuple[str, str]]:
    """What a reader must see first about a mission: (level, text), level fail, warn or ok."""
    s = summary
    out: list[tuple[str, str]] = []
    if s.get("committed_steps") == 0:
        out.append(("fail", f"no step committed: the mission verified nothing (0 of {s.get('steps')} steps)"))
    same = s.get("records_identical_on_all_nodes")
    if same:
        out.append(("ok", "records identical on every node that applied them"))
    elif same is None:
        out.append(("warn", "records not compared: no step's record was applied by two nodes"))
    else:
        out.append(("fail", "records DIFFER between nodes for some step"))
    for w in s.get("warnings", []):
        out.append(("warn", f"warning: {w}"))
    wrong = s.get("wrong_partition_step_count", 0)
    if wrong:
        ranges = ", ".join(
            f"{a:g}" if a == b else f"{a:g}-{b:g}" for a, b in s.get("wrong_partition_time_ranges_s", [])
        )
        out.append(
            (
                "fail",
                f"wrong partition (flags differ from the spoofed set) in {wrong} committed steps, "
                f"t = {ranges} s",
            )
        )
    else:
        out.append(("ok", "no wrong-partition step"))
    ig = s.get("integrity", {})
    mis = ig.get("misleading_drone_steps", 0)
    if mis:
        times = ", ".join(f"{t:g}" for t in ig.get("misleading_times_s", []))
        out.append(
            (
                "fail",
                f"misleading information (error above its protection level, status ok) in {mis} "
                f"drone-steps, t = {times} s",
            )
        )
    elif "misleading_drone_steps" in ig and mis is None:
        out.append(("warn", "misleading information not judged: no ok record has a protection level"))
    else:
        out.append(("ok", "no misleading information (every ok record within its protection levels)"))
    if unlevelled := ig.get("ok_drone_steps_without_level"):
        out.append(("warn", f"{unlevelled} drone-steps of ok records have no protection level: not judged"))
    for d in s.get("detections", []):
        who = f"{d['kind']} on drone {d['drone']} from {d['start_s']:g} s"
        if not d.get("flagged_at_least_once"):
            out.append(("fail", f"{who}: never flagged in {d['judged_steps']} judged steps"))
        elif d.get("time_to_sustained_detection_s") is None:
            out.append(
                ("warn", f"{who}: flagged in {fmt(d['flagged_fraction'])} of its steps, never sustained")
            )
        else:
            out.append(
                (
                    "ok",
                    f"{who}: flagged in {d['flagged_steps']} of {d['judged_steps']} judged steps, "
                    f"sustained after {d['time_to_sustained_detection_s']:g} s",
                )
            )
    skipped = s.get("skipped_steps", 0)
    if s.get("committed_steps") == 0:
        pass  # said first, as a failure
    elif skipped:
        sk = s.get("skipped_causes")  # summaries written before it have none
        why = (
            f": {sk['before_first_record']} before the first record, {sk['after_fault']} soon after "
            f"a fault, {sk['unexplained']} unexplained"
            if sk
            else ""
        )
        out.append(
            (
                "warn",
                f"{skipped} of {s.get('steps')} steps skipped (no committed record; longest run "
                f"{s.get('longest_skipped_run')}{why})",
            )
        )
    else:
        out.append(("ok", "every step committed"))
    fp = s.get("honest_false_positive_rate")
    if fp is None:
        out.append(("warn", "honest drones' flags not judged: no honest drone in a committed step"))
    elif fp:
        out.append(("warn", f"honest drones flagged in {fp:.2%} of their judged steps"))
    else:
        out.append(("ok", "no honest drone flagged"))
    hx = s.get("honest_worse_than_gnss")
    if isinstance(hx, Mapping):
        verdict = "fail" if hx.get("longest_s", 0) > 1 else "ok"
        out.append(
            (
                verdict,
                f"honest drones worse than raw GNSS in {hx.get('steps')} steps (longest run "
                f"{hx.get('longest_s'):g} s; target at most 1 s)",
            )
        )
    withheld = {k: v for k, v in ig.get("status_counts", {}).items() if k not in ("ok", "skipped") and v}
    if withheld:
        out.append(("warn", "records not ok: " + ", ".join(f"{k} {v}" for k, v in sorted(withheld.items()))))
    launch = s.get("launch")
    if isinstance(launch, Mapping):
        differ = launch.get("steps_with_records_differing") or []
        if differ:
            out.append(("fail", f"networked run: records differ between drones at steps {fmt(differ)}"))
        if launch.get("interrupted"):
            out.append(("fail", "networked run: interrupted before the scenario ended"))
        late = {d: t for d, t in (launch.get("up_after_step0_s") or {}).items() if t is None or t > 0}
        if late:
            out.append(
                (
                    "warn",
                    "networked run: drone processes not up at step 0: "
                    + ", ".join(
                        f"{d} ({'never' if t is None else f'{t:g} s late'})" for d, t in sorted(late.items())
                    ),
                )
            )
    return out


#: summary.json fields shown in the mission's summary table: (key, label)
MISSION_FIELDS = (
    ("drones", "drones"),
    ("steps", "steps"),
    ("committed_steps", "committed steps"),
    ("skipped_steps", "skipped steps"),
    ("longest_skipped_run", "longest run of skipped steps"),
    ("records_identical_on_all_nodes", "records identical on all nodes"),
    ("records_compared", "records compared between nodes"),
    ("wrong_partition_step_count", "wrong-partition steps"),
    ("honest_error_gnss_m", "honest drones: raw GNSS error, m"),
    ("honest_error_swarmraft_m", "honest drones: SwarmRaft error, m"),
    ("honest_snapshot_bound_m", "honest drones: snapshot bound, m"),
    ("honest_false_positive_rate", "honest drones: share of judged steps flagged"),
    ("sustained_detection_s", "sustained detection window, s"),
    ("latency_ms_median", "consensus latency median, ms"),
    ("latency_ms_p99", "consensus latency p99, ms"),
    ("raft_messages_per_committed_step", "Raft messages per committed step"),
    ("raft_minimum_per_step", "Raft minimum per step, 2(n-1)"),
    ("reports_per_step", "reports per step"),
)
INTEGRITY_FIELDS = (
    ("ok_steps", "committed steps with status ok"),
    ("status_counts", "steps per status"),
    ("median_hpl_m", "median horizontal protection level (ok records), m"),
    ("median_vpl_m", "median vertical protection level (ok records), m"),
    ("misleading_drone_steps", "misleading drone-steps (error above level, status ok)"),
    ("ok_drone_steps_without_level", "drone-steps of ok records without a level (not judged)"),
    ("misleading_times_s", "first times with misleading information, s"),
)
DETECTION_COLUMNS = (
    ("drone", "drone"),
    ("kind", "spoof"),
    ("start_s", "from, s"),
    ("judged_steps", "judged steps"),
    ("flagged_steps", "flagged steps"),
    ("flagged_fraction", "flagged share"),
    ("time_to_first_detection_s", "first flagged after, s"),
    ("time_to_sustained_detection_s", "sustained after, s"),
    ("reported_error_at_first_detection_m", "its GNSS error then, m"),
    ("mean_error_m", "mean error, m"),
    ("worst_error_m", "worst error, m"),
    ("mean_snapshot_bound_m", "snapshot bound, m"),
    ("p95_error_to_snapshot_bound", "p95 error / bound"),
)
_SHOWN = {
    "scenario", "version", "seed", "detector", "detector_params", "warnings", "bound_note",
    "wrong_partition_time_ranges_s", "wrong_partition_steps", "detections", "after_faults",
    "outages", "events", "integrity",
}  # fmt: skip


def mission_report(
    summary: Mapping[str, Any],
    scenario: Mapping[str, Any],
    figures: Sequence[Figure],
    provenance: Sequence[tuple[str, str, Any]],
    kind: str = "mission",
) -> str:
    """A mission's (or a networked run's, ``kind`` 'launch') report: checks first, then the
    summary, integrity, detections, wrong-partition steps, faults, outages, events, every
    other summary field, the figures and the scenario."""
    s = summary
    what = "networked run (swarmraft launch)" if kind == "launch" else "mission (swarmraft mission)"
    title = f"SwarmRaft report: {what.split(' (')[0]} {s.get('scenario', '')}"
    meta = [
        ("kind", "kind of folder", what),
        ("scenario", "scenario", s.get("scenario")),
        ("seed", "seed", s.get("seed")),
        ("version", "written by swarmraft", s.get("version")),
        ("detector", "detector", s.get("detector")),
        ("detector_params", "detector parameters", s.get("detector_params") or "defaults"),
        *provenance,
    ]
    wrong_rows = [
        {
            **w,
            "honest_flagged": w.get("honest_flagged") or [],
            "spoofed_not_flagged": w.get("spoofed_not_flagged") or [],
        }
        for w in s.get("wrong_partition_steps", [])
    ]
    sections = [
        "<h2>Checks</h2>" + checks_list(mission_checks(s)),
        "<h2>Summary</h2>"
        + key_table(((k, lab, s.get(k)) for k, lab in MISSION_FIELDS if k in s), "summary"),
        "<h2>Integrity</h2>"
        + key_table(((k, lab, s.get("integrity", {}).get(k)) for k, lab in INTEGRITY_FIELDS), "integrity"),
        "<h2>Spoofed drones: detection</h2>"
        + row_table(s.get("detections", []), DETECTION_COLUMNS, "detections"),
        f"<h2>Wrong-partition steps ({len(wrong_rows)})</h2>"
        + row_table(
            wrong_rows,
            (
                ("step", "step"),
                ("t", "t, s"),
                ("status", "status"),
                ("honest_flagged", "honest flagged"),
                ("spoofed_not_flagged", "spoofed not flagged"),
            ),
            "wrong-partition",
        ),
        "<h2>After each fault</h2>"
        + row_table(
            s.get("after_faults", []),
            (
                ("event", "event"),
                ("from_s", "from, s"),
                ("to_s", "to, s"),
                ("honest_error_swarmraft_m", "honest: SwarmRaft, m"),
                ("honest_error_gnss_m", "honest: raw GNSS, m"),
                ("skipped_steps", "skipped"),
                ("wrong_partition_steps", "wrong partition"),
            ),
            "after-faults",
        ),
        "<h2>GNSS outages</h2>"
        + row_table(
            s.get("outages", []),
            (
                ("drone", "drone"),
                ("from_s", "from, s"),
                ("to_s", "to, s"),
                ("mean_error_swarmraft_m", "SwarmRaft, m"),
                ("mean_error_ins_aligned_m", "INS aligned at start, m"),
                ("mean_error_ins_alone_m", "INS never reset, m"),
                ("ins_alone_error_at_start_m", "INS never reset at start, m"),
                ("mean_snapshot_bound_m", "snapshot bound, m"),
            ),
            "outages",
        ),
        "<h2>Events</h2>"
        + (
            '<ul id="events">' + "".join(f"<li>{esc(e)}</li>" for e in s.get("events", [])) + "</ul>"
            if s.get("events")
            else '<p id="events">none</p>'
        ),
        f"<p><i>{esc(s.get('bound_note', ''))}</i></p>",
    ]
    other = [(k, k, v) for k, v in s.items() if k not in _SHOWN and k not in dict(MISSION_FIELDS)]
    if other:
        sections.append("<h2>Other summary fields</h2>" + key_table(other, "other-fields"))
    sections.append(
        figures_section(figures, MISSION_FIGURES, "`swarmraft mission` and `swarmraft launch` draw them.")
    )
    sections.append("<h2>Scenario (scenario.json)</h2>" + _json_block(scenario, "scenario"))
    return page(title, meta, sections)


# -- sweeps and comparisons -----------------------------------------------------------------------

#: cells.csv columns of the main table of a sweep or a comparison: (column, header)
CELL_MAIN = (
    ("n", "n"),
    ("f", "f"),
    ("trials", "trials"),
    ("baseline_mean", "reported error, m"),
    ("recovered_mean", "verified error, m"),
    ("recovered_sem", "s.e., m"),
    ("recovered_median", "median, m"),
    ("honest_mean", "honest drones, m"),
    ("detection_rate", "detected"),
    ("false_positive_rate", "false positives"),
    ("identification_rate", "exact identification"),
    ("status_ok", "status ok"),
    ("misleading_rate", "misleading rate"),
    ("attacked_efficiency", "efficiency (attacked)"),
)


def _runs_rows(run: Mapping[str, Any]) -> list[dict[str, Any]]:
    return [
        {**r, "cells": ", ".join(f"({a}, {b})" for a, b in r.get("cells", []))} for r in run.get("runs", [])
    ]


RUN_COLUMNS = (
    ("started", "started (UTC)"),
    ("executor", "executor"),
    ("wall_seconds", "wall time, s"),
    ("seed", "seed"),
    ("cells", "cells computed"),
    ("config_sha256", "config sha256"),
)


def sweep_report(
    cells: Mapping[str, np.ndarray],
    run: Mapping[str, Any],
    figures: Sequence[Figure],
    provenance: Sequence[tuple[str, str, Any]],
    folder: str,
) -> str:
    """A sweep's report: the cells (main columns, then every column of cells.csv), the runs
    that made them, the detector parameters and calibration per n, the figures and the config."""
    config = run["config"]
    att = config.get("attack", {}).get("name")
    title = (
        f"SwarmRaft report: sweep, preset {config.get('preset')}, detector {config.get('detector')}, "
        f"attack {att}"
    )
    meta = [
        ("kind", "kind of folder", "sweep (swarmraft sweep)"),
        ("seed", "seed", run.get("seed")),
        ("version", "written by swarmraft", run.get("version")),
        ("python", "Python, numpy", f"{run.get('python')}, {run.get('numpy')}"),
        ("config_sha256", "config sha256", run.get("config_sha256")),
        ("trials", "trials per cell", config.get("trials")),
        *provenance,
    ]
    rows = columns_rows(cells)
    cal = run.get("calibration") or {}
    sections = [
        f"<h2>Cells ({len(rows)})</h2>" + row_table(rows, CELL_MAIN, "cells-main"),
        "<h2>Every column of cells.csv</h2>" + row_table(rows, [(c, c) for c in cells], "cells"),
        "<h2>Runs that computed cells</h2>" + row_table(_runs_rows(run), RUN_COLUMNS, "runs"),
        "<h2>Detector parameters per n</h2>"
        + key_table(
            (
                (n, f"n = {n}", p or "defaults")
                for n, p in sorted(
                    (run.get("detector_params") or {}).items(),
                    key=lambda kv: (
                        not str(kv[0]).isdigit(),
                        int(kv[0]) if str(kv[0]).isdigit() else 0,
                        str(kv[0]),
                    ),
                )
            ),
            "detector-params",
        ),
    ]
    if cal:
        sections.append("<h2>Calibration</h2>" + _json_block(cal, "calibration"))
    sections.append(figures_section(figures, SWEEP_FIGURES, f"`swarmraft figure all {folder}` draws them."))
    sections.append("<h2>Config (run.json)</h2>" + _json_block(config, "config"))
    return page(title, meta, sections)


def compare_report(
    table: Mapping[str, np.ndarray],
    runs: Mapping[str, Mapping[str, Any]],
    figures: Sequence[Figure],
    expected: Sequence[str],
    provenance: Sequence[tuple[str, str, Any]],
) -> str:
    """A detector comparison's report: compare.csv (main columns with the attack and detector,
    then every column), the sweeps it ran (each one's seed, version and runs), the figures
    and the config they share. ``runs`` maps each sweep's folder (attack/detector) to its run.json."""
    rows = columns_rows(table)
    dets = list(dict.fromkeys(str(d) for d in table["detector"]))
    atks = list(dict.fromkeys(str(a) for a in table["attack"]))
    first = next(iter(runs.values()), {})
    config = dict(first.get("config", {}))
    config["detector"] = dets
    config["attack"] = {**config.get("attack", {}), "name": atks}
    title = f"SwarmRaft report: detectors compared ({', '.join(dets)}) on {', '.join(atks)}"
    seeds = sorted({r.get("seed") for r in runs.values()}, key=str)
    versions = sorted({r.get("version") for r in runs.values()}, key=str)
    meta = [
        ("kind", "kind of folder", "detector comparison (swarmraft compare)"),
        ("seed", "seed", seeds[0] if len(seeds) == 1 else seeds),
        ("version", "written by swarmraft", versions[0] if len(versions) == 1 else versions),
        ("preset", "preset", config.get("preset")),
        ("trials", "trials per cell", config.get("trials")),
        *provenance,
    ]
    main = (("attack", "attack"), ("detector", "detector"), *CELL_MAIN)
    sweeps = [
        {
            "folder": name,
            "seed": r.get("seed"),
            "version": r.get("version"),
            "config_sha256": r.get("config_sha256"),
            "started": ", ".join(str(x.get("started")) for x in r.get("runs", [])),
        }
        for name, r in runs.items()
    ]
    sections = [
        f"<h2>Cells ({len(rows)})</h2>" + row_table(rows, main, "cells-main"),
        "<h2>Every column of compare.csv</h2>" + row_table(rows, [(c, c) for c in table], "cells"),
        "<h2>Sweeps</h2>"
        + row_table(
            sweeps,
            (
                ("folder", "folder"),
                ("seed", "seed"),
                ("version", "version"),
                ("started", "started (UTC)"),
                ("config_sha256", "config sha256"),
            ),
            "sweeps",
        ),
        figures_section(figures, expected, "`swarmraft compare` draws them."),
        "<h2>Config (shared by the sweeps; detector and attack vary)</h2>" + _json_block(config, "config"),
    ]
    return page(title, meta, sections)
