"""The swarmraft command: outputs, figures, and one-line errors for bad input."""

import subprocess
import sys

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
    out, _ = results
    r = CliRunner().invoke(main, ["check", str(out)])
    assert "published" in r.output and "3 (1)" in r.output
    assert r.exit_code in (0, 1)


@pytest.mark.parametrize(
    "args,needle",
    [
        (["sweep", "--n", "abc"], "--n"),
        (["sweep", "--trials", "0", "--n", "5"], "trials"),
        (["sweep", "--param", "tau=-1", "--n", "5"], "paper.tau"),
        (["sweep", "--param", "nonsense", "--n", "5"], "KEY=VALUE"),
        (["sweep", "--param", "colour=1", "--n", "5"], "paper.colour: unknown parameter"),
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
    bad = CliRunner().invoke(main, ["compare", "--attacks", "teleport", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "unknown attack 'teleport'" in bad.output


def test_cli_attack_names_match_the_config():
    from swarmraft.cli import ATTACK_NAMES
    from swarmraft.experiments.config import ATTACKS

    assert ATTACK_NAMES == list(ATTACKS)
