"""The scenario fault kind transfer-leader (issue 12 item 5): the leader hands over to a named
drone or to the most caught-up voter, in a mission that keeps identical records everywhere."""

import re

import pytest
from pydantic import ValidationError

from swarmraft.experiments.mission import error_series, summarize
from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario


@pytest.fixture(scope="module")
def handed_over():
    sc = Scenario(
        drones=5,
        duration_s=8,
        seed=1,
        network={"loss": 0.05},
        fault=[{"kind": "transfer-leader", "at_s": 3}, {"kind": "transfer-leader", "at_s": 5.5, "drone": 4}],
    )
    log = run_mission(sc)
    return log, summarize(log, error_series(log))


def test_the_leader_hands_over_twice_and_every_drone_keeps_identical_records(handed_over):
    log, summary = handed_over
    first, second = summary["events"]
    m = re.fullmatch(r"3\.0 s: leader (\d+) hands over to drone (\d+)", first)
    assert m and m.group(1) != m.group(2), first
    # the drone that took over is the leader that hands over in turn
    assert second == f"5.5 s: leader {m.group(2)} hands over to drone 4", second
    assert summary["records_identical_on_all_nodes"]
    # a step proposed while a transfer runs may be refused: at most a few around each
    skipped = [k for k in range(len(log.committed)) if not log.committed[k]]
    assert len(skipped) <= 6, skipped
    assert log.committed[-10:].all()


def test_a_transfer_to_an_unknown_drone_is_a_one_line_error():
    with pytest.raises(ValidationError, match=r"fault\[0\]\.drone: drone ids must be in 1\.\.5, got \[9\]"):
        Scenario(drones=5, duration_s=8, fault=[{"kind": "transfer-leader", "at_s": 3, "drone": 9}])
