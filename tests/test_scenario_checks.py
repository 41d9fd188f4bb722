"""Scenarios that were accepted but meant something other than what they say: each is now a
one-line error naming the field (found by a review of the mission summaries)."""

import pytest
from pydantic import ValidationError

from swarmraft.sim.scenario import Scenario

JUMP = {"kind": "jump", "drones": [4], "start_s": 1}


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        # the steps' times and the motion's time points disagreed (a broadcast error, or a spoof
        # or fault after the last step, which vanished without a word)
        ({"duration_s": 4, "dt_s": 0.7}, r"dt_s: 0\.7 s does not divide duration_s = 4 s"),
        ({"duration_s": 4, "dt_s": 0.3}, r"dt_s: 0\.3 s does not divide duration_s = 4 s"),
        # one drone twice in a list: two detection entries, or a rotation axis of length 0
        ({"spoof": [{**JUMP, "drones": [2, 2]}]}, r"spoof\[0\]\.drones: drone 2 twice"),
        (
            {"spoof": [{"kind": "collusion", "drones": [2, 4], "pivots": [3, 3], "start_s": 1}]},
            r"spoof\[0\]\.pivots: drone 3 twice",
        ),
        ({"outage": [{"drones": [5, 5], "start_s": 1}]}, r"outage\[0\]\.drones: drone 5 twice"),
        # two spoofs of one drone at once: the later replaced the earlier, which was still scored
        (
            {"spoof": [{**JUMP, "drones": [3]}, {"kind": "drag", "drones": [3], "start_s": 2}]},
            r"spoof\[1\]\.drones: drone 3 is spoofed by spoof\[0\] from 1 s",
        ),
        # a spoof of a drone without a fix: it reported INS and the spoof was scored as missed
        (
            {"spoof": [JUMP], "outage": [{"drones": [4], "start_s": 0.5, "end_s": 2}]},
            r"outage\[0\]\.drones: drone 4 has no GNSS fix from 0\.5 s to 2 s while spoof\[0\]",
        ),
        # fields a fault's kind does not use were ignored
        (
            {"fault": [{"kind": "loss", "at_s": 1, "drone": 3, "value": 0.5}]},
            r"fault\[0\]\.drone: a loss fault does not use it",
        ),
        (
            {"fault": [{"kind": "crash-leader", "at_s": 1, "drone": 3}]},
            r"fault\[0\]\.drone: a crash-leader fault does not use it",
        ),
        (
            {"fault": [{"kind": "heal", "at_s": 1, "groups": [[1, 2]]}]},
            r"fault\[0\]\.groups: a heal fault does not use it \(only partition\)",
        ),
        (
            {"fault": [{"kind": "crash", "at_s": 1, "drone": 2, "value": 0.5}]},
            r"fault\[0\]\.value: a crash fault does not use it \(only loss\)",
        ),
        # a drone in two groups bridged them: no partition
        (
            {"fault": [{"kind": "partition", "at_s": 1, "groups": [[1, 2, 3, 4], [4, 5, 6]]}]},
            r"fault\[0\]\.groups: drone 4 is in two groups",
        ),
        # a spoof's field its kind does not use
        ({"spoof": [{**JUMP, "rate": 2.0}]}, r"spoof\[0\]\.rate: a jump spoof does not use it \(only drag\)"),
        (
            {"spoof": [{"kind": "drag", "drones": [2], "start_s": 1, "magnitude": 40}]},
            r"spoof\[0\]\.magnitude: a drag spoof does not use it \(only jump, area\)",
        ),
        ({"spoof": [{**JUMP, "angle_deg": 90}]}, r"spoof\[0\]\.angle_deg: a jump spoof does not use it"),
        ({"spoof": [{**JUMP, "pivots": [1]}]}, r"spoof\[0\]\.pivots: a jump spoof does not use it"),
    ],
)
def test_a_scenario_that_means_something_else_is_refused(fields, message):
    with pytest.raises(ValidationError, match=message):
        Scenario(drones=9, **fields)


def test_what_stays_allowed():
    # jamming then spoofing: the outage ends as the spoof starts
    Scenario(drones=9, spoof=[JUMP], outage=[{"drones": [4], "start_s": 0.2, "end_s": 1}])
    # one drone spoofed twice, one spoof after the other
    Scenario(drones=9, spoof=[{**JUMP, "end_s": 2}, {"kind": "drag", "drones": [4], "start_s": 2}])
    # a step that divides the mission up to rounding (0.3 s into 6 s), an event between steps
    Scenario(drones=9, duration_s=6, dt_s=0.3, fault=[{"kind": "crash-leader", "at_s": 5.95}])
    # an enlargement (GNSS left alone) beside a position spoof of the same drone, or while it is
    # jammed: it lengthens the ranges only
    enl = {"kind": "enlarge", "drones": [4], "start_s": 3, "enlarge": 5.0}
    Scenario(drones=9, spoof=[{**JUMP, "end_s": 5}, enl])
    Scenario(drones=9, spoof=[enl], outage=[{"drones": [4], "start_s": 2}])
    # an enlargement with any kind of spoof (the README's `enlarge = 5.0`), partitions apart
    Scenario(drones=9, spoof=[{**JUMP, "enlarge": 5.0}])
    Scenario(drones=9, fault=[{"kind": "partition", "at_s": 1, "groups": [[1, 2, 3, 4], [5, 6]]}])
