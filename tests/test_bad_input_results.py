"""Results folders are validated when read: a truncated or corrupt file is named in one line
(exit status 2, nothing written); run.json keeps every run's provenance, and a resume with
another seed or config is refused even when run.json is gone (the cells carry theirs)."""

import json
import shutil

import pytest
from click.testing import CliRunner

from swarmraft.cli import main
from test_bad_input import fails_cleanly

SWEEP = ["sweep", "--n", "3,5", "--diagonal", "--trials", "50", "--workers", "1"]


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    """An empty working folder for the test."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("base") / "ref"
    r = CliRunner().invoke(main, [*SWEEP, "--out", str(out)])
    assert r.exit_code == 0, r.output
    return out


@pytest.fixture
def ref(finished, tmp_path, monkeypatch):
    """A copy of a finished reference sweep in ./ref, the test's working folder."""
    monkeypatch.chdir(tmp_path)
    shutil.copytree(finished, tmp_path / "ref")
    return tmp_path / "ref"


def resume(*extra: str) -> list[str]:
    return [*SWEEP, *extra, "--out", "ref"]


def test_cell_cut_mid_line_then_resume(ref):
    cell = ref / "cells" / "n5_f2.csv"
    cell.write_bytes(cell.read_bytes()[:-40])
    line = fails_cleanly(resume(), "ref/cells/n5_f2.csv, line 51:", ref.parent)
    assert "a truncated or corrupt file" in line


def test_cell_missing_rows_then_resume(ref):
    cell = ref / "cells" / "n5_f2.csv"
    cell.write_text("".join(cell.read_text().splitlines(keepends=True)[:31]))
    line = fails_cleanly(resume(), "ref/cells/n5_f2.csv: 30 trials where the config has 50", ref.parent)
    assert "remove it to recompute" in line


@pytest.mark.parametrize("command", [["check"], ["figure", "scaling"], ["figure", "all"]])
def test_cells_csv_cut_mid_line(ref, command):
    table = ref / "cells.csv"
    table.write_bytes(table.read_bytes()[:-25])
    fails_cleanly([*command, "ref"], "ref/cells.csv, line 3: ", ref.parent)


def test_cells_csv_cut_inside_its_header(ref):
    """Cut inside the header (a new-user review: `head -c 300`), the table was called one from
    another version of swarmraft, to be run again; it is a truncated file."""
    table = ref / "cells.csv"
    table.write_bytes(table.read_bytes()[:300])
    assert b"\n" not in table.read_bytes()
    line = fails_cleanly(["check", "ref"], "ref/cells.csv: the file ends inside its header", ref.parent)
    assert "truncated or corrupt" in line and "another version" not in line


@pytest.mark.parametrize("command", [["check"], ["figure", "scaling"]])
def test_cells_csv_with_a_word_for_a_number(ref, command):
    table = ref / "cells.csv"
    header, first, *rest = table.read_text().splitlines(keepends=True)
    values = first.split(",")
    values[header.split(",").index("recovered_mean")] = "abc"
    table.write_text("".join([header, ",".join(values), *rest]))
    fails_cleanly(
        [*command, "ref"], "ref/cells.csv, line 2, column recovered_mean: 'abc' is not a number", ref.parent
    )


def test_garbage_cells_csv(ref):
    (ref / "cells.csv").write_text("hello\nworld\n")
    line = fails_cleanly(
        ["check", "ref"], "ref/cells.csv: not a table this version of swarmraft wrote", ref.parent
    )
    from swarmraft.experiments.metrics import CELL_COLUMNS

    assert f"(no column n, f, trials and {len(CELL_COLUMNS) - 3} more; a folder from another version" in line


@pytest.mark.parametrize("command", [["check", "ref"], ["figure", "recovery", "ref"], resume()])
def test_corrupt_run_json_is_named(ref, command):
    (ref / "run.json").write_text('{"config": {"preset": ')
    fails_cleanly(command, "ref/run.json: not valid JSON (", ref.parent)


def test_missing_run_json_is_named(ref):
    (ref / "run.json").unlink()
    fails_cleanly(["check", "ref"], "ref/run.json: missing", ref.parent)


def test_missing_trials_csv_is_named_by_the_distribution_figure(ref):
    (ref / "trials.csv").unlink()
    fails_cleanly(["figure", "distribution", "ref"], "ref/trials.csv: missing", ref.parent)


def test_resume_with_another_seed_without_run_json_is_refused(ref):
    (ref / "run.json").unlink()
    line = fails_cleanly(resume("--seed", "5"), "--out ref: n3_f1.csv was made with seed 2025", ref.parent)
    assert "this run has seed 5" in line


def test_resume_with_another_seed_is_refused(ref):
    fails_cleanly(
        resume("--seed", "5"), "--out ref holds a sweep with a different config (seed differ)", ref.parent
    )


def test_cell_without_provenance_or_run_json_is_refused(ref):
    (ref / "run.json").unlink()
    (ref / "cells" / "n3_f1.json").unlink()
    fails_cleanly(
        resume(), "ref/cells/n3_f1.csv: neither n3_f1.json nor run.json says what made it", ref.parent
    )


def test_resume_without_run_json_reuses_cells_of_the_same_seed(ref):
    cells = (ref / "cells.csv").read_bytes()
    (ref / "run.json").unlink()
    r = CliRunner().invoke(main, resume())
    assert r.exit_code == 0, r.output
    assert "reused 2 finished cells" in r.output
    assert "0/0" not in r.output  # nothing left to run: no empty progress bar
    assert "nothing to run: every cell was already finished" in r.output
    assert (ref / "cells.csv").read_bytes() == cells


def test_run_json_keeps_every_run(ref):
    first = json.loads((ref / "run.json").read_text())
    assert len(first["runs"]) == 1
    run = first["runs"][0]
    assert run["seed"] == 2025 and run["executor"] == "inline" and run["cells"] == [[3, 1], [5, 2]]
    assert run["config_sha256"] == first["config_sha256"] and run["started"].endswith("+00:00")
    (ref / "cells" / "n5_f2.csv").unlink()
    r = CliRunner().invoke(main, resume())
    assert r.exit_code == 0, r.output
    second = json.loads((ref / "run.json").read_text())
    assert second["runs"][0] == run
    assert second["runs"][1]["cells"] == [[5, 2]]
    # a resume that computes nothing adds no entry
    assert CliRunner().invoke(main, resume()).exit_code == 0
    assert json.loads((ref / "run.json").read_text())["runs"] == second["runs"]


def test_cell_provenance_names_its_seed_and_config(ref):
    meta = json.loads((ref / "cells" / "n5_f2.json").read_text())
    run = json.loads((ref / "run.json").read_text())
    from swarmraft.experiments.sweep import code_hash

    assert meta == {
        "config_sha256": run["config_sha256"],
        "code_sha256": code_hash(),
        "f": 2,
        "n": 5,
        "seed": 2025,
        "trials": 50,
    }


def test_run_json_with_a_bad_config_is_named(ref):
    run = json.loads((ref / "run.json").read_text())
    run["config"]["trials"] = -4
    (ref / "run.json").write_text(json.dumps(run))
    fails_cleanly(
        ["figure", "recovery", "ref"], "ref/run.json: config.trials: Input should be greater than", ref.parent
    )


def test_resume_with_other_code_is_refused(ref, monkeypatch):
    """Cells made by another version of the code are not mixed with this version's."""
    import json

    from swarmraft.experiments import sweep as sweep_module

    meta = sorted((ref / "cells").glob("*.json"))[0]
    data = json.loads(meta.read_text())
    assert data["code_sha256"] == sweep_module.code_hash()
    data["code_sha256"] = "0" * 64
    meta.write_text(json.dumps(data))
    fails_cleanly(resume(), "was made by other code (source 000000000000", ref.parent)


def _set(table, row: int, column: str, value: str) -> None:
    """Write ``value`` into ``column`` of data row ``row`` (0 = the line under the header)."""
    header, *rows = table.read_text().splitlines(keepends=True)
    values = rows[row].rstrip("\n").split(",")
    values[header.rstrip("\n").split(",").index(column)] = value
    rows[row] = ",".join(values) + "\n"
    table.write_text("".join([header, *rows]))


@pytest.mark.parametrize("command", [["check"], ["figure", "scaling"]])
def test_cells_csv_missing_a_cell_of_the_config(ref, command):
    table = ref / "cells.csv"
    table.write_text("".join(table.read_text().splitlines(keepends=True)[:2]))
    fails_cleanly(
        [*command, "ref"],
        "ref/cells.csv: cells (3, 1) where run.json's config lists (3, 1), (5, 2)",
        ref.parent,
    )


def test_cells_csv_with_a_cell_the_config_does_not_list(ref):
    _set(ref / "cells.csv", 1, "n", "7")
    fails_cleanly(
        ["figure", "scaling", "ref"],
        "ref/cells.csv: cells (3, 1), (7, 2) where run.json's config lists (3, 1), (5, 2)",
        ref.parent,
    )


def test_trials_csv_cut_at_a_row_boundary_or_emptied(ref):
    """Cut between two rows, the file still parses: its cells' trial counts give it away."""
    table = ref / "trials.csv"
    lines = table.read_text().splitlines(keepends=True)
    table.write_text("".join(lines[: len(lines) - 3]))
    fails_cleanly(["figure", "distribution", "ref"], "ref/trials.csv: cell (5, 2) has ", ref.parent)
    table.write_text(lines[0])
    fails_cleanly(["figure", "distribution", "ref"], "ref/trials.csv: cells (none: no row) where", ref.parent)


def test_trials_csv_with_a_cell_the_config_does_not_list(ref):
    table = ref / "trials.csv"
    header, *rows = table.read_text().splitlines(keepends=True)
    n_col = header.split(",").index("n")
    rows = [",".join("9" if i == n_col else v for i, v in enumerate(r.split(","))) for r in rows]
    table.write_text("".join([header, *rows]))
    fails_cleanly(
        ["figure", "distribution", "ref"],
        "ref/trials.csv: cells (9, 1), (9, 2) where run.json's config lists (3, 1), (5, 2)",
        ref.parent,
    )


@pytest.mark.parametrize("command", [["check"], ["figure", "scaling"]])
def test_negative_standard_error_is_named(ref, command):
    _set(ref / "cells.csv", 1, "recovered_sem", "-0.25")
    line = fails_cleanly(
        [*command, "ref"], "ref/cells.csv, line 3, column recovered_sem: -0.25 is negative", ref.parent
    )
    assert "standard error" in line


def test_negative_trial_count_is_named(ref):
    _set(ref / "cells.csv", 0, "trials", "-50")
    fails_cleanly(["check", "ref"], "ref/cells.csv, line 2, column trials: -50 is negative", ref.parent)


def test_trial_count_other_than_the_configs_is_named(ref):
    _set(ref / "cells.csv", 0, "trials", "40")
    fails_cleanly(
        ["check", "ref"],
        "ref/cells.csv, line 2, column trials: 40 where run.json's config has 50",
        ref.parent,
    )


@pytest.mark.parametrize(
    "column,value,needle",
    [
        ("baseline_mean", "nan", "column baseline_mean: nan where a finite number is required"),
        ("identification_rate", "inf", "column identification_rate: inf where a finite number is required"),
        ("recovered_mean", "-inf", "column recovered_mean: -inf where a finite number or nan is expected"),
        ("status_ok", "1.5", "column status_ok: 1.5 is a share above 1"),
    ],
)
def test_impossible_numbers_in_cells_csv_are_named(ref, column, value, needle):
    _set(ref / "cells.csv", 0, column, value)
    fails_cleanly(["figure", "scaling", "ref"], f"ref/cells.csv, line 2, {needle}", ref.parent)


def test_unknown_preset_in_cells_csv_is_named(ref):
    _set(ref / "cells.csv", 1, "preset", "bogus")
    line = fails_cleanly(
        ["figure", "scaling", "ref"],
        "ref/cells.csv, line 3, column preset: unknown preset 'bogus'",
        ref.parent,
    )
    assert "known: reference, realistic" in line


def test_cells_csv_of_another_detector_than_run_json_is_named(ref):
    _set(ref / "cells.csv", 0, "detector", "joint")
    fails_cleanly(
        ["check", "ref"],
        "ref/cells.csv, line 2, column detector: 'joint' where run.json's config has 'paper'",
        ref.parent,
    )


def test_check_on_a_mission_or_comparison_folder_says_what_it_is(tmp_path, monkeypatch):
    """It told the user to run a sweep into their mission folder."""
    from swarmraft.experiments.mission_folder import FILES

    monkeypatch.chdir(tmp_path)
    (tmp_path / "m").mkdir()
    for name in FILES:
        (tmp_path / "m" / name).write_text("{}")
    fails_cleanly(["check", "m"], "error: m: a mission folder, not a sweep's (no cells.csv)", tmp_path)
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "compare.csv").write_text("x\n")
    fails_cleanly(
        ["check", "c"], "c: a compare folder, not a sweep's (no cells.csv) (its sweeps are in", tmp_path
    )


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--attack", "range-bias"], "attack.name is 'range-bias' (the paper's: 'jump')"),
        (["--detector", "clique"], "detector is 'clique' (the paper's: 'paper')"),
        (["--param", "tau=0.3"], "detector_params is {'tau': 0.3} (the paper's: {})"),
    ],
)
def test_check_refuses_a_reference_sweep_that_is_not_the_papers_experiment(cwd, extra, said):
    """`check` graded any sweep of the reference preset against the paper's numbers, whatever
    its attack, detector or parameters: a range-bias sweep 'passed' (a review found it)."""
    r = CliRunner().invoke(main, [*SWEEP, *extra, "--out", "other"])
    assert r.exit_code == 0, r.output
    line = fails_cleanly(["check", "other"], "other: not the paper's experiment: ", cwd)
    assert said in line


def test_a_mission_refuses_another_kind_of_results_folder(ref):
    """A mission's files beside a sweep's made the folder neither: the sweep could not be
    resumed or drawn, and `report` showed the mission alone (found by a new-user review)."""
    (ref.parent / "tiny.toml").write_text('name = "tiny"\ndrones = 5\nduration_s = 1\n')
    line = fails_cleanly(
        ["mission", "--scenario", "tiny.toml", "--out", "ref"], "--out ref is a sweep folder", ref.parent
    )
    assert "a mission writes a folder of its own" in line


def test_a_mission_run_again_leaves_no_figure_or_report_of_the_run_before(cwd):
    """Figures and the report drawn from a mission folder described that run; a new run into
    the folder (another seed, the default results/NAME) left them, and `report` embedded the
    old animation under the new mission's title."""
    (cwd / "tiny.toml").write_text('name = "tiny"\ndrones = 5\nduration_s = 1\n')
    run = ["mission", "--scenario", "tiny.toml", "--out", "m"]
    assert CliRunner().invoke(main, run).exit_code == 0
    (cwd / "m" / "figures" / "animation.gif").write_bytes(b"GIF89a old run")
    (cwd / "m" / "report.html").write_text("<html>old run</html>")
    (cwd / "notes.txt").write_text("mine")
    r = CliRunner().invoke(main, [*run, "--seed", "2"])
    assert r.exit_code == 0, r.output
    assert not (cwd / "m" / "figures" / "animation.gif").exists()
    assert not (cwd / "m" / "report.html").exists()
    assert len(list((cwd / "m" / "figures").glob("*.png"))) == 4
    assert (cwd / "notes.txt").read_text() == "mine"


def test_curves_refuses_another_kind_of_results_folder_and_repeated_offsets(ref):
    """curves wrote curves.csv and its figures into a sweep's or a mission's folder without a
    word, and ran a repeated offset twice (found by a new-user review)."""
    curves = ["curves", "--n", "5", "--f", "1", "--trials", "10"]
    line = fails_cleanly([*curves, "--out", "ref"], "--out ref is a sweep folder", ref.parent)
    assert "curves writes a folder of its own" in line
    fails_cleanly([*curves, "--offsets", "10,10", "--out", "new"], "--offsets: 10 m twice", ref.parent)


def test_launch_refuses_another_kind_of_results_folder(ref):
    """launch wrote a mission's files (and records.csv) into a sweep's folder: neither could be
    read again (found by a review). Refused before any process starts."""
    (ref.parent / "tiny.toml").write_text('name = "tiny"\ndrones = 4\nduration_s = 1\n')
    line = fails_cleanly(
        ["launch", "--scenario", "tiny.toml", "--out", "ref"], "--out ref is a sweep folder", ref.parent
    )
    assert "a networked run writes a folder of its own" in line


@pytest.fixture(scope="module")
def a_mission(tmp_path_factory):
    out = tmp_path_factory.mktemp("m") / "m"
    (out.parent / "tiny.toml").write_text('name = "tiny"\ndrones = 5\nduration_s = 2\n')
    r = CliRunner().invoke(main, ["mission", "--scenario", str(out.parent / "tiny.toml"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    return out


@pytest.mark.parametrize(
    ("damage", "said"),
    [
        # a summary without its fields: the report passed its checks on defaults (0, "ok")
        (lambda m: (m / "summary.json").write_text("{}"), "m/summary.json lacks committed_steps"),
        (lambda m: (m / "summary.json").write_text("[]"), "m/summary.json: not a JSON object"),
        (
            lambda m: (m / "summary.json").write_text(
                (m / "summary.json").read_text().replace('"integrity": {', '"integrity": null, "x": {')
            ),
            "m/summary.json lacks integrity.misleading_drone_steps",
        ),
        # a row cut short where the rows still come in whole steps: a traceback before
        (
            lambda m: (m / "steps.csv").write_text(
                "\n".join((m / "steps.csv").read_text().splitlines()[:11])[:-60] + "\n"
            ),
            "m/steps.csv, row 10: cut short or not a number",
        ),
    ],
)
def test_a_damaged_mission_folder_is_one_line_for_report(a_mission, tmp_path, monkeypatch, damage, said):
    """Found by a new-user review of report, record and figure."""
    monkeypatch.chdir(tmp_path)
    shutil.copytree(a_mission, tmp_path / "m")
    damage(tmp_path / "m")
    fails_cleanly(["report", "m"], said, tmp_path)


def test_view_refuses_a_file_that_is_not_a_recording(cwd):
    """`view junk.rrd` served an empty viewer and waited, without a word (found by a new-user
    review): a rerun recording starts with its magic bytes."""
    (cwd / "junk.rrd").write_text("junk")
    line = fails_cleanly(["view", "junk.rrd"], "junk.rrd is not a rerun recording", cwd)
    assert "RRF" in line


def test_a_mission_folder_with_a_file_gone_says_which(a_mission, tmp_path, monkeypatch):
    """report said only 'is not a results folder' of a mission folder whose scenario.json was
    gone (found by a new-user review)."""
    monkeypatch.chdir(tmp_path)
    shutil.copytree(a_mission, tmp_path / "m")
    (tmp_path / "m" / "scenario.json").unlink()
    line = fails_cleanly(["report", "m"], "is not a results folder", tmp_path)
    assert "but no scenario.json" in line
