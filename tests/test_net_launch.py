"""`swarmraft launch` as a user runs it: real drone processes on 127.0.0.1 behind the fault
relay (20 % loss and 20 % duplication on every link), a drone SIGKILLed, every process frozen
with SIGSTOP for 2 s and resumed, a partition and its heal; every drone ends with identical
records, the steps go on after each fault, and launch writes what `swarmraft mission` writes."""

import csv
import json
import os
import subprocess
import sys
import tomllib

import pytest

from swarmraft.experiments.mission import STEP_COLUMNS
from swarmraft.net.launch import events, read_jsonl

SCENARIO = """
name = "launch-faults"
seed = 5
drones = 5
duration_s = 30

[network]
loss = 0.2
duplicate = 0.2

[protocol]
detector = "joint"

[[spoof]]
kind = "jump"
drones = [3]
start_s = 0
magnitude = 30

[[fault]]
kind = "crash"
drone = 5
at_s = 14

[[fault]]
kind = "pause"
at_s = 17
for_s = 2

[[fault]]
kind = "partition"
at_s = 22
groups = [[1], [2, 3, 4]]

[[fault]]
kind = "heal"
at_s = 25
"""


def test_launch_through_the_fault_relay_with_a_crash_a_pause_and_a_partition(tmp_path):
    scenario = tmp_path / "faults.toml"
    scenario.write_text(SCENARIO)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "swarmraft", "launch", "--scenario", str(scenario), "--out", str(out)]
    done = subprocess.run(
        cmd, capture_output=True, text=True, timeout=150, env={**os.environ, "COLUMNS": "200"}
    )
    assert done.returncode == 0, done.stdout + done.stderr
    for line in (
        "network: through the fault relay: delay 1-3 ms, loss 20%, duplication 20%",
        "14 s: drone 5 killed (SIGKILL)",
        "17 s: every drone paused (SIGSTOP) for 2 s",
        "19 s: every drone resumed (SIGCONT)",
        "22 s: partition [[1], [2, 3, 4]] (fault relay)",
        "25 s: network healed (fault relay)",
        "every node's records identical: yes",
    ):
        assert line in done.stdout, line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["records_identical_on_all_nodes"] is True
    relay = summary["launch"]["relay_counters"]
    assert relay["lost"] > 0 and relay["duplicated"] > 0 and relay["cut"] > 0
    # the duplicates arrive and are dropped as replays, never applied twice
    stops = {i: [e for e in events(out / "nodes", i) if e["event"] == "stop"] for i in range(1, 6)}
    assert not stops[5]  # SIGKILLed: no clean stop
    for i in range(1, 5):
        (stop,) = stops[i]
        assert stop["reason"] == "end of scenario"
        assert stop["verifier"].get("replayed", 0) > 0
        assert stop["counters"].get("internal_error", 0) == 0
        assert stop["counters"].get("replayed_record_differs", 0) == 0

    # what `swarmraft mission` writes
    with (out / "steps.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == tuple(STEP_COLUMNS) and len(rows) == 301 * 5
    for name in ("error_over_time", "swarm_maps", "consensus_latency", "messages_per_step"):
        assert (out / "figures" / f"{name}.png").stat().st_size > 10_000
    committed = {int(r["step"]): r["committed"] == "1" for r in rows}
    # frozen 17-19 s: no step of the pause commits (its timers fire late and are dropped)
    assert not any(committed[k] for k in range(171, 190))
    # the steps go on in the 5 s after the crash, the resume and the heal (20 % loss can cost
    # a second or two of elections now and then)
    for lo in (141, 190, 250):
        assert sum(committed[k] for k in range(lo, lo + 50)) >= 10, lo
    # the dead drone is not alive after its crash, and the spoofed drone is flagged
    alive5 = [r["alive"] == "1" for r in rows if r["drone"] == "5"]
    assert not any(alive5[141:]) and any(alive5[:140])
    # judged as the simulator's missions are. The simulator flags drone 3 in 93.4 % of 273
    # steps of this scenario; on processes (timing-dependent) 0.9 failed in 5 of 8 runs on
    # 2026-12-02 on a 2-core AMD EPYC (3 of 5 with this code, 2 of 3 with 1ddf171's; 0.871-0.899
    # where the value was printed)
    (det,) = summary["detections"]
    assert det["drone"] == 3 and det["judged_steps"] >= 50 and det["flagged_fraction"] >= 0.8

    # drone 1 was cut off 22-25 s: the records of those steps reached it only after the heal
    step0 = tomllib.loads((out / "swarm.toml").read_text())["start_unix_s"]
    applied1 = {r["step"]: r for r in read_jsonl(out / "nodes" / "drone-1.steps.jsonl") if r["committed"]}
    others = {r["step"]: r for r in read_jsonl(out / "nodes" / "drone-2.steps.jsonl") if r["committed"]}
    cut_steps = [k for k in range(222, 245) if k in others]
    assert all(k in applied1 for k in cut_steps)
    # the majority went on while drone 1 was cut off ... (drone 1 led when cut off in most runs:
    # 3 of 5 drones, with 20 % loss on every message, need 0.36 s for a new leader at the median,
    # 0.98 s at p90 and 1.9 s at p99 in the simulator over 297 seeds; 2 s in a failed CI run
    # that asked for 10 of these 23 steps)
    assert sum(others[k]["applied_unix_s"] < step0 + 25 for k in cut_steps) >= 3
    # ... and drone 1 learnt of none of those records before the heal
    assert all(applied1[k]["applied_unix_s"] >= step0 + 25 for k in cut_steps)
    with (out / "records.csv").open(newline="") as f:
        assert all(r["identical"] == "1" for r in csv.DictReader(f))


def test_launch_refuses_a_bad_relay_choice_or_replay_log_in_one_line_naming_the_option(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,drone\n")
    for args, start in (
        (["--relay", "maybe"], "error: --relay: 'maybe' is not one of 'auto', 'on', 'off'."),
        (
            ["--replay", str(tmp_path / "nope.csv")],
            f"error: --replay: {tmp_path / 'nope.csv'}: cannot read it",
        ),
        (["--replay", str(bad)], f"error: --replay: {bad}:1: header: "),
    ):
        out = tmp_path / "out"
        cmd = [sys.executable, "-m", "swarmraft", "launch", "--scenario", "demo", "--out", str(out), *args]
        done = subprocess.run(
            cmd, capture_output=True, text=True, timeout=60, env={**os.environ, "COLUMNS": "200"}
        )
        assert done.returncode == 2, done.stderr
        assert done.stderr.startswith(start) and len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert not out.exists()  # nothing written, nothing started


def test_a_launch_that_commits_nothing_fails_and_writes_strict_json(tmp_path):
    """Step 0 at once and a 1 s scenario: the drones come up after it ended, nothing commits.
    The run is void: exit status 1 with one line saying so (it was 0), and summary.json is
    strict JSON, null where there is no latency (it held NaN, which parsers refuse)."""
    scenario = tmp_path / "short.toml"
    scenario.write_text('name = "short"\ndrones = 4\nduration_s = 1\n')
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "swarmraft", "launch", "--scenario", str(scenario), "--out", str(out)]
    done = subprocess.run([*cmd, "--start-delay", "0"], capture_output=True, text=True, timeout=150)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "0 of 11 steps committed" in done.stdout
    assert "error: no step was committed" in done.stderr and "Warning" not in done.stderr
    summary = json.loads(
        (out / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(f"not JSON: {c}")
    )
    assert summary["latency_ms_median"] is None and summary["raft_messages_per_committed_step"] is None


def test_launch_says_before_it_starts_when_the_replayed_log_ends_before_the_scenario(tmp_path):
    from swarmraft.cli.net import short_log
    from swarmraft.net.sources.replay import read_sensor_log
    from swarmraft.sim.scenario import Scenario

    sc = Scenario(drones=4, duration_s=10)
    rows = "\n".join(f"{t / 10:g},{d},0,0,0,0,0,0,,,," for t in range(51) for d in range(1, 5))
    log = tmp_path / "short.csv"
    log.write_text(
        "t_s,drone,gnss_x,gnss_y,gnss_z,ins_x,ins_y,ins_z,range_1,range_2,range_3,range_4\n" + rows
    )
    said = short_log(read_sensor_log(log, 4), sc, log)
    assert said is not None and said.startswith(f"{log} ends at 5 s and the scenario flies 10 s")
    assert short_log(read_sensor_log(log, 4), Scenario(drones=4, duration_s=5), log) is None
    # its last lines serve 1 s more (max_age_s): a log 0.2 s short skips nothing
    assert short_log(read_sensor_log(log, 4), Scenario(drones=4, duration_s=5.2), log) is None


def test_launch_says_when_a_drone_process_exits_on_its_own(tmp_path):
    """A drone process that exits without launch stopping it (a crash, out of memory) was
    reported alive to the end, its skipped steps unexplained. Now launch says so once, counts
    the drone down from then (its steps are not `alive`) and lists it among the events and in
    ``launch.exited_on_their_own``; a drone launch killed itself, and exits at the scenario's
    end, are not such."""
    import time

    from swarmraft.net.launch import NodeProcess
    from swarmraft.net.localswarm import LocalSwarm
    from swarmraft.sim.scenario import Scenario

    said = []
    sc = Scenario(name="x", drones=4, duration_s=10)
    run = LocalSwarm(sc, tmp_path / "s.toml", tmp_path, say=said.append)
    run.start_unix_s = time.time() - 2.0  # 2 s into a 10 s scenario
    run.procs = {}
    for d, code in [(1, "import sys; sys.exit(3)"), (2, "import time; time.sleep(60)")]:
        p = NodeProcess(d, tmp_path / "swarm.toml", tmp_path / f"drone-{d}.log")
        p.proc = subprocess.Popen([sys.executable, "-c", code])
        run.procs[d] = p
    run.procs[1].proc.wait()
    run._kill(2, "killed")  # by launch: not on its own
    run._watch()
    run._watch()  # said once
    assert [(d, s) for d, _, s in run.exited] == [(1, 3)]
    assert len(said) == 1 and said[0].startswith("warning: ")
    assert "drone 1 exited on its own (exit status 3)" in said[0]
    assert [what for _, what in run.events] == ["drone 1 exited on its own (exit status 3)"]
    assert len(run.kills[1]) == 1 and len(run.kills[2]) == 1
    run.start_unix_s = time.time() - 11.0  # the scenario is over: exits are the drones' own end
    run._down.clear()
    run._watch()
    assert len(run.exited) == 1
