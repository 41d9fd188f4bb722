"""Small results folders for the report and animation tests, made once per test session: a
4 s mission of 6 drones (a spoof, a leader crash) with its figures, a one-cell sweep with
only its scaling figure, and a two-detector comparison with its figures: a test module
names this module in its ``pytest_plugins``."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from swarmraft.cli import main


@pytest.fixture(scope="session")
def mission_dir(tmp_path_factory) -> Path:
    from swarmraft.cli.missions import mission_figures
    from swarmraft.experiments.mission import write_results
    from swarmraft.sim.mission import run_mission
    from swarmraft.sim.scenario import Scenario

    sc = Scenario(
        name="short",
        drones=6,
        duration_s=4,
        seed=7,
        spoof=[{"kind": "jump", "drones": [2], "start_s": 1, "magnitude": 30}],
        fault=[{"kind": "crash-leader", "at_s": 2}],
    )
    out = tmp_path_factory.mktemp("report") / "mission"
    mission_figures(write_results(run_mission(sc), out), out)
    return out


@pytest.fixture(scope="session")
def sweep_dir(tmp_path_factory) -> Path:
    from swarmraft.cli.sweeps import draw_figures
    from swarmraft.experiments import build_config, run_sweep

    out = tmp_path_factory.mktemp("report") / "sweep"
    run_sweep(build_config("reference", n=(5,), f=(1,), trials=20), out, workers=1)
    draw_figures("scaling", out)  # distribution and recovery left out: the report must say so
    return out


@pytest.fixture(scope="session")
def compare_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report") / "compare"
    args = ["compare", "--detectors", "paper,clique", "--n", "7", "--f", "2", "--trials", "20"]
    r = CliRunner().invoke(main, [*args, "--workers", "1", "--out", str(out)])
    assert r.exit_code == 0, r.output
    return out
