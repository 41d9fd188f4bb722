"""A networked run's results as the simulator's `MissionLog`, so ``swarmraft launch`` writes
the same steps.csv, summary.json and figures as ``swarmraft mission`` (the experiments and viz
layers take it from there).

What the world determines (truth, GNSS, spoofing, outages, INS alone) comes from the scenario
as each drone computed it (`sim.mission.world_log`); what the swarm did comes from the drones'
files (docs/net.md): the committed records (the first drone's line for each step; every
drone's record hash goes to the log's ``agreement`` so disagreement shows), the position each drone
reported, the leader of each record's term (from the role events), the latency from a step's
start to the first drone applying its record, the datagrams sent per step (``sent.csv``), and
whether each process was up (its start and stop events, and the times launch SIGKILLed it).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from swarmraft.net.launch import read_jsonl
from swarmraft.net.swarmfile import drone_file
from swarmraft.sim.mission import MissionLog, ins_aligned_in_outages, world_log
from swarmraft.sim.sensing import ScenarioWorld


def _floats(row: list | None) -> np.ndarray:
    if row is None:
        return np.full(3, np.nan)
    return np.array([np.nan if v is None else float(v) for v in row])


def _levels(values: list | None, n: int) -> np.ndarray:
    if values is None:
        return np.full(n, np.nan)
    return np.array([np.inf if v == "inf" else np.nan if v is None else float(v) for v in values])


def _up_intervals(events: list[dict], kills: list[float]) -> list[tuple[float, float]]:
    """(from, to) unix times a drone's process was up: from each start event to the next stop
    event or SIGKILL (or for ever)."""
    marks = sorted(
        [(e["t"], 1) for e in events if e["event"] == "start"]
        + [(e["t"], 0) for e in events if e["event"] == "stop"]
        + [(t, 0) for t in kills]
    )
    out, since = [], None
    for t, up in marks:
        if up and since is None:
            since = t
        elif not up and since is not None:
            out.append((since, t))
            since = None
    if since is not None:
        out.append((since, np.inf))
    return out


def launch_log(
    world: ScenarioWorld,
    nodes_dir: Path,
    start_unix_s: float,
    events: list[tuple[float, str]],
    kills: dict[int, list[float]] | None = None,
    idle_faults: list[tuple[float, str]] | None = None,
) -> MissionLog:
    """The mission log of a networked run of ``world.sc`` whose drones wrote into
    ``nodes_dir``, step 0 at ``start_unix_s``; ``events`` (s after step 0, what) are launch's
    faults, ``idle_faults`` those that found nothing to do, and ``kills`` the unix times it
    SIGKILLed each drone."""
    sc = world.sc
    n, S, dt = sc.drones, sc.steps + 1, sc.dt_s
    log = world_log(world)
    ins_aligned_in_outages(log, world.drift)
    log.detector_params = dict(world.protocol.detector_params)
    log.events = list(events)
    log.idle_faults = list(idle_faults or [])
    log.in_flight_s = dt  # the step before a fault: its record was on its way when it landed
    log.raft_messages = np.zeros(S, int)
    log.report_messages = np.zeros(S, int)
    step_start = start_unix_s + np.arange(S) * dt
    leader_of_term: dict[int, int] = {}
    first_apply = np.full(S, np.inf)
    for d in range(1, n + 1):
        i = d - 1
        evs = read_jsonl(drone_file(nodes_dir, d, "events.jsonl"))
        for e in evs:
            if e["event"] == "role" and e.get("role") == "leader":
                leader_of_term.setdefault(int(e["term"]), d)
            elif e["event"] == "proposal_refused":
                log.refused_proposals += 1
        for a, b in _up_intervals(evs, (kills or {}).get(d, [])):
            log.alive[:, i] |= (step_start >= a) & (step_start < b)
        recs = []
        for row in read_jsonl(drone_file(nodes_dir, d, "steps.jsonl")):
            k = int(row["step"])
            if not 0 <= k < S:
                continue
            if row.get("reported") is not None:
                log.reported[k, i] = _floats(row["reported"])
            if not row["committed"]:
                continue
            recs.append((k, row["record"]))
            first_apply[k] = min(first_apply[k], row["applied_unix_s"])
            if not log.committed[k]:
                _note_row(log, k, row)
        for k, digest in sorted(recs):
            log.agreement.note(d, k, digest)
        sent = drone_file(nodes_dir, d, "sent.csv")
        if sent.exists():
            with sent.open(newline="") as f:
                for r in csv.DictReader(f):
                    try:
                        k, raft, reports = int(r["step"]), int(r["raft"]), int(r["reports"])
                    except (TypeError, ValueError):  # a torn last line after a SIGKILL
                        continue
                    if 0 <= k < S:
                        log.raft_messages[k] += raft
                        log.report_messages[k] += reports
    log.leader = np.array(
        [leader_of_term.get(int(t), 0) if c else 0 for t, c in zip(log.term, log.committed, strict=True)]
    )
    with np.errstate(invalid="ignore"):
        log.latency_ms = np.where(np.isfinite(first_apply), (first_apply - step_start) * 1000, np.nan)
    log.status = log.status.astype(str)
    if sc.protocol.audit:
        log.audit = audit_summary(nodes_dir, n, start_unix_s)
    return log


def audit_summary(nodes_dir: Path, n: int, start_unix_s: float) -> dict:
    """The audit's counts over a networked run's drones, as the simulator's
    (`sim.mission.Mission.audit_summary`), from their event and step files: the liar is the
    drone told to lie (its ``compromised`` event); refused entries, refused applies and
    censorship findings are the other drones'; ``falsified_applied`` counts the step-file rows of drones
    other than the liar that hold a record the liar falsified (the invariant: 0);
    ``compromised_s``, when the liar was told to lie, and ``other_leader_s``, when a drone
    other than the liar first led after that (the liar replaced).
    Times are seconds after step 0."""
    evs = {d: read_jsonl(drone_file(nodes_dir, d, "events.jsonl")) for d in range(1, n + 1)}
    marks = sorted((e["t"], d) for d in evs for e in evs[d] if e["event"] == "compromised")
    liar = marks[0][1] if marks else None
    lies = [e for e in evs.get(liar, []) if e["event"] == "falsified"]
    falsified = {e["record"] for e in lies}
    honest = [d for d in evs if d != liar]

    def times(kind: str) -> list[float]:
        return sorted(round(e["t"] - start_unix_s, 3) for d in honest for e in evs[d] if e["event"] == kind)

    refusals, findings = times("audit_refused"), times("censorship")
    applied = sum(
        r.get("record") in falsified
        for d in honest
        for r in read_jsonl(drone_file(nodes_dir, d, "steps.jsonl"))
        if r["committed"]
    )
    first_lie = min((e["t"] for e in lies), default=None)
    since = marks[0][0] if marks else None
    led = [e["t"] for d in honest for e in evs[d] if e["event"] == "role" and e.get("role") == "leader"]
    after = [t for t in led if since is not None and t >= since]
    return {
        "refused_entries": len(refusals),
        "refused_applies": len(times("audit_refused_apply")),
        "censorship_findings": len(findings),
        "falsified_proposed": len(lies),
        "falsified_applied": applied,
        "liar": liar,
        "first_lie_s": None if first_lie is None else round(first_lie - start_unix_s, 3),
        "first_refusal_s": refusals[0] if refusals else None,
        "first_finding_s": findings[0] if findings else None,
        "compromised_s": None if since is None else round(since - start_unix_s, 3),
        "other_leader_s": round(min(after) - start_unix_s, 3) if after else None,
    }


def _note_row(log: MissionLog, k: int, row: dict) -> None:
    """Step k of ``log`` takes the record a drone's step-file row holds."""
    n = log.scenario.drones
    log.committed[k] = True
    log.status[k] = row["status"]
    log.term[k] = int(row["term"])
    log.verified[k] = np.array([_floats(p) for p in row["positions"]])
    log.hpl[k], log.vpl[k] = _levels(row.get("hpl"), n), _levels(row.get("vpl"), n)
    for f in row["faulty"]:
        log.faulty[k, f - 1] = True
    for m in row["missing"]:
        log.missing[k, m - 1] = True


class LaunchTail:
    """A networked run's mission log while it runs, for the live view: each `poll` reads the
    lines the drones have appended to their step files since the last one (a torn last line
    waits for the next poll) and their event files, and fills what `launch_log` fills from
    them (reports, records, leaders, latency, which processes are up). ``events`` (s after
    step 0, what) is launch's list of faults, shared as it grows; ``kills`` gives the unix
    times launch SIGKILLed each drone."""

    def __init__(
        self,
        world: ScenarioWorld,
        nodes_dir: Path,
        start_unix_s: float,
        events: list[tuple[float, str]],
        kills: dict[int, list[float]],
    ) -> None:
        sc = world.sc
        self.n, self.S = sc.drones, sc.steps + 1
        self.nodes_dir, self.kills = Path(nodes_dir), kills
        self.log = world_log(world)
        self.log.events = events
        self.step_start = start_unix_s + np.arange(self.S) * sc.dt_s
        self._offsets = dict.fromkeys(range(1, self.n + 1), 0)
        self._leader_of_term: dict[int, int] = {}

    def poll(self) -> None:
        log = self.log
        for d in range(1, self.n + 1):
            i = d - 1
            evs = read_jsonl(drone_file(self.nodes_dir, d, "events.jsonl"))
            for e in evs:
                if e["event"] == "role" and e.get("role") == "leader":
                    self._leader_of_term.setdefault(int(e["term"]), d)
            log.alive[:, i] = False
            for a, b in _up_intervals(evs, self.kills.get(d, [])):
                log.alive[:, i] |= (self.step_start >= a) & (self.step_start < b)
            for row in self._new_rows(d):
                k = int(row["step"])
                if not 0 <= k < self.S:
                    continue
                if row.get("reported") is not None:
                    log.reported[k, i] = _floats(row["reported"])
                if not row["committed"]:
                    continue
                lat = (row["applied_unix_s"] - self.step_start[k]) * 1000
                if not np.isfinite(log.latency_ms[k]) or lat < log.latency_ms[k]:
                    log.latency_ms[k] = lat
                if not log.committed[k]:
                    _note_row(log, k, row)
        for k in np.flatnonzero(log.committed & (log.leader == 0)):
            log.leader[k] = self._leader_of_term.get(int(log.term[k]), 0)

    def _new_rows(self, drone: int) -> list[dict]:
        """The complete lines appended to the drone's step file since the last call."""
        path = drone_file(self.nodes_dir, drone, "steps.jsonl")
        try:
            with path.open("rb") as f:
                f.seek(self._offsets[drone])
                data = f.read()
        except FileNotFoundError:
            return []
        end = data.rfind(b"\n") + 1
        self._offsets[drone] += end
        rows = []
        for line in data[:end].splitlines():
            try:
                rows.append(json.loads(line))
            except ValueError:
                continue
        return rows
