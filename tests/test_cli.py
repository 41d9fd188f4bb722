"""The swarmraft command: outputs, figures, and one-line errors for bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from swarmraft.cli import main


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "ref"
    r = CliRunner().invoke(
        main,
        [
            "sweep",
            "--preset",
            "reference",
            "--n",
            "3-9:2",
            "--diagonal",
            "--trials",
            "400",
            "--workers",
            "1",
            "--out",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    return out, r.output


def test_sweep_writes_tables_and_says_where(results):
    out, text = results
    for name in ("cells.csv", "trials.csv", "run.json"):
        assert (out / name).exists()
        assert f"wrote {out / name}" in text
    assert "mean, sem, med, p99: the attacked drones after recovery" in text


@pytest.mark.parametrize("kind", ["scaling", "distribution", "recovery"])
def test_figures(results, kind):
    out, _ = results
    r = CliRunner().invoke(main, ["figure", kind, str(out)])
    assert r.exit_code == 0, r.output
    png = out / "figures" / f"{kind}.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str(png) in r.output


def test_recovery_3d(results, tmp_path):
    out, _ = results
    target = tmp_path / "r3d.png"
    r = CliRunner().invoke(main, ["figure", "recovery", str(out), "--view", "3d", "--out", str(target)])
    assert r.exit_code == 0, r.output
    assert target.stat().st_size > 10_000


def test_check_compares_with_published(results):
    import json

    from swarmraft.experiments.published import PUBLISHED
    from swarmraft.experiments.tables import read_table

    out, _ = results
    r = CliRunner().invoke(main, ["check", str(out)])
    assert "published" in r.output and "3 (1)" in r.output
    j = CliRunner().invoke(main, ["check", str(out), "--json"])
    report = json.loads(j.stdout)
    cells = read_table(out / "cells.csv")
    for row, n, mean, sem in zip(
        report["cells"], cells["n"], cells["recovered_mean"], cells["recovered_sem"], strict=True
    ):
        assert row["n"] == n
        assert row["z"] == pytest.approx((mean - PUBLISHED[int(n)][1]) / sem)
    crit = report["criteria"]
    for row in report["cells"]:
        gap = abs(row["baseline"] - row["published_baseline"])
        assert row["ok"] == (abs(row["z"]) <= crit["max_abs_z"] and gap <= crit["max_baseline_gap_m"])
    assert report["pass"] == all(row["ok"] for row in report["cells"])
    assert r.exit_code == (0 if report["pass"] else 1)  # the exit status follows the numbers


@pytest.mark.parametrize(
    "args,needle",
    [
        (["sweep", "--n", "abc"], "--n"),
        (["sweep", "--trials", "0", "--n", "5"], "trials"),
        (["sweep", "--param", "tau=-1", "--n", "5"], "paper.tau"),
        (["sweep", "--param", "nonsense", "--n", "5"], "KEY=VALUE"),
        (["sweep", "--param", "colour=1", "--n", "5"], "paper.colour: unknown parameter"),
        (  # sweep's default detector is paper: the line names the detectors that have it
            ["sweep", "--param", "p_fa=0.01", "--n", "5"],
            "paper.p_fa: unknown parameter (p_fa is a parameter of clique, fde, joint, shape: choose",
        ),
        (
            ["sweep", "--detector", "joint", "--param", "registration_rival=true", "--n", "5"],
            "joint.registration_rival: unknown parameter (did you mean registration_rivals?)",
        ),
        (["sweep", "--detector", "nope", "--n", "5"], "unknown name 'nope'"),
        (["sweep", "--workers", "0", "--n", "5", "--trials", "1"], "--workers"),
        (["sweep", "--config", "/nonexistent.toml"], "no file"),
        (["figure", "scaling", "/nonexistent-folder"], "no cells.csv"),
        (["sweep", "--attack", "teleport"], "teleport"),
    ],
)
def test_bad_input_is_one_line(args, needle, tmp_path):
    r = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "o")] if args[0] == "sweep" else args)
    assert r.exit_code == 2
    lines = [ln for ln in r.output.strip().splitlines() if ln.strip()]
    assert needle in r.output
    assert not any("Traceback" in ln for ln in lines)
    error_lines = [ln for ln in lines if "error" in ln.lower()]
    assert len(error_lines) == 1


def test_config_file(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text('preset = "realistic"\nn = [7]\ntrials = 50\n[gnss]\nsigma_h = -2\n')
    r = CliRunner().invoke(main, ["sweep", "--config", str(toml), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "gnss.sigma_h" in r.output


def test_console_script_runs():
    r = subprocess.run([sys.executable, "-m", "swarmraft.cli", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "sweep" in r.stdout and "figure" in r.stdout


def test_compare_and_curves(tmp_path):
    r = CliRunner().invoke(
        main,
        [
            "compare",
            "--detectors",
            "paper,clique",
            "--attacks",
            "jump,range-tamper",
            "--n",
            "9",
            "--f",
            "2",
            "--trials",
            "40",
            "--workers",
            "1",
            "--out",
            str(tmp_path / "cmp"),
        ],
    )
    assert r.exit_code == 0, r.output
    from swarmraft.experiments.tables import read_table

    t = read_table(tmp_path / "cmp" / "compare.csv")
    assert sorted(set(zip(t["attack"], t["detector"], strict=True))) == [
        ("jump", "clique"),
        ("jump", "paper"),
        ("range-tamper", "clique"),
        ("range-tamper", "paper"),
    ]
    assert (tmp_path / "cmp" / "figures" / "detection_rate.png").exists()
    # identical trials: the same reports reach both detectors, so the baselines agree
    base = {(a, d): b for a, d, b in zip(t["attack"], t["detector"], t["baseline_mean"], strict=True)}
    assert base[("jump", "clique")] == base[("jump", "paper")]
    r = CliRunner().invoke(
        main,
        [
            "curves",
            "--detectors",
            "clique,fde",
            "--n",
            "9",
            "--f",
            "2",
            "--trials",
            "20",
            "--offsets",
            "5,30",
            "--out",
            str(tmp_path / "cur"),
        ],
    )
    assert r.exit_code == 0, r.output
    c = read_table(tmp_path / "cur" / "curves.csv")
    off = [
        (d, o, p)
        for d, k, o, p in zip(c["detector"], c["kind"], c["offset"], c["detection"], strict=True)
        if k == "offset"
    ]
    assert len(off) == 4
    for det in ("clique", "fde"):  # a 30 m spoof is caught more often than a 5 m one
        pd = {o: p for d, o, p in off if d == det}
        assert pd[30.0] >= pd[5.0]
    assert (tmp_path / "cur" / "roc.png").exists()
    # the chosen thresholds and what they detect, printed: the numbers of curves.csv
    text = " ".join(r.output.split())
    for det in ("clique", "fde"):
        k = (c["detector"] == det) & (c["kind"] == "offset")
        thr, param = c["threshold"][k][0], c["parameter"][k][0]
        fa = np.mean(c["false_alarm"][k])
        assert (
            f"{det}: {param} = {thr:.4g} (false alarms <= 1.0% in the ROC's trials; {fa:.1%} in the offset"
            in text
        )
        pd = dict(zip(c["offset"][k], c["detection"][k], strict=True))
        half = "from 5 m" if pd[5.0] >= 0.5 else "from 30 m" if pd[30.0] >= 0.5 else "at no offset up to 30 m"
        assert f"half the attacked drones flagged {half}" in text.split(f"{det}: ")[1]
    bad = CliRunner().invoke(main, ["compare", "--attacks", "teleport", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "unknown attack 'teleport'" in bad.output


def test_cli_attack_names_match_the_config():
    from swarmraft.cli import ATTACK_NAMES
    from swarmraft.experiments.config import ATTACKS

    assert ATTACK_NAMES == list(ATTACKS)


def _render(table_and_legend) -> list[str]:
    from rich.console import Console

    from swarmraft.cli.app import print_table

    con = Console(width=80, record=True, file=open("/dev/null", "w"), color_system=None)  # noqa: SIM115
    print_table(table_and_legend, con)
    return con.export_text().splitlines()


def _headers(lines: list[str]) -> list[str]:
    rule = next(i for i, ln in enumerate(lines) if set(ln.strip()) == {"─"})
    return lines[rule - 1].split("  ")


def test_tables_fit_80_columns_with_names_whole_and_abbreviations_explained():
    import numpy as np

    from swarmraft.cli.tables import check_legend, check_table, compare_table, summary_table
    from swarmraft.experiments.published import compare_published
    from swarmraft.experiments.sweep import load_results

    attacks = ["range-tamper", "collusion-1", "collusion-2", "collusion-3"]
    rows = [(a, d) for a in attacks for d in ("paper", "clique", "fde", "joint")]
    k = len(rows)
    number = np.full(k, 12.3456)
    table = {
        "attack": np.array([a for a, _ in rows], dtype=object),
        "detector": np.array([d for _, d in rows], dtype=object),
        "n": np.full(k, 17),
        "f": np.full(k, 8),
        **{c: number for c in ("recovered_mean", "honest_mean", "honest_baseline_mean")},
        "attacked_efficiency": np.full(k, np.nan),
        **{c: np.full(k, 0.999) for c in ("detection_rate", "false_positive_rate")},
        **{c: np.full(k, 0.5) for c in ("identification_rate", "status_unidentifiable")},
    }
    lines = _render(compare_table(table, "detectors on identical trials"))
    assert max(map(len, lines)) <= 80 and not any("…" in ln for ln in lines)
    body = "\n".join(lines)
    for a, d in rows:
        assert any(ln.split()[:2] == [a, d] for ln in lines), (a, d)
    legend = body.split("Errors in m.")[1]
    for abbreviation in ("att", "hon", "GNSS", "eff", "det", "FP", "id", "unid"):
        assert f"{abbreviation}:" in legend
    cells = {
        "n": np.array([17, 15]),
        "f": np.array([8, 7]),
        "trials": np.array([10000, 10000]),
        **{
            c: np.array([28.8123, 1.23e-08])
            for c in ("baseline_mean", "recovered_mean", "recovered_sem", "recovered_median")
        },
        **{c: np.array([104.5, 0.5]) for c in ("recovered_p99", "honest_mean")},
        **{c: np.array([1.0, 0.1234]) for c in ("frac_over_1m", "detection_rate", "false_positive_rate")},
    }
    lines = _render(summary_table(cells, "reference: mean error of attacked drones"))
    assert max(map(len, lines)) <= 80 and not any("…" in ln for ln in lines)
    text = "\n".join(lines)
    for abbreviation in ("base", "sem", "med", "p99", ">1m", "hon", "det", "FP"):
        assert abbreviation in _headers(lines)[0] or abbreviation in lines[1]
        assert f"{abbreviation}:" in text or f"{abbreviation}," in text
    assert not lines[1].rstrip().endswith("und")  # no cell leaves a drone undetermined: no column
    lines = _render(summary_table({**cells, "undetermined_rate": np.array([0.0, 0.028])}, "realistic"))
    assert max(map(len, lines)) <= 80 and lines[1].rstrip().endswith("und")
    assert "2.8%" in "".join(lines[2:5]) and "und: share of the drones left without" in " ".join(
        " ".join(lines).split()
    )
    rows = compare_published({**cells, "n": np.array([17, 3]), "f": np.array([8, 1])})
    lines = _render(check_table(rows, "results/reference against the published means", check_legend(3, 0.3)))
    assert max(map(len, lines)) <= 80 and "z = (recovered - published) / sem" in " ".join(
        " ".join(lines).split()
    )
    assert load_results  # the folder reader the tables are fed from


def test_check_json_for_scripts(results):
    out, _ = results
    r = CliRunner().invoke(main, ["check", str(out), "--json"])
    report = json.loads(r.stdout)
    assert [c["n"] for c in report["cells"]] == [3, 5, 7, 9]
    assert report["criteria"] == {"max_abs_z": 3.0, "max_baseline_gap_m": 0.3}
    assert report["pass"] == all(c["ok"] for c in report["cells"])
    assert r.exit_code == (0 if report["pass"] else 1)


def test_compare_json_for_scripts(tmp_path):
    out = tmp_path / "cmp"
    args = [
        "compare",
        "--preset",
        "reference",
        "--detectors",
        "paper",
        "--n",
        "7",
        "--f",
        "2",
        "--trials",
        "20",
    ]
    r = CliRunner().invoke(main, [*args, "--json", "--out", str(out)])
    assert r.exit_code == 0, r.output
    rows = json.loads(r.stdout)
    assert [(row["attack"], row["detector"], row["n"], row["f"]) for row in rows] == [("jump", "paper", 7, 2)]
    assert rows[0]["attacked_efficiency"] is None  # nan (exact data: no bound) is null, valid JSON
    assert f"wrote {out / 'compare.csv'}" in r.stderr


def test_printed_paths_are_never_wrapped(tmp_path):
    out = tmp_path / ("a-folder-name-long-enough-to-pass-the-console-width-" * 3) / "ref"
    args = ["sweep", "--n", "5", "--f", "1", "--trials", "10", "--workers", "1", "--out", str(out)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert f"  wrote {out / 'cells.csv'}\n" in r.output
    assert f"-> {out}\n" in r.output


def test_headings_never_cut_a_path():
    from rich.console import Console

    from swarmraft.cli.app import heading

    con = Console(width=80, record=True, file=open("/dev/null", "w"), color_system=None)  # noqa: SIM115
    heading("[bold]mission[/] demo-mission: 9 drones, 60 s -> results/demo/mission", con)
    title = (
        "[bold]detectors compared[/]: realistic, n = 17, f = 8, 250 identical trials -> results/demo/compare"
    )
    heading(title, con)
    lines = con.export_text().splitlines()
    assert "demo-mission: 9 drones, 60 s -> results/demo/mission" in lines[0] and lines[0].startswith("─")
    assert set(lines[1]) == {"─"}
    assert (
        lines[2]
        == "detectors compared: realistic, n = 17, f = 8, 250 identical trials -> results/demo/compare"
    )


def test_headings_fit_the_text_width_on_a_wide_console():
    from rich.console import Console

    from swarmraft.cli.app import TEXT_WIDTH, heading

    con = Console(width=130, record=True, file=open("/dev/null", "w"), color_system=None)  # noqa: SIM115
    heading("[bold]written[/]", con)
    (line,) = con.export_text().splitlines()
    assert len(line) == TEXT_WIDTH and "written" in line


def test_mission_help_names_every_shipped_scenario():
    """`mission --scenario` takes a shipped scenario's name: its help lists every one (it
    once missed coordinated-drag and sparse-65, added after the list was written)."""
    from swarmraft.sim.scenario import shipped_scenarios

    r = CliRunner().invoke(main, ["mission", "--help"], terminal_width=1000)
    assert r.exit_code == 0
    help_text = " ".join(r.output.split())
    missing = [name for name in shipped_scenarios() if name not in help_text]
    assert not missing and len(shipped_scenarios()) >= 11, missing


def test_integrity_figure_counts_the_verdicts_it_cannot_draw(results, tmp_path):
    """The Stanford diagram draws the ok verdicts; the others are counted in its title, by
    status, as trials.csv has them. A folder of `paper` verdicts (no protection levels) is a
    one-line error."""
    from swarmraft.experiments.sweep import load_results
    from swarmraft.viz.integrity import verdict_counts

    out, _ = results
    r = CliRunner().invoke(main, ["figure", "integrity", str(out)])
    assert r.exit_code == 2 and "no protection levels" in r.output and "Traceback" not in r.output

    out = tmp_path / "joint"
    args = ["sweep", "--preset", "realistic", "--detector", "joint", "--n", "7", "--f", "3"]
    r = CliRunner().invoke(main, [*args, "--trials", "60", "--workers", "1", "--out", str(out)])
    assert r.exit_code == 0, r.output
    _, trials, _ = load_results(out)
    status = list(trials["status"])
    line = verdict_counts(trials["status"])
    assert line.startswith(f"{status.count('ok')} ok of 60 verdicts; not ok (not to be used): ")
    for s in ("alarm", "unidentifiable", "degenerate"):  # (7, 3): most are degenerate
        assert (f"{s} {status.count(s)}" in line) == (status.count(s) > 0)
    assert status.count("degenerate") > 0
    r = CliRunner().invoke(main, ["figure", "integrity", str(out)])
    assert r.exit_code == 0, r.output
    png = out / "figures" / "integrity.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and str(png) in r.output


def test_calibrate_on_a_preset_that_does_not_calibrate_says_so_before_its_table():
    """The reference preset's honest residuals are exactly 0 (a table of zeros), and its sweeps
    use the detector's own thresholds: said first, so the zeros are not read as the thresholds."""
    r = CliRunner().invoke(main, ["calibrate", "--preset", "reference", "--n", "5", "--trials", "10"])
    assert r.exit_code == 0, r.output
    first = " ".join(r.output.split("calibration, preset reference")[0].split())
    assert (
        "preset reference does not calibrate (calibrate = false): its sweeps use the paper "
        "detector's tau 0.01 m" in first
    )


def test_a_numerical_failure_is_an_internal_error_not_bad_input():
    """A LinAlgError from inside a command (a ValueError to Python) is reported as an internal
    error with exit status 1, not as bad input (status 2), so a user reports it instead of
    changing their input; a ValueError of the input keeps status 2."""
    from swarmraft.cli import app

    @app.main.command("boom-linalg")
    def boom_linalg() -> None:
        raise np.linalg.LinAlgError("Eigenvalues did not converge")

    @app.main.command("boom-input")
    def boom_input() -> None:
        raise ValueError("n: must be at least 3")

    try:
        r = CliRunner().invoke(app.main, ["boom-linalg"])
        assert r.exit_code == 1
        assert "internal error" in r.output and "Eigenvalues did not converge" in r.output
        r = CliRunner().invoke(app.main, ["boom-input"])
        assert r.exit_code == 2 and "error: n: must be at least 3" in r.output
        assert "internal" not in r.output
    finally:
        app.main.commands.pop("boom-linalg", None)
        app.main.commands.pop("boom-input", None)


def test_a_size_that_makes_no_cell_is_named_not_dropped_in_silence(tmp_path):
    """`sweep --n 5,9 --f 3` ran (9, 3) only and said nothing of n = 5 (3 attackers need 7
    drones; a new-user review)."""
    args = ["sweep", "--n", "5,9", "--f", "3", "--trials", "2", "--workers", "1"]
    args += ["--out", str(tmp_path / "s")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "note: no cell at n = 5 with the attacker counts given: left out" in r.output
    r = CliRunner().invoke(main, [*args[:2], "9", *args[3:-1], str(tmp_path / "t")])
    assert "note:" not in r.output
