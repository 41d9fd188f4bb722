"""Packaging: the scenarios ship inside the package (by name from any folder), `python -m
swarmraft` is the command, and Ctrl-C exits 130 rather than 2 (bad input)."""

import subprocess
import sys
from pathlib import Path

from click.testing import CliRunner

from swarmraft.cli import main
from swarmraft.experiments.mission import load_scenario
from swarmraft.sim.scenario import find_scenario, shipped_scenarios

ROOT = Path(__file__).parent.parent
SHIPPED = [
    "coordinated-drag",
    "demo",
    "drag-off",
    "jammed-drone",
    "join-leave",
    "leader-crash-under-attack",
    "packet-loss-20",
    "paper-recovery-11-5",
    "paper-recovery-16-7",
    "paper-recovery-6-2",
    "sparse-65",
]


def test_one_copy_of_the_scenarios_inside_the_package():
    assert sorted(shipped_scenarios()) == SHIPPED
    assert all(p.parent == ROOT / "src" / "swarmraft" / "scenarios" for p in shipped_scenarios().values())
    assert not (ROOT / "scenarios").exists()


BUILD_PY = """
import sys
from setuptools.config.pyprojecttoml import apply_configuration
from setuptools.dist import Distribution

dist = Distribution()
apply_configuration(dist, "pyproject.toml")
dist.script_name = "setup.py"
cmd = dist.get_command_obj("build_py")
cmd.build_lib = sys.argv[1]
cmd.ensure_finalized()
cmd.run()
"""


def test_a_built_package_holds_the_scenarios(tmp_path):
    """What setuptools puts in a wheel (build_py into a folder): every scenario file."""
    r = subprocess.run(
        [sys.executable, "-W", "ignore", "-c", BUILD_PY, str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    built = sorted(p.stem for p in (tmp_path / "swarmraft" / "scenarios").glob("*.toml"))
    assert built == SHIPPED


def test_scenario_by_name_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert find_scenario("demo") == shipped_scenarios()["demo"]
    assert find_scenario("demo.toml") == shipped_scenarios()["demo"]
    assert load_scenario("demo").name == "demo-mission"
    # a file of that name in the working folder wins over the shipped one
    (tmp_path / "demo.toml").write_text('name = "mine"\n')
    assert load_scenario("demo.toml").name == "mine"


def test_python_m_swarmraft_runs_a_shipped_mission_from_another_folder(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "swarmraft", "mission", "--scenario", "paper-recovery-6-2", "--out", "o"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "o" / "summary.json").exists()
    assert "wrote o/summary.json" in r.stdout


def test_python_m_swarmraft_help(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "swarmraft", "--help"], cwd=tmp_path, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    assert "demo" in r.stdout and "mission" in r.stdout


def test_demo_defaults_to_the_shipped_scenario():
    scenario = next(p for p in main.commands["demo"].params if p.name == "scenario_file")
    assert scenario.default == "demo"


def test_ctrl_c_exits_130_not_2(tmp_path, monkeypatch):
    import swarmraft.experiments

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(swarmraft.experiments, "run_sweep", interrupted)
    r = CliRunner().invoke(main, ["sweep", "--n", "5", "--trials", "5", "--out", str(tmp_path / "o")])
    assert r.exit_code == 130, r.output
    assert "error:" not in r.output
    assert r.output.strip().splitlines()[-1] == "interrupted"


def test_no_command_prints_the_help():
    r = CliRunner().invoke(main, [])
    assert r.exit_code == 0, r.output
    assert r.output.startswith("Usage: ") and "error" not in r.output
    assert "\n  sweep " in r.output and "\n  demo " in r.output
