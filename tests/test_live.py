"""The live view's stream and recordings (docs/live.md): the simulator's per-step hook leaves a
mission unchanged, `--record` and `record DIR` write every drone's positions, the leader and
the events, a networked run's files are followed as they grow, and bad input (no rerun, a
port in use, a missing .rrd, a folder that is not a mission's) is one line with status 2."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from proc_lines import exit_code, line_queue, wait_line
from rrd import assert_swarm_recorded, recording_rows
from swarmraft.cli import main
from swarmraft.experiments.mission import load_scenario, run_and_write
from swarmraft.net.results import LaunchTail, launch_log
from swarmraft.net.swarmfile import drone_file
from swarmraft.sim.sensing import ScenarioWorld

# 5 drones for 6 s: drone 2 spoofed by 30 m from 1.5 s, the leader crashed at 3 s.
SCENARIO = """
name = "live-test"
seed = 5
drones = 5
duration_s = 6

[protocol]
detector = "joint"

[[spoof]]
kind = "jump"
drones = [2]
start_s = 1.5
magnitude = 30

[[fault]]
kind = "crash-leader"
at_s = 3
"""


def swarmraft(*args: str, rc: int = 0) -> str:
    """What `swarmraft ARGS` prints (stdout and stderr), its exit status checked."""
    r = CliRunner().invoke(main, list(args))
    assert r.exit_code == rc, r.output
    return r.output


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A mission run with --record; its folder holds scenario.toml, the results and live.rrd."""
    d = tmp_path_factory.mktemp("live")
    (d / "scenario.toml").write_text(SCENARIO)
    swarmraft(
        "mission",
        "--scenario",
        str(d / "scenario.toml"),
        "--out",
        str(d / "out"),
        "--record",
        str(d / "live.rrd"),
    )
    return d


def test_a_mission_is_the_same_with_and_without_the_step_hook(tmp_path):
    (tmp_path / "s.toml").write_text(SCENARIO)
    sc = load_scenario(tmp_path / "s.toml")
    seen: list[int] = []
    committed_when_seen: list[bool] = []

    def on_step(log, k):
        seen.append(k)
        committed_when_seen.append(bool(log.committed[k]))

    run_and_write(sc, tmp_path / "plain")
    run_and_write(sc, tmp_path / "hooked", on_step=on_step)
    for f in ("steps.csv", "summary.json"):
        assert (tmp_path / "plain" / f).read_bytes() == (tmp_path / "hooked" / f).read_bytes()
    assert seen == list(range(sc.steps + 1))
    # the hook sees records as they commit, within the step after their own
    assert sum(committed_when_seen) > sc.steps // 2


def test_the_recording_holds_every_drone_moving_the_flags_and_the_leader_change(recorded):
    summary = json.loads((recorded / "out" / "summary.json").read_text())
    rows = assert_swarm_recorded(recorded / "live.rrd", drones=5)
    assert len(rows["/swarm/verified"]) >= summary["steps"]
    texts = [r["TextLog:text"][0] for _, r in rows["/events"]]
    assert any(t.startswith("leader ") and "crashed" in t for t in texts)
    assert any(t.startswith("drone 2 flagged") for t in texts)
    reported = rows["/swarm/reported"]
    red = [r for _, r in reported if 0xE74C3CFF in (r["Points3D:colors"] or [])]
    assert red  # drone 2's report drawn in the flagged colour


def test_record_dir_writes_the_recording_of_a_mission_folder(recorded):
    out = swarmraft("record", str(recorded / "out"))
    rrd = recorded / "out" / "recording.rrd"
    assert f"wrote {rrd}" in out
    live, after = recording_rows(recorded / "live.rrd"), recording_rows(rrd)

    def final(rows, t):  # the last row at time t (a late record is logged again)
        return [r for tt, r in rows["/swarm/verified"] if abs(tt - t) < 1e-9][-1]["Points3D:positions"]

    for t in (1.0, 2.5, 4.5):
        np.testing.assert_allclose(final(live, t), final(after, t), atol=1e-4)


def test_ctrl_c_stops_the_viewer_even_where_the_parent_ignored_it(recorded):
    """A process started with SIGINT ignored (a parent that ignores it passes that on) still
    stops `swarmraft view` on Ctrl-C: the wait for Ctrl-C installs its own handler. Without it
    the viewer stays up for good."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cmd = [sys.executable, "-m", "swarmraft", "view", str(recorded / "live.rrd"), "--port", str(port)]
    ignore = lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)  # noqa: E731
    out = {"stdout": subprocess.PIPE, "stderr": subprocess.STDOUT, "text": True}
    env = {**os.environ, "PYTHONFAULTHANDLER": "1"}  # a hang shows its stacks (exit_code)
    proc = subprocess.Popen(cmd, preexec_fn=ignore, env=env, **out)
    seen: list[str] = []
    try:
        q = line_queue(proc)
        wait_line(q, "Ctrl-C to stop", 120, seen)
        proc.send_signal(signal.SIGINT)
        assert exit_code(proc, q, 60, seen) == 0, "".join(seen)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_record_dir_refuses_a_folder_that_is_not_a_missions_and_mixed_uses(tmp_path):
    out = swarmraft("record", str(tmp_path), rc=2)
    assert out.strip() == (
        f"error: DIR: {tmp_path} is not a mission folder (no steps.csv, summary.json, scenario.json; "
        "`swarmraft mission` and `swarmraft launch` write one)"
    )
    out = swarmraft("record", str(tmp_path), "--scenario", "demo", rc=2)
    assert out.startswith("error: give either a mission folder DIR or --scenario")
    out = swarmraft("record", rc=2)
    assert out.startswith("error: give a mission folder DIR (to write a .rrd recording) or --scenario")
    assert len(out.strip().splitlines()) == 1
    # a missing DIR is DIR's error, not --out's (whose default lies inside DIR)
    out = swarmraft("record", str(tmp_path / "nope"), rc=2)
    assert out.startswith("error: DIR: no folder ") and "--out" not in out
    assert str(tmp_path / "nope") in "".join(out.split())
    # the two uses' files mixed up: a sensor log is CSV, a recording comes from a folder
    out = swarmraft("record", "--scenario", "demo", "--out", str(tmp_path / "r.rrd"), rc=2)
    assert "with --scenario the file written is a sensor log (CSV)" in " ".join(out.split())
    assert not (tmp_path / "r.rrd").exists()
    out = swarmraft("record", "--scenario", "demo", "--out", str(tmp_path / "s.csv"), "--seconds", "0", rc=2)
    assert "--seconds" in out and "x>0" in out.replace(" ", "")


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["mission", "--scenario", "demo", "--live"], "--live"),
        (["mission", "--scenario", "demo", "--record", "x.rrd"], "--record"),
        (["view", "{rrd}"], "swarmraft view"),
    ],
)
def test_without_the_live_extra_the_command_says_how_to_install_it(tmp_path, monkeypatch, args, option):
    monkeypatch.setitem(sys.modules, "rerun", None)  # what `import rerun` meets without the extra
    monkeypatch.chdir(tmp_path)
    rrd = tmp_path / "a.rrd"
    rrd.write_bytes(b"")
    out = swarmraft(*[a.replace("{rrd}", str(rrd)) for a in args], rc=2)
    assert out == f"error: {option} needs the live extra: pip install 'swarmraft[live]'\n"
    assert not (tmp_path / "results").exists()  # refused before the mission ran


def test_live_refuses_a_port_in_use_before_running(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        out = swarmraft(
            "mission",
            "--scenario",
            "demo",
            "--out",
            str(tmp_path / "o"),
            "--live",
            "--port",
            str(port),
            rc=2,
        )
    assert (
        out.strip().splitlines()[-1]
        == f"error: --port: 127.0.0.1:{port} is in use; choose another port with --port"
    )
    assert not (tmp_path / "o").exists()


def test_view_and_live_options_refuse_bad_input_in_one_line(tmp_path):
    out = swarmraft("view", str(tmp_path / "none.rrd"), rc=2)
    assert out.startswith(f"error: RRD: no file {tmp_path / 'none.rrd'}")
    out = swarmraft("mission", "--scenario", "demo", "--speed", "4", rc=2)
    assert out.endswith("error: --speed: only with --live (see `main mission --help`)\n")
    out = swarmraft("mission", "--scenario", "demo", "--record", str(tmp_path / "x.csv"), rc=2)
    assert out.startswith(f"error: --record: {tmp_path / 'x.csv'}: give a file name ending in .rrd")


def _write_lines(path: Path, rows: list[dict], torn: str = "") -> None:
    with path.open("a") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")
        f.write(torn)


def test_following_a_networked_runs_files_as_they_grow_gives_the_log_launch_writes(tmp_path):
    (tmp_path / "s.toml").write_text(SCENARIO)
    sc = load_scenario(tmp_path / "s.toml")
    world = ScenarioWorld.build(sc)
    nodes = tmp_path / "nodes"
    nodes.mkdir()
    start = 1000.0
    rng = np.random.default_rng(3)

    def row(k: int, committed: bool) -> dict:
        base = {"step": k, "committed": committed, "reported": [float(v) for v in rng.normal(size=3)]}
        if not committed:
            return {**base, "status": "skipped"}
        return {
            **base,
            "status": "ok",
            "term": 2,
            "record": f"h{k}",
            "faulty": [2] if k >= 3 else [],
            "missing": [],
            "positions": [[float(k), float(i), 0.0] for i in range(5)],
            "hpl": [1.0] * 5,
            "vpl": [2.0] * 5,
            "applied_unix_s": start + k * sc.dt_s + 0.02,
        }

    for d in range(1, 6):
        _write_lines(
            drone_file(nodes, d, "events.jsonl"),
            [{"t": start - 1, "event": "start", "role": "follower", "term": 0}],
        )
    _write_lines(
        drone_file(nodes, 3, "events.jsonl"),
        [{"t": start + 0.05, "event": "role", "role": "leader", "term": 2}],
    )
    tail = LaunchTail(world, nodes, start, [], {})
    for d in range(1, 6):
        _write_lines(
            drone_file(nodes, d, "steps.jsonl"), [row(0, False), row(1, True)], torn='{"step": 2, "comm'
        )
    tail.poll()
    assert tail.log.committed[:3].tolist() == [False, True, False]
    assert tail.log.leader[1] == 3
    for d in range(1, 6):
        path = drone_file(nodes, d, "steps.jsonl")
        path.write_text(path.read_text().rsplit("\n", 1)[0] + "\n")  # the torn line completed as a new one
        _write_lines(path, [row(2, True), row(3, True)])
    tail.poll()
    final = launch_log(world, nodes, start, [], {})
    for name in (
        "committed",
        "verified",
        "faulty",
        "missing",
        "hpl",
        "vpl",
        "leader",
        "term",
        "reported",
        "alive",
    ):
        np.testing.assert_array_equal(getattr(tail.log, name), getattr(final, name), err_msg=name)
    np.testing.assert_allclose(tail.log.latency_ms, final.latency_ms)


def test_a_late_record_is_logged_again_and_never_told_as_a_skipped_step(recorded, tmp_path):
    import copy

    import rerun as rr

    from swarmraft.experiments.mission_folder import read_mission
    from swarmraft.viz.live import StepStream, log_static, new_stream

    final = read_mission(recorded / "out").log
    assert final.committed[10:20].all()
    live = copy.deepcopy(final)
    live.committed[12] = False  # step 12's record has not arrived yet
    rec = new_stream(rr, "late")
    rec.save(str(tmp_path / "late.rrd"))
    log_static(rec, live)
    stream = StepStream(rec, settle_steps=5)
    stream.update(live, 13)  # 12 is logged without a record; its events wait for it
    live.committed[12] = True  # the record arrives
    stream.update(live, 15)
    stream.finish(final)
    rec.flush()
    rec.disconnect()
    rows = recording_rows(tmp_path / "late.rrd")
    texts = [r["TextLog:text"][0] for _, r in rows["/events"]]
    assert not any("skipped from step 12" in t for t in texts)
    at_12 = [r for t, r in rows["/swarm/verified"] if abs(t - 1.2) < 1e-9]
    assert [len(r["Points3D:positions"]) for r in at_12] == [0, 5]  # logged again with its record
