"""A mission's results folder read back gives the log and errors that wrote it."""

import json

import numpy as np
import pytest

from swarmraft.experiments.config import ConfigError
from swarmraft.experiments.mission import write_results
from swarmraft.experiments.mission_folder import is_mission_folder, read_mission
from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    sc = Scenario(
        drones=6,
        duration_s=4,
        seed=7,
        spoof=[{"kind": "jump", "drones": [2], "start_s": 1, "magnitude": 30}],
        outage=[{"drones": [4], "start_s": 1.5, "end_s": 3}],
        fault=[{"kind": "crash-leader", "at_s": 2}],
    )
    out = tmp_path_factory.mktemp("mission")
    return out, write_results(run_mission(sc), out)


def test_every_per_step_array_and_error_comes_back_exactly(written):
    out, res = written
    back = read_mission(out)
    log = res.log
    assert back.log.scenario == log.scenario
    for name in ("t", "truth", "reported", "verified", "hpl", "vpl", "latency_ms"):
        np.testing.assert_array_equal(getattr(back.log, name), getattr(log, name), err_msg=name)
    for name in ("spoofed", "outage", "alive", "faulty", "missing", "committed", "leader", "term"):
        np.testing.assert_array_equal(getattr(back.log, name), getattr(log, name), err_msg=name)
    for name in ("raft_messages", "report_messages", "status"):
        np.testing.assert_array_equal(getattr(back.log, name), getattr(log, name), err_msg=name)
    for k, v in res.errors.items():
        np.testing.assert_array_equal(back.errors[k], v, err_msg=k)
    assert [e for _, e in back.log.events] == [e for _, e in log.events]
    np.testing.assert_allclose([t for t, _ in back.log.events], [t for t, _ in log.events], atol=0.05)
    assert back.summary == json.loads((out / "summary.json").read_text())
    assert log.leader.max() > 0 and len(set(log.leader.tolist()) - {0}) >= 2  # the crash moved the lead


def test_a_folder_that_is_not_a_mission_is_one_clear_error(written, tmp_path):
    out, _ = written
    assert is_mission_folder(out) and not is_mission_folder(tmp_path)
    with pytest.raises(ConfigError, match="DIR: .* is not a mission folder \\(no steps.csv"):
        read_mission(tmp_path)
    with pytest.raises(ConfigError, match="is not a folder"):
        read_mission(out / "steps.csv")
    for f in ("summary.json", "scenario.json", "steps.csv"):
        (tmp_path / f).write_text((out / f).read_text())
    lines = (tmp_path / "steps.csv").read_text().splitlines()
    (tmp_path / "steps.csv").write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(ConfigError, match="not a multiple of 6 drones"):
        read_mission(tmp_path)


def test_results_written_from_errors_given_are_the_results_written_from_scratch(written, tmp_path):
    # a caller that has the bounds already (bench_scale times them apart) passes them in;
    # the files must be what write_results computes itself
    from swarmraft.experiments.mission import error_series

    out, res = written
    again = write_results(res.log, tmp_path, errors=error_series(res.log))
    for name in ("steps.csv", "summary.json", "scenario.json"):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes(), name
    assert again.summary == res.summary
