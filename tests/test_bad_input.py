"""Bad input on the command line: one line starting with `error:` that names the option, field
or file, exit status 2, and nothing written anywhere (the working folder included)."""

from pathlib import Path

import pytest
from click.testing import CliRunner

from swarmraft.cli import main


def tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` with its bytes (folders by a marker), to compare before and after."""
    out = {}
    for p in sorted(root.rglob("*")):
        out[str(p.relative_to(root))] = p.read_bytes() if p.is_file() else b"<dir>"
    return out


def fails_cleanly(args: list[str], needle: str, root: Path) -> str:
    """Run ``swarmraft ARGS`` in ``root`` (the working folder); assert the one-line error that
    contains ``needle``, exit status 2 and that nothing under ``root`` changed."""
    before = tree(root)
    r = CliRunner().invoke(main, args)
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2, r.output
    assert len(lines) == 1, r.output
    assert lines[0].startswith("error: "), r.output
    assert needle in lines[0], r.output
    assert tree(root) == before
    return lines[0]


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


SCENARIO = """
name = "tiny"
drones = 5
duration_s = 2
"""


def scenario(root: Path, extra: str) -> str:
    path = root / "s.toml"
    path.write_text(SCENARIO + extra)
    return str(path)


def test_out_below_a_file(cwd):
    (cwd / "file").write_text("x")
    line = fails_cleanly(["sweep", "--n", "5", "--trials", "5", "--out", "file/sub"], "--out", cwd)
    assert "file is a file, not a folder" in line


@pytest.mark.parametrize(
    "command",
    [
        ["sweep", "--n", "5", "--trials", "5"],
        ["compare", "--n", "5", "--trials", "5"],
        ["curves", "--n", "9", "--f", "2"],
        ["demo"],
        ["mission", "--scenario", "demo"],
    ],
)
def test_empty_out_is_refused(cwd, command):
    line = fails_cleanly([*command, "--out", ""], "--out", cwd)
    assert "give a folder name" in line


def test_scenario_name_cannot_leave_the_results_folder(cwd):
    path = scenario(cwd, "").replace("", "")
    Path(path).write_text(SCENARIO.replace('"tiny"', '"../../escape"'))
    line = fails_cleanly(["mission", "--scenario", path], "name", cwd)
    assert "s.toml: name: String should match pattern" in line


def test_n_below_3_is_refused_not_dropped(cwd):
    line = fails_cleanly(
        ["sweep", "--n", "1-3", "--out", "o"], "error: --n: every swarm size must be >= 3", cwd
    )
    assert "got 1, 2" in line


def test_a_known_set_needs_a_detector_with_a_noise_model(cwd):
    fails_cleanly(
        ["sweep", "--known-set", "--n", "5", "--trials", "5", "--out", "o"],
        "error: --known-set: detector 'paper' has no noise model to estimate with; use clique, fde",
        cwd,
    )
    fails_cleanly(
        [
            "sweep",
            "--known-set",
            "--detector",
            "joint",
            "--param",
            "set_search=300",
            "--n",
            "9",
            "--out",
            "o",
        ],
        "error: --known-set: set_search is a detection parameter of joint, not used with the true honest set",
        cwd,
    )
    # the rival search's parameters are detection's too, though every statistical detector has them
    fails_cleanly(
        ["sweep", "--known-set", "--detector", "clique", "--param", "better_fit_margin=3", "--n", "9"],
        "error: --known-set: better_fit_margin is a detection parameter of clique, not used with the",
        cwd,
    )


def test_a_sweep_flag_the_config_refuses_is_named_as_the_flag(cwd):
    # the config's own field names (attack.name, detector, detector_params) mean nothing on
    # the command line
    fails_cleanly(
        ["sweep", "--attack", "nope", "--n", "5", "--out", "o"], "error: --attack: unknown attack 'nope'", cwd
    )
    fails_cleanly(
        ["sweep", "--detector", "nope", "--n", "5", "--out", "o"],
        "error: --detector: unknown name 'nope'",
        cwd,
    )
    fails_cleanly(
        ["sweep", "--param", "k=-1", "--detector", "clique", "--n", "5", "--out", "o"],
        "error: --param: clique.k:",
        cwd,
    )


def test_calibrate_needs_3_drones(cwd):
    fails_cleanly(
        ["calibrate", "--n", "2", "--trials", "10"], "error: --n: every swarm size must be >= 3", cwd
    )


def test_compare_without_detectors(cwd):
    line = fails_cleanly(["compare", "--detectors", "", "--n", "5", "--out", "o"], "--detectors", cwd)
    assert "no names in ''" in line
    fails_cleanly(["compare", "--detectors", "paper,nope", "--out", "o"], "unknown detector 'nope'", cwd)
    fails_cleanly(["compare", "--attacks", " , ", "--out", "o"], "--attacks", cwd)


def test_a_compare_param_every_detector_must_take(cwd):
    """--param goes to every detector compared: one that lacks it is refused by name before
    any sweep runs, wherever it is in the list."""
    for dets in ("paper,joint", "joint,paper"):
        args = ["compare", "--detectors", dets, "--param", "registration_rivals=false", "--out", "o"]
        line = fails_cleanly(args, "--param", cwd)
        assert "paper.registration_rivals: unknown parameter" in line
    # a parameter the --config file gives is the file's fault, not --param's
    (cwd / "cfg.toml").write_text('detector = "paper"\n[detector_params]\ntau = 0.3\n')
    args = ["compare", "--config", "cfg.toml", "--detectors", "paper,joint", "--param", "link_rounds=2"]
    line = fails_cleanly([*args, "--out", "o"], "--config cfg.toml", cwd)
    assert "joint.tau: unknown parameter" in line and "--param" not in line


def test_workers_0_fails_before_anything_starts(cwd):
    line = fails_cleanly(["sweep", "--n", "5", "--workers", "0", "--out", "o"], "--workers", cwd)
    assert "0 is not in the range x>=1" in line


def test_demo_trials_0_fails_before_the_mission(cwd):
    fails_cleanly(["demo", "--trials", "0", "--out", "o"], "--trials", cwd)


def test_scheduler_is_named(cwd):
    line = fails_cleanly(["sweep", "--n", "5", "--scheduler", "bogus", "--out", "o"], "--scheduler", cwd)
    assert "expected tcp://HOST:PORT or 'local', got 'bogus'" in line


def test_raft_fuzz_needs_3_nodes(cwd):
    fails_cleanly(["raft-fuzz", "--nodes", "1", "--seeds", "1"], "--nodes", cwd)


@pytest.mark.parametrize(
    "extra,needle",
    [
        ("[gnss]\nsigma_h = inf\n", "gnss.sigma_h: Input should be a finite number"),
        ("[ranging]\nsigma = nan\n", "ranging.sigma: Input should be a finite number"),
        (
            '[[spoof]]\nkind = "jump"\ndrones = [2]\nstart_s = 5\n',
            "spoof[0].start_s: 5 s is not before the mission's end (2 s)",
        ),
        (
            '[[spoof]]\nkind = "jump"\ndrones = [2]\nstart_s = 1\nend_s = 0.5\n',
            "spoof[0].end_s: 0.5 s is not after start_s = 1 s",
        ),
        (
            "[[outage]]\ndrones = [3]\nstart_s = 1.5\nend_s = 1\n",
            "outage[0].end_s: 1 s is not after start_s = 1.5 s",
        ),
        (
            "[[outage]]\ndrones = [3]\nstart_s = 3\n",
            "outage[0].start_s: 3 s is not before the mission's end (2 s)",
        ),
        ('[[fault]]\nkind = "crash-leader"\nat_s = 9\n', "fault[0].at_s: 9 s is not before"),
        ("dt_s = 5\n", "dt_s: a step of 5 s is longer than the mission (2 s)"),
        ("[motion]\nwaypoints = []\n", "motion.waypoints: give at least 2 waypoints"),
        ("[motion]\nwaypoints = [[0, 0, 0]]\n", "motion.waypoints: give at least 2 waypoints"),
        ("[network]\ndelay_ms = [5, 1]\n", "network.delay_ms: low 5 ms is above high 1 ms"),
        ("[protocol]\ncommittee = 4\n", "protocol.committee: committee size must be odd and in 1..7, got 4"),
        ("[protocol]\ncensor_k = 30\n", "protocol.censor_k: 30 must be below censor_m = 20"),
        (
            '[[spoof]]\nkind = "collusion"\ndrones = [2]\nstart_s = 0.2\npivots = [2]\n',
            "spoof[0].pivots: a pivot is an honest drone, and 2 is spoofed",
        ),
    ],
)
def test_scenario_field_is_named(cwd, extra, needle):
    path = scenario(cwd, extra)
    fails_cleanly(["mission", "--scenario", path, "--out", "o"], f"s.toml: {needle}", cwd)


def test_unknown_scenario_name_lists_the_shipped_ones(cwd):
    line = fails_cleanly(["mission", "--scenario", "nope", "--out", "o"], "--scenario: no file nope", cwd)
    assert "shipped: coordinated-drag, demo, drag-off" in line


def test_sweep_config_with_inf(cwd):
    (cwd / "c.toml").write_text('preset = "realistic"\nn = [5]\n[gnss]\nsigma_h = inf\n')
    fails_cleanly(
        ["sweep", "--config", "c.toml", "--out", "o"],
        "--config c.toml: gnss.sigma_h: Input should be a finite",
        cwd,
    )


def test_a_bad_field_from_the_config_file_names_the_file_and_a_flag_names_the_flag(cwd):
    (cwd / "c.toml").write_text("n = [2]\n")
    fails_cleanly(
        ["sweep", "--config", "c.toml", "--out", "o"], "error: --config c.toml: n: every swarm", cwd
    )
    fails_cleanly(["sweep", "--config", "c.toml", "--n", "2", "--out", "o"], "error: --n: every swarm", cwd)


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("swept") / "ref"
    r = CliRunner().invoke(
        main, ["sweep", "--n", "5", "--diagonal", "--trials", "20", "--workers", "1", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    return out


@pytest.mark.parametrize(
    "target,needle",
    [
        ("", "--out: give an image file name ending in .png, .pdf or .svg"),
        ("picture", "--out: picture: give an image file name ending in .png, .pdf or .svg"),
        ("folder.png", "--out: folder.png is a folder"),
        ("file.txt/x.png", "--out: file.txt is a file, not a folder"),
    ],
)
def test_figure_out_must_be_an_image_file(cwd, swept, target, needle):
    (cwd / "folder.png").mkdir()
    (cwd / "file.txt").write_text("x")
    fails_cleanly(["figure", "scaling", str(swept), "--out", target], needle, cwd)


@pytest.mark.parametrize("command", [["mission", "--scenario"], ["sweep", "--config"]])
def test_a_file_that_is_not_text_is_named(cwd, command):
    (cwd / "bin.toml").write_bytes(b"\xff\xfe")
    line = fails_cleanly([*command, "bin.toml", "--out", "o"], f"{command[1]} bin.toml: not a text file", cwd)
    assert "utf-8" in line


@pytest.mark.parametrize(
    "args,needle",
    [
        (["compare", "--workers", "0"], "--workers: 0 is not in the range x>=1"),
        (["demo", "--workers", "0"], "--workers: 0 is not in the range x>=1"),
        (
            ["compare", "--scheduler", "bogus"],
            "--scheduler: expected tcp://HOST:PORT or 'local', got 'bogus'",
        ),
        (["compare", "--trials", "0"], "--trials: 0 is not in the range x>=1"),
        (["curves", "--detectors", ""], "--detectors: no names in ''"),
        (["compare", "--n", "1-3"], "error: --n: every swarm size must be >= 3"),
        (["compare", "--f", "0"], "error: --f: every attacker count must be >= 1"),
    ],
)
def test_other_commands_check_the_same_options(cwd, args, needle):
    fails_cleanly([*args, "--out", "o"], needle, cwd)


@pytest.mark.parametrize(
    "extra,args,needle",
    [
        ('[protocol]\ndetector = "nope"\n', [], "s.toml: protocol.detector: unknown name 'nope'"),
        (
            '[protocol]\ndetector = "joint"\ndetector_params = {colour = 1}\n',
            [],
            "s.toml: protocol.detector_params: joint.colour: unknown parameter",
        ),
        ("", ["--detector", "nope"], "--detector: unknown name 'nope'"),
        # a negative time drew the map counted from the end, a late one the last step's
        ("maps_at_s = [-1.0, 99]\n", [], "s.toml: maps_at_s: [-1.0, 99.0] outside the mission"),
        # a misspelt key: named as the file spells it, list items by index, a close key offered
        (
            "[[spoof]]\nkind = 'jump'\ndrones = [2]\nstart_s = 1.0\nmagnitud = 20\n",
            [],
            "spoof[0].magnitud: unknown parameter (did you mean magnitude?)",
        ),
        ("[gnss]\nsigm = 2\n", [], "gnss.sigm: unknown parameter (did you mean sigma_h or sigma_v?)"),
        (
            '[protocol]\ndetector = "joint"\ndetector_params = {c_gnss = 5.0}\n',
            ["--detector", "paper"],
            "--detector: paper.c_gnss: unknown parameter",
        ),
    ],
)
def test_mission_detector_is_checked_before_anything_is_written(cwd, extra, args, needle):
    fails_cleanly(["mission", "--scenario", scenario(cwd, extra), *args, "--out", "o"], needle, cwd)


@pytest.mark.parametrize(
    ("param", "needle"),
    [
        # checked for every swarm size before run.json is written (it was written, with
        # "complete": false, and the sweep failed at its first cell)
        ("f_max=99", "joint.f_max: 99 attackers cannot be tolerated among n = 7 drones"),
        # a negative sigma was floored to 1 mm: every verdict an alarm, all drones flagged
        ("gnss_sigma=[-1.5,-3]", "joint.gnss_sigma: expected (horizontal, vertical), both finite and >= 0"),
        ("gnss_common=[-2,-2]", "joint.gnss_common: expected (horizontal, vertical)"),
    ],
)
def test_detector_parameters_checked_before_the_sweep_starts(cwd, param, needle):
    args = ["sweep", "--preset", "realistic", "--detector", "joint", "--param", param]
    fails_cleanly([*args, "--n", "7", "--f", "1", "--trials", "5", "--out", "o"], needle, cwd)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        # a negative offset failed after the ROC's seconds of work, naming the attack's field
        (["curves", "--n", "9", "--f", "2", "--trials", "10", "--offsets", "2,-5"], "--offsets: offsets are"),
        # a detector without a threshold failed after an empty progress bar (a new-user review)
        (["curves", "--detectors", "shape", "--n", "7", "--f", "2"], "--detectors: no threshold parameter"),
        # the same detector twice ran the same trials twice and tabled them twice
        (["compare", "--detectors", "paper,joint,paper", "--n", "9", "--f", "2"], "--detectors: paper given"),
        (
            ["compare", "--attacks", "jump,jump", "--n", "9", "--f", "2"],
            "--attacks: jump given more than once",
        ),
        # options a figure would not use were ignored
        (["figure", "scaling", "res", "--view", "3d"], "--view: only for `swarmraft figure recovery`"),
        (["figure", "all", "res", "--out", "x.png"], "--out: names one file, and `all` writes three"),
    ],
)
def test_an_option_that_cannot_apply_is_refused_before_any_work(cwd, args, needle):
    (cwd / "res").mkdir()
    fails_cleanly([*args, "--out", "o"] if args[0] != "figure" else args, needle, cwd)


@pytest.mark.parametrize(
    "command",
    [
        ["sweep", "--n", "5"],
        ["compare", "--n", "5"],
        ["mission", "--scenario", "demo"],
        ["curves", "--n", "9"],
    ],
)
def test_a_negative_seed_is_the_options_error(cwd, command):
    # the mission's was "demo.toml: seed: ...", blaming the shipped file for the option's value
    fails_cleanly([*command, "--seed", "-1", "--out", "o"], "error: --seed: -1 is not in the range x>=0", cwd)


@pytest.mark.parametrize(
    ("command", "kind", "files"),
    [
        # compare.csv beside a sweep's files made it a comparison: its figures could not be drawn
        (["compare", "--n", "5", "--trials", "10"], "sweep", ("cells.csv", "run.json")),
        (["sweep", "--n", "5", "--trials", "10"], "compare", ("compare.csv",)),
        (["sweep", "--n", "5", "--trials", "10"], "mission", ("steps.csv", "summary.json", "scenario.json")),
    ],
)
def test_a_results_folder_of_another_kind_is_not_written_into(cwd, command, kind, files):
    (cwd / "res").mkdir()
    for name in files:
        (cwd / "res" / name).write_text("x\n")
    fails_cleanly([*command, "--out", "res"], f"--out res is a {kind} folder", cwd)


def test_compare_says_which_sweeps_compare_csv_no_longer_lists(cwd):
    args = ["compare", "--attacks", "jump", "--n", "5", "--f", "1", "--trials", "10", "--out", "c"]
    r = CliRunner().invoke(main, [*args, "--detectors", "paper,clique"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, [*args, "--detectors", "clique"])
    assert r.exit_code == 0, r.output
    assert "it listed jump/paper too, whose folders are kept" in " ".join(r.output.split())
    assert "c/jump/paper" not in r.output  # not written by this run: not said to be
    assert (cwd / "c" / "jump" / "paper" / "cells.csv").exists()
