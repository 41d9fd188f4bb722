"""A --config file sets what the command line leaves alone, and a flag typed on the command
line wins over the file: the options' defaults must not pass for typed flags (a review found
compare running its own default cells, trials and attack over a file's, and sweep keeping
the file's preset over a typed --preset)."""

import json

from click.testing import CliRunner

from swarmraft.cli import main

CONFIG = 'preset = "realistic"\nn = [9]\nf = [2]\ntrials = 20\nseed = 7\n[attack]\nname = "collusion-1"\n'


def test_compare_takes_the_files_cells_trials_and_attack(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.toml").write_text(CONFIG)
    r = CliRunner().invoke(
        main, ["compare", "--config", "c.toml", "--detectors", "paper", "--workers", "1", "--out", "o"]
    )
    assert r.exit_code == 0, r.output
    assert "compare: paper on collusion-1, preset realistic, 1 cells x 20 trials" in " ".join(
        r.output.split()
    )
    config = json.loads((tmp_path / "o" / "collusion-1" / "paper" / "run.json").read_text())["config"]
    assert (config["n"], config["f"], config["trials"], config["seed"]) == ([9], [2], 20, 7)


def test_a_typed_flag_wins_over_the_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.toml").write_text(CONFIG)
    args = ["--config", "c.toml", "--preset", "reference", "--trials", "30", "--workers", "1"]
    r = CliRunner().invoke(main, ["sweep", *args, "--out", "s"])
    assert r.exit_code == 0, r.output
    config = json.loads((tmp_path / "s" / "run.json").read_text())["config"]
    assert (config["preset"], config["trials"], config["n"]) == ("reference", 30, [9])
    r = CliRunner().invoke(
        main, ["compare", *args, "--attacks", "jump", "--detectors", "paper", "--out", "c"]
    )
    assert r.exit_code == 0, r.output
    config = json.loads((tmp_path / "c" / "jump" / "paper" / "run.json").read_text())["config"]
    assert (config["preset"], config["trials"]) == ("reference", 30)
    assert "paper on jump" in r.output


def test_a_value_that_does_not_exist_is_a_dash_in_the_tables():
    """docs/cli-output.md: '-' marks a value that does not exist; the sweep and compare tables
    printed nan for attacked drones no trial placed (found by a new-user review)."""
    import numpy as np
    from rich.console import Console

    from swarmraft.cli.tables import compare_table

    nan = float("nan")
    row = {"attack": ["jump"], "detector": ["clique"], "n": [5], "f": [2], "recovered_mean": [nan]}
    row |= {k: [nan] for k in ("honest_mean", "honest_baseline_mean", "attacked_efficiency")}
    row |= {k: [0.5] for k in ("detection_rate", "false_positive_rate", "identification_rate")}
    row |= {"status_unidentifiable": [0.0]}
    table, _ = compare_table({k: np.asarray(v) for k, v in row.items()}, "t")
    console = Console(record=True, width=120)
    console.print(table)
    text = console.export_text()
    assert "nan" not in text and text.splitlines()[-1].split()[4:8] == ["-", "-", "-", "-"]


def test_a_comparison_run_again_leaves_no_figure_it_did_not_draw(tmp_path, monkeypatch):
    """A comparison with no efficiency (every value nan) drew no efficiency figure, and the
    one of the comparison before in the same folder stayed, embedded by `report` (found by a
    new-user review)."""
    monkeypatch.chdir(tmp_path)
    run = ["compare", "--n", "9", "--f", "2", "--trials", "10", "--workers", "1", "--out", "c"]
    assert CliRunner().invoke(main, [*run, "--detectors", "joint"]).exit_code == 0
    figure = tmp_path / "c" / "figures" / "attacked_efficiency.png"
    assert figure.exists()
    (tmp_path / "c" / "report.html").write_text("old")
    # exact data (reference preset): no Cramer-Rao bound, no efficiency figure to draw
    r = CliRunner().invoke(main, [*run, "--detectors", "clique", "--preset", "reference"])
    assert r.exit_code == 0, r.output
    assert not figure.exists()
    assert not (tmp_path / "c" / "report.html").exists()


def test_the_calibration_line_is_wrapped_in_a_pipe(tmp_path, monkeypatch):
    """docs/cli-output.md: prose wraps at 100 columns with a 4-space indent in a pipe; the
    calibrated thresholds' line ran on to about 130 (found by a new-user review)."""
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(
        main,
        [
            "sweep",
            "--preset",
            "realistic",
            "--n",
            "3-17:2",
            "--f",
            "1",
            "--trials",
            "10",
            "--workers",
            "1",
            "--out",
            "s",
        ],
    )
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("thresholds calibrated"))
    assert len(lines[k]) <= 100 and lines[k + 1].startswith("    ")


def test_compare_keeps_its_defaults_for_what_the_file_does_not_set(tmp_path, monkeypatch):
    """A file that sets neither cells nor an attack: compare's own defaults (9, 13, 17; jump),
    not the preset's whole grid (a review found 36 cells x 10,000 trials instead of 18 x 1,000)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.toml").write_text("[attack]\nmin_move = 30.0\n")
    args = ["compare", "--config", "c.toml", "--detectors", "paper", "--trials", "5", "--f", "1"]
    r = CliRunner().invoke(main, [*args, "--workers", "1", "--out", "o"])
    assert r.exit_code == 0, r.output
    assert "compare: paper on jump, preset realistic, 3 cells x 5 trials" in " ".join(r.output.split())


def test_sweep_config_from_python_is_not_a_click_command():
    """options.typed asked click for the running command's context: sweep_config called from
    Python (tests, notebooks) with a file that sets a preset raised RuntimeError."""
    from pathlib import Path

    from swarmraft.cli.options import sweep_config

    example = Path(__file__).parent.parent / "docs" / "examples" / "collusion-30m.toml"
    config = sweep_config("reference", example, "12", "4", False, None, None, {})
    assert config.preset == "realistic"


def test_the_compare_table_shows_undetermined_drones_as_the_sweep_table_does():
    """A detector that places no attacked drone (every verdict degenerate) showed att '-' and
    det 100 % with nothing saying why: the sweep's table has an und column, compare's had
    none (found by a new-user review)."""
    import numpy as np
    from rich.console import Console

    from swarmraft.cli.tables import compare_table

    row = {"attack": ["jump"], "detector": ["joint"], "n": [5], "f": [2], "recovered_mean": [float("nan")]}
    row |= {k: [1.0] for k in ("honest_mean", "honest_baseline_mean", "attacked_efficiency")}
    row |= {k: [1.0] for k in ("detection_rate", "identification_rate")}
    row |= {"false_positive_rate": [0.0], "status_unidentifiable": [0.0], "undetermined_rate": [0.4]}
    table, legend = compare_table({k: np.asarray(v) for k, v in row.items()}, "t")
    console = Console(record=True, width=120)
    console.print(table)
    lines = [ln for ln in console.export_text().splitlines() if ln.strip() and not ln.startswith("─")]
    assert lines[-2].split()[-1] == "und" and lines[-1].split()[-1] == "40.0%"
    assert "und: share of the drones left without a position" in legend
