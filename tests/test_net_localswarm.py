"""`net.localswarm.LocalSwarm`'s faults, without processes: each scenario fault becomes the
right action on the right drone's process or on the relay, in time order, and crash-leader
kills the drone whose event file says it leads, of the highest term."""

import json

from swarmraft.net import localswarm
from swarmraft.net.localswarm import LocalSwarm, needs_relay
from swarmraft.sim.scenario import Scenario


class FakeProcess:
    def __init__(self, log):
        self.log, self.alive, self.paused = log, True, False

    def kill(self):
        self.log.append("kill")
        self.alive = False

    def pause(self):  # as NodeProcess: a process that is not running is not paused
        if self.alive and not self.paused:
            self.log.append("pause")
            self.paused = True

    def resume(self):
        if self.alive and self.paused:
            self.log.append("resume")
        self.paused = False

    def start(self):
        self.log.append("start")
        self.alive = True

    def compromise(self):
        self.log.append("compromise")


class FakeRelay:
    """Stands for RelayThread: call(method, *args) records what was asked of the relay."""

    def __init__(self):
        self.calls = []
        self.relay = self

    def call(self, method, *args, **kwargs):
        self.calls.append((method.__name__, args, kwargs))

    def partition(self, groups):
        pass

    def heal(self):
        pass

    def set_all(self, **changes):
        pass


def swarm_with(tmp_path, faults, network=None):
    sc = Scenario(drones=5, duration_s=30, fault=faults, network=network or {})
    run = LocalSwarm(sc, tmp_path / "s.toml", tmp_path / "out", say=lambda s: None)
    run.nodes_dir.mkdir(parents=True)
    run.logs = {i: [] for i in range(1, 6)}
    run.procs = {i: FakeProcess(run.logs[i]) for i in range(1, 6)}
    run.relay = FakeRelay() if run.link is not None else None
    return run


def role_events(run, drone, *roles):
    with (run.nodes_dir / f"drone-{drone}.events.jsonl").open("a") as f:
        for role, term in roles:
            f.write(json.dumps({"t": 0, "event": "role", "role": role, "term": term}) + "\n")


def test_each_fault_acts_on_its_process_or_the_relay_in_time_order(tmp_path):
    faults = [
        {"kind": "heal", "at_s": 25},
        {"kind": "crash-leader", "at_s": 10},
        {"kind": "pause", "at_s": 12, "for_s": 2, "drone": 2},
        {"kind": "crash", "at_s": 5, "drone": 4},
        {"kind": "restart", "at_s": 20, "drone": 4},
        {"kind": "partition", "at_s": 22, "groups": [[1], [2, 3, 5]]},
        {"kind": "loss", "at_s": 23, "value": 0.3},
        {"kind": "pause", "at_s": 26, "for_s": 1},
    ]
    run = swarm_with(tmp_path, faults)
    assert needs_relay(run.sc) and run.relay is not None
    role_events(run, 1, ("leader", 1), ("follower", 2))  # led term 1, then lost it
    role_events(run, 3, ("follower", 1), ("leader", 2))  # leads term 2
    role_events(run, 5, ("leader", 1))  # a stale leader of term 1
    acts = run.actions()
    assert [(a.at_s, a.kind) for a in acts] == [
        (5, "crash"),
        (10, "crash-leader"),
        (12, "pause"),
        (14, "resume"),
        (20, "restart"),
        (22, "partition"),
        (23, "loss"),
        (25, "heal"),
        (26, "pause"),
        (27, "resume"),
    ]
    said = [a.run() for a in acts]
    assert said[:5] == [
        "drone 4 killed (SIGKILL)",
        "leader 3 (term 2) killed (SIGKILL)",
        "drone 2 paused (SIGSTOP) for 2 s",
        "drone 2 resumed (SIGCONT)",
        "drone 4 restarted on its SQLite file",
    ]
    assert said[8:] == ["every drone paused (SIGSTOP) for 1 s", "every drone resumed (SIGCONT)"]
    assert run.logs[4] == ["kill", "start", "pause", "resume"]
    assert run.logs[3] == ["kill"] and run.logs[1] == run.logs[5] == ["pause", "resume"]
    assert run.logs[2] == ["pause", "resume", "pause", "resume"]
    assert run.relay.calls == [
        ("partition", ([[1], [2, 3, 5]],), {}),
        ("set_all", (), {"loss": 0.3}),
        ("heal", (), {}),
    ]
    assert set(run.kills) == {4, 3}


def test_without_the_relay_network_faults_are_said_not_applied(tmp_path):
    faults = [{"kind": "partition", "at_s": 2, "groups": [[1, 2], [3, 4, 5]]}]
    run = swarm_with(tmp_path, faults)
    run.relay = None  # as with --relay off
    assert run.actions()[0].run() == "partition: not applied (no fault relay: --relay off)"


def test_crash_leader_with_no_leader_known_kills_nothing(tmp_path):
    run = swarm_with(tmp_path, [{"kind": "crash-leader", "at_s": 3}])
    role_events(run, 2, ("candidate", 4))
    assert run.actions()[0].run() == "crash-leader: no leader known, nothing killed"
    assert not any(run.logs.values())


def test_the_relay_is_needed_only_for_what_loopback_cannot_do():
    assert not needs_relay(Scenario(drones=5, duration_s=10, network={"delay_ms": (5, 9)}))
    assert needs_relay(Scenario(drones=5, duration_s=10, network={"reorder": 0.1}))
    assert needs_relay(Scenario(drones=5, duration_s=10, fault=[{"kind": "loss", "at_s": 1, "value": 0.1}]))
    assert not needs_relay(
        Scenario(drones=5, duration_s=10, fault=[{"kind": "pause", "at_s": 1, "for_s": 1}])
    )


def test_transfer_leader_is_listed_as_not_applied_and_touches_no_process(tmp_path):
    run = swarm_with(tmp_path, [{"kind": "transfer-leader", "at_s": 4, "drone": 2}])
    acts = run.actions()
    assert [(a.at_s, a.kind) for a in acts] == [(4, "transfer-leader")]
    said = acts[0].run()
    assert said == "transfer-leader: not applied (the drone processes take no commands; simulator only)"
    assert all(log == [] for log in run.logs.values())


def test_join_and_leave_are_listed_as_not_applied_and_touch_no_process(tmp_path):
    faults = [{"kind": "join", "at_s": 2, "drone": 5}, {"kind": "leave", "at_s": 6, "drone": 1}]
    run = swarm_with(tmp_path, faults)
    acts = run.actions()
    assert [(a.at_s, a.kind) for a in acts] == [(2, "join"), (6, "leave")]
    said = [a.run() for a in acts]
    assert said == [
        f"{k}: not applied (every drone's process runs from the start, in the swarm; simulator only)"
        for k in ("join", "leave")
    ]
    assert all(log == [] for log in run.logs.values())


def test_lying_leader_tells_the_drone_that_leads_to_lie_and_no_other(tmp_path, monkeypatch):
    lie = {"kind": "lying-leader", "at_s": 3, "mode": "move", "drone": 2, "offset_m": 5}
    run = swarm_with(tmp_path, [lie])
    assert not needs_relay(run.sc)  # a process fault: no relay needed
    role_events(run, 1, ("leader", 1), ("follower", 2))
    role_events(run, 4, ("leader", 2))
    (act,) = run.actions()
    assert act.run() == "leader 4 (term 2) compromised (SIGUSR1): lies (move drone 2)"
    assert run.logs[4] == ["compromise"] and run.liar == 4
    assert all(run.logs[i] == [] for i in (1, 2, 3, 5))
    # no leader known: it waits LIE_WAIT_S for one, then says so
    monkeypatch.setattr(localswarm, "LIE_WAIT_S", 0.2)
    run = swarm_with(tmp_path / "b", [lie])
    role_events(run, 2, ("candidate", 3))
    assert run.actions()[0].run() == "lying-leader: no leader known within 0.2 s, nobody compromised"
    assert not any(run.logs.values()) and run.liar is None


def test_without_the_relay_the_line_names_what_of_the_network_is_not_applied(tmp_path):
    run = swarm_with(tmp_path, [], network={"loss": 0.2, "delay_ms": [1, 3]})
    run.link = None  # as with --relay off
    line = run.network_line()
    assert "no fault relay" in line and "delay 1-3 ms, loss 20% not applied" in line
    run = swarm_with(tmp_path / "b", [])
    run.link = None
    assert run.network_line().endswith("the scenario's delay 1-3 ms not applied)")


def test_a_fault_is_timed_when_launch_began_it_not_when_it_finished(tmp_path, monkeypatch):
    """crash-leader reads the drones' event files first; the fault's time is when that
    began (the skipped steps are counted from it), not 0.1 s later."""
    run = swarm_with(tmp_path, [{"kind": "crash-leader", "at_s": 0.0}])
    role_events(run, 2, ("leader", 1))
    # the fault's wait, its start, the kill (0.3 s later), then past the scenario's end
    clock = iter([100.0, 100.0, 100.3, 100.3])
    monkeypatch.setattr(localswarm.time, "time", lambda: next(clock, 200.0))
    run.start_unix_s = 100.0
    run.sc = run.sc.model_copy(update={"duration_s": 0.0})
    monkeypatch.setattr(run, "stop", lambda: None)
    run.run()
    assert run.events == [(0.0, "leader 2 (term 1) killed (SIGKILL)")]


def test_a_lie_is_timed_when_the_leader_was_told_not_when_launch_began_to_wait(tmp_path, monkeypatch):
    """lying-leader waits up to LIE_WAIT_S for a leader; its event is when the SIGUSR1 went,
    which the skipped steps are counted from (timed at the wait's start it was up to 5 s early)."""
    lie = {"kind": "lying-leader", "at_s": 0.0, "mode": "move", "drone": 2, "offset_m": 5}
    run = swarm_with(tmp_path, [lie])
    answers = iter([None, None, (2, 1)])
    monkeypatch.setattr(localswarm, "current_leader", lambda *a: next(answers))
    ticks = iter(range(100, 1000))  # each call of time.time() one second on
    monkeypatch.setattr(localswarm.time, "time", lambda: float(next(ticks)))
    monkeypatch.setattr(localswarm.time, "sleep", lambda s: None)
    monkeypatch.setattr(run, "stop", lambda: None)
    run.start_unix_s = 100.0
    run.sc = run.sc.model_copy(update={"duration_s": 0.0})
    run.run()
    (when, what) = run.events[0]
    assert what == "leader 2 (term 1) compromised (SIGUSR1): lies (move drone 2)"
    assert run.logs[2] == ["start", "compromise"]  # run() starts every process first
    assert when == 6.0  # began at 101, asked at 103, 104, 105; told at 106


def test_a_fault_that_finds_nothing_to_do_is_idle_not_an_event(tmp_path):
    """As in the simulator (idle_faults): a crash-leader with no leader known, a fault the
    processes cannot take, a relay fault without a relay did nothing, and listed as events
    they excused the skipped steps after them in the launch summary (found by a review)."""
    from swarmraft.sim.mission import Idle

    run = swarm_with(tmp_path, [{"kind": "crash-leader", "at_s": 3}, {"kind": "transfer-leader", "at_s": 4}])
    role_events(run, 2, ("candidate", 4))
    said = [a.run() for a in run.actions()]
    assert all(isinstance(s, Idle) for s in said)
    relayless = swarm_with(tmp_path / "r", [{"kind": "heal", "at_s": 1}])
    relayless.relay = None
    assert isinstance(relayless.actions()[0].run(), Idle)
    # a fault that acted is an event
    acted = swarm_with(tmp_path / "p", [{"kind": "pause", "at_s": 1, "drone": 2, "for_s": 1}])
    assert not isinstance(acted.actions()[0].run(), Idle)
