"""`swarmraft report` and `swarmraft figure animation`: the numbers in the report are the
folder's, every figure is in it and nothing is fetched; the animation has the frames asked
for; bad input is one line."""

import base64
import json
import math
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from report_page import Page
from swarmraft.cli import main
from swarmraft.experiments.compare import compare_figure_names
from swarmraft.experiments.tables import read_table
from swarmraft.viz import animation as va
from swarmraft.viz import report as vr

pytest_plugins = ("report_folders",)  # the folders' fixtures


def report_of(folder, *extra) -> Page:
    r = CliRunner().invoke(main, ["report", str(folder), *extra])
    assert r.exit_code == 0, r.output
    target = folder / "report.html" if not extra else extra[-1]
    assert f"wrote {target}" in r.output
    return Page(open(target, encoding="utf-8").read())


def same(text: str, value) -> bool:
    """A report's cell says ``value`` (numbers to 6 significant digits)."""
    if value is None:
        return text == "n/a"
    if isinstance(value, bool):
        return text == ("yes" if value else "no")
    if isinstance(value, int | float):
        if isinstance(value, float) and math.isnan(value):
            return text == "nan"
        return math.isclose(float(text), value, rel_tol=5e-6, abs_tol=1e-300)
    return text == str(value)


def test_mission_report_holds_the_summary_numbers(mission_dir):
    page = report_of(mission_dir)
    s = json.loads((mission_dir / "summary.json").read_text())
    shown = page.keys["summary"]
    for key, _ in vr.MISSION_FIELDS:
        assert same(shown[key], s[key]), key
    for key in ("ok_steps", "median_hpl_m", "median_vpl_m", "misleading_drone_steps"):
        assert same(page.keys["integrity"][key], s["integrity"][key]), key
    rows = page.tables["detections"]
    assert len(rows) == len(s["detections"]) == 1
    for key, _ in vr.DETECTION_COLUMNS:
        assert same(rows[0][key], s["detections"][0][key]), key
    wrong = page.tables["wrong-partition"]
    assert [int(r["step"]) for r in wrong] == [w["step"] for w in s["wrong_partition_steps"]]
    assert [r["event"] for r in page.tables["after-faults"]] == [a["event"] for a in s["after_faults"]]
    meta = page.keys["provenance"]
    assert same(meta["seed"], s["seed"]) and meta["version"] == s["version"]
    assert meta["command"] == f"swarmraft report {mission_dir}"
    assert json.loads(page.by_id["scenario"]) == json.loads((mission_dir / "scenario.json").read_text())
    # the mission has a spoof and a crash: its checks say what happened, failures first
    levels = [lv for lv, _ in page.checks]
    assert levels == sorted(levels, key=["fail", "warn", "ok"].index)
    assert ("ok", "records identical on every node that applied them") in page.checks
    assert any(lv == "warn" and "steps skipped" in t for lv, t in page.checks) == (s["skipped_steps"] > 0)
    assert any(lv == "fail" and "wrong partition" in t for lv, t in page.checks) == bool(
        s["wrong_partition_step_count"]
    )


def test_mission_failures_come_first_and_none_is_left_out(mission_dir, tmp_path):
    folder = tmp_path / "bad"
    shutil.copytree(mission_dir, folder)
    s = json.loads((folder / "summary.json").read_text())
    s["records_identical_on_all_nodes"] = False
    s["warnings"] = ["4 drones spoofed at once"]
    s["detections"][0]["flagged_at_least_once"] = False
    s["integrity"]["misleading_drone_steps"] = 3
    s["integrity"]["misleading_times_s"] = [2.5]
    s["launch"] = {"steps_with_records_differing": [7], "interrupted": True, "up_after_step0_s": {"3": None}}
    (folder / "summary.json").write_text(json.dumps(s))
    page = report_of(folder)
    fails = [t for lv, t in page.checks if lv == "fail"]
    assert page.checks[: len(fails)] == [("fail", t) for t in fails]  # before any warning or pass
    for needle in (
        "records DIFFER",
        "never flagged",
        "misleading information",
        "records differ between drones at steps 7",
        "interrupted",
    ):
        assert any(needle in t for t in fails), needle
    warns = [t for lv, t in page.checks if lv == "warn"]
    assert "warning: 4 drones spoofed at once" in warns
    assert any("not up at step 0: 3 (never)" in t for t in warns)
    assert page.by_id["check-counts"].startswith(f"{len(fails)} failed, {len(warns)} warnings")
    # fields the report has no section for are still shown
    assert "steps_with_records_differing" in page.keys["other-fields"]["launch"]


def test_a_networked_runs_folder_is_reported_as_one(mission_dir, tmp_path):
    folder = tmp_path / "launch"
    shutil.copytree(mission_dir, folder, ignore=shutil.ignore_patterns("report.html"))
    (folder / "records.csv").write_text("step,identical\n0,1\n")
    page = report_of(folder)
    assert page.keys["provenance"]["kind"] == "networked run (swarmraft launch)"
    assert page.by_id.get("checks")  # the mission's checks, as for a simulated mission


def data_images(page: Page) -> dict[str, bytes]:
    return {
        a["data-name"]: base64.b64decode(a["src"].split(",", 1)[1], validate=True)
        for tag, a in page.tags
        if tag == "img"
    }


def no_outside_resource(page: Page, text: str) -> None:
    """Nothing in the document would make a browser fetch: every src and href is a data: URI,
    no script, link, frame, object or base element, no url() in the style, a CSP that allows
    data: images and inline style only."""
    for tag, a in page.tags:
        assert tag not in ("script", "link", "iframe", "object", "embed", "base", "frame"), tag
        for attr in ("src", "href", "srcset", "action", "poster", "background"):
            if attr in a:
                assert a[attr].startswith("data:"), (tag, attr, a[attr][:40])
    assert "http://" not in text and "https://" not in text
    assert "url(" not in text
    csp = [
        a["content"]
        for tag, a in page.tags
        if tag == "meta" and a.get("http-equiv") == "Content-Security-Policy"
    ]
    assert csp == ["default-src 'none'; img-src data:; style-src 'unsafe-inline'"]


def test_every_figure_is_embedded_byte_for_byte_and_nothing_is_fetched(mission_dir):
    page = report_of(mission_dir)
    files = {p.name: p.read_bytes() for p in (mission_dir / "figures").iterdir()}
    assert set(vr.MISSION_FIGURES) <= set(files)
    assert data_images(page) == files
    assert "missing-figures" not in page.by_id and "unshown-figures" not in page.by_id
    no_outside_resource(page, (mission_dir / "report.html").read_text())


def test_missing_and_unreadable_figures_are_named_not_dropped(mission_dir, tmp_path):
    folder = tmp_path / "m"
    shutil.copytree(mission_dir, folder, ignore=shutil.ignore_patterns("report.html"))
    (folder / "figures" / "swarm_maps.png").unlink()
    broken = folder / "figures" / "messages_per_step.png"
    broken.write_bytes(broken.read_bytes()[:2000])  # cut short
    (folder / "figures" / "notes.txt").write_text("x")
    page = report_of(folder)
    assert "swarm_maps.png" in page.by_id["missing-figures"]
    assert "messages_per_step.png: unreadable" in page.by_id["unshown-figures"]
    assert "notes.txt: not shown" in page.by_id["unshown-figures"]
    assert set(data_images(page)) == {"error_over_time.png", "consensus_latency.png"}


def test_text_from_the_folder_is_escaped(mission_dir, tmp_path):
    folder = tmp_path / "m"
    shutil.copytree(mission_dir, folder, ignore=shutil.ignore_patterns("report.html"))
    s = json.loads((folder / "summary.json").read_text())
    s["scenario"] = "<script>alert(1)</script>"
    s["events"] = ['1.0 s: <img src="https://example.org/x.png">']
    (folder / "summary.json").write_text(json.dumps(s))
    page = report_of(folder)
    text = (folder / "report.html").read_text()
    assert not [t for t, _ in page.tags if t == "script"]
    assert [a["data-name"] for t, a in page.tags if t == "img"] == list(vr.MISSION_FIGURES)
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text
    assert page.by_id["events"] == '1.0 s: <img src="https://example.org/x.png">'  # shown as text


def test_sweep_report_holds_every_cell_of_cells_csv(sweep_dir):
    page = report_of(sweep_dir)
    cells = read_table(sweep_dir / "cells.csv")
    rows = page.tables["cells"]
    assert len(rows) == len(cells["n"]) == 1
    for column, values in cells.items():
        for row, value in zip(rows, values, strict=True):
            assert same(row[column], value.item() if hasattr(value, "item") else value), column
    main_row = page.tables["cells-main"][0]
    assert same(main_row["recovered_mean"], float(cells["recovered_mean"][0]))
    run = json.loads((sweep_dir / "run.json").read_text())
    assert json.loads(page.by_id["config"]) == run["config"]
    assert same(page.keys["provenance"]["seed"], run["seed"])
    assert page.keys["provenance"]["config_sha256"] == run["config_sha256"]
    assert set(data_images(page)) == {"scaling.png"}
    missing = page.by_id["missing-figures"]
    assert "distribution.png, recovery.png" in missing and f"swarmraft figure all {sweep_dir}" in missing
    no_outside_resource(page, (sweep_dir / "report.html").read_text())


def test_compare_report_holds_every_row_of_compare_csv(compare_dir, tmp_path):
    target = tmp_path / "sub" / "cmp.html"
    page = report_of(compare_dir, "--out", str(target))
    table = read_table(compare_dir / "compare.csv")
    rows = page.tables["cells"]
    assert len(rows) == len(table["n"]) == 2
    for column, values in table.items():
        for row, value in zip(rows, values, strict=True):
            assert same(row[column], value.item() if hasattr(value, "item") else value), column
    assert [r["detector"] for r in page.tables["cells-main"]] == ["paper", "clique"]
    assert [r["folder"] for r in page.tables["sweeps"]] == ["jump/paper", "jump/clique"]
    want = compare_figure_names(table)
    assert set(data_images(page)) == set(want) and len(want) >= 5
    assert json.loads(page.by_id["config"])["detector"] == ["paper", "clique"]
    assert not (compare_dir / "report.html").exists()  # --out was given
    no_outside_resource(page, target.read_text())


def one_error_line(args, needle: str) -> None:
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.output
    assert needle in lines[0], lines[0]


def test_report_bad_input_is_one_line_and_writes_nothing(mission_dir, tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "a-file").write_text("x")
    corrupt = tmp_path / "corrupt"
    shutil.copytree(mission_dir, corrupt, ignore=shutil.ignore_patterns("report.html"))
    (corrupt / "summary.json").write_text("{not json")
    holder = tmp_path / "holder"
    shutil.copytree(mission_dir, holder / "m1", ignore=shutil.ignore_patterns("report.html"))
    cases = [
        (["report", str(tmp_path / "empty")], f"DIR: {tmp_path / 'empty'} is not a results folder"),
        (["report", str(tmp_path / "nope")], f"DIR: {tmp_path / 'nope'}: no such folder"),
        (["report", str(tmp_path / "a-file")], "is a file, not a results folder"),
        (["report", str(corrupt)], f"{corrupt / 'summary.json'}: unreadable"),
        (["report", str(holder)], "these subfolders are: m1"),
        (["report", str(mission_dir), "--out", str(tmp_path / "r.txt")], "--out: "),
        (["report", str(mission_dir), "--out", str(tmp_path / "empty.html")], "--out: "),
    ]
    (tmp_path / "empty.html").mkdir()
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    for args, needle in cases:
        one_error_line(args, needle)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


# -- the animation ----------------------------------------------------------------------------------


def gif_frames(path) -> tuple[Image.Image, list[np.ndarray]]:
    im = Image.open(path)
    frames = []
    for k in range(im.n_frames):
        im.seek(k)
        frames.append(np.asarray(im.convert("RGB")))
    return im, frames


def test_animation_gif_has_one_distinct_frame_per_every_steps(mission_dir, tmp_path):
    target = tmp_path / "a.gif"
    args = ["figure", "animation", str(mission_dir), "--every", "4", "--fps", "5", "--out", str(target)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    steps = len(read_table(mission_dir / "steps.csv")["step"]) // 6
    want = math.ceil(steps / 4)
    assert f"wrote {target} ({want} frames, one per 4 of the {steps} steps" in r.output
    assert not list(tmp_path.glob(".*part*"))  # the render's temporary file is gone
    im, frames = gif_frames(target)
    assert im.n_frames == want == 11
    assert im.size == (512, 512)
    assert im.info["duration"] == 200  # 5 frames per second
    for a, b in zip(frames, frames[1:], strict=False):
        assert (a != b).any(axis=2).mean() > 0.001  # at least the clock in the title moves


def test_animation_frames_show_the_steps_leader_and_flags(mission_dir, monkeypatch, tmp_path):
    """The frames drawn, read from the figure before each is grabbed."""
    from matplotlib import animation

    from swarmraft.experiments.mission_folder import read_mission

    seen = []

    def grab(self, **kw):
        ax = self.fig.axes[0]
        labels = {t.get_text() for t in self.fig.legends[0].get_texts()}
        seen.append((self.fig._suptitle.get_text(), ax.get_title(), labels))

    monkeypatch.setattr(animation.PillowWriter, "grab_frame", grab)
    monkeypatch.setattr(animation.PillowWriter, "finish", lambda self: open(self.outfile, "wb").close())
    m = read_mission(mission_dir)
    log = m.log
    va.swarm_animation(log, tmp_path / "unused.gif", every=3, title="short")
    steps = va.frame_steps(len(log.t), 3)
    assert len(seen) == len(steps)
    for (title, axtitle, labels), k in zip(seen, steps, strict=True):
        assert title.startswith(f"short: t = {log.t[k]:.1f} s, step {k} of {len(log.t) - 1}")
        assert ("Raft leader" in labels) == (log.leader[k] > 0)
        assert (f"leader {log.leader[k]}" in title) == (log.leader[k] > 0)
        flagged = np.flatnonzero(log.faulty[k] & log.committed[k]) + 1
        # every flag is shown: ringed where it was placed, at its report where it was not
        assert any(lb.startswith("flagged") for lb in labels) == (flagged.size > 0)
        if log.committed[k]:
            assert axtitle.startswith(
                f"record {log.status[k]}; flagged: {', '.join(map(str, flagged)) or 'none'}"
            )
        else:
            assert axtitle.startswith("no record (skipped)")
        assert ("crashed (no report)" in labels) == (~log.alive[k]).any()


def test_an_interrupted_animation_leaves_no_file(mission_dir, monkeypatch, tmp_path):
    from matplotlib import animation

    from swarmraft.experiments.mission_folder import read_mission

    grabbed = []
    grab = animation.PillowWriter.grab_frame

    def grab_then_stop(self, **kw):
        grab(self, **kw)
        grabbed.append(1)
        if len(grabbed) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(animation.PillowWriter, "grab_frame", grab_then_stop)
    with pytest.raises(KeyboardInterrupt):
        va.swarm_animation(read_mission(mission_dir).log, tmp_path / "a.gif", every=4)
    assert len(grabbed) == 3 and list(tmp_path.iterdir()) == []


def test_default_every_keeps_a_minute_under_120_frames():
    assert va.default_every(601) == 6 and len(va.frame_steps(601, 6)) == 101
    assert va.default_every(41) == 1 and len(va.frame_steps(41, 1)) == 41
    assert len(va.frame_steps(120, va.default_every(120))) == 120
    assert len(va.frame_steps(121, va.default_every(121))) == 61


def test_animation_bad_input_is_one_line_and_writes_nothing(mission_dir, sweep_dir, tmp_path, monkeypatch):
    monkeypatch.setattr(va.shutil, "which", lambda name: None)  # no ffmpeg, whatever this machine has
    cases = [
        (
            ["figure", "animation", str(sweep_dir)],
            "is a sweep folder; `swarmraft figure animation` needs a mission",
        ),
        (["figure", "animation", str(mission_dir), "--out", str(tmp_path / "a.mp4")], "needs ffmpeg on PATH"),
        (
            ["figure", "animation", str(mission_dir), "--out", str(tmp_path / "a.png")],
            "ending in .gif or .mp4",
        ),
        (["figure", "animation", str(tmp_path / "nope")], "RESULTS: "),
        (
            ["figure", "scaling", str(mission_dir)],
            "is a mission folder; `swarmraft figure scaling` draws from a sweep",
        ),
        (["figure", "scaling", str(sweep_dir), "--fps", "3"], "--fps: only for `swarmraft figure animation`"),
        (["figure", "animation", str(mission_dir), "--every", "0"], "--every"),
    ]
    before = sorted(mission_dir.rglob("*")) + sorted(tmp_path.rglob("*"))
    for args, needle in cases:
        one_error_line(args, needle)
    assert sorted(mission_dir.rglob("*")) + sorted(tmp_path.rglob("*")) == before


def test_misleading_information_not_judged_is_a_warning_not_a_pass(mission_dir, tmp_path):
    folder = tmp_path / "paper"
    shutil.copytree(mission_dir, folder)
    s = json.loads((folder / "summary.json").read_text())
    s["integrity"]["misleading_drone_steps"] = None  # a `paper` mission: no levels
    (folder / "summary.json").write_text(json.dumps(s))
    page = report_of(folder)
    assert ("warn", "misleading information not judged: no ok record has a protection level") in page.checks
    assert not any("no misleading information" in t for _, t in page.checks)
