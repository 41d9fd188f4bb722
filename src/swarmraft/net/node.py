"""One drone of a networked swarm: an asyncio host that drives one `raft.RaftNode` and one
`protocol.SwarmDrone`, unchanged, from the wall clock and UDP datagrams, in the simulator's
driving order (`sim.runtime`, `sim.mission`):

- every ``tick_ms``: ``node.tick()``; for each datagram the `Verifier` accepts, ``node.step``
  (a Raft message) or ``drone.receive`` (a report, on the leader); hostile datagrams are
  dropped and counted, never raised;
- then every Ready in order: persist hard state and entries to the drone's `SQLiteStorage`
  (in a worker thread; the node is not touched until the write returns, so nothing that
  depends on it is sent before), send the messages, apply the committed entries, ``advance``;
- every step k (at ``start_unix_s + k * step_s``): the drone's report from its sensor source
  (`net.sources`: by default the scenario's world, `sim.sensing.ScenarioWorld`, the same draws
  every process makes from the swarm file; or a recorded log, or MAVLink) to the leader it
  knows (no report when the source has no reading); the leader acknowledges it; a resend at
  half the deadline if no acknowledgement came or the leader changed; the leader verifies at
  the deadline (or once every recent drone reported) and proposes the record. The
  verification runs in a worker thread (the detector takes tens of ms); the drone is not
  touched until it returns (reports wait, committed entries queue), while Raft goes on;
- every applied step is one JSON line (flushed) in ``drone-<id>.steps.jsonl``; starts, role
  changes and the final counters go to ``drone-<id>.events.jsonl``.

SIGTERM and SIGINT stop it cleanly: the write in flight finishes (nothing persisted or
committed is lost), the files are flushed and closed, the socket and the database closed.
"""

from __future__ import annotations

import asyncio
import datetime
import hashlib
import json
import logging
import os
import random
import signal
import sqlite3
import time
import tomllib
from collections import Counter, deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from nacl.signing import SigningKey, VerifyKey
from pydantic import ValidationError

from swarmraft.estimation.blas import pin_one_blas_thread
from swarmraft.estimation.bounds import gnss_covariance
from swarmraft.estimation.joint import trusted_estimate
from swarmraft.estimation.registry import one_line
from swarmraft.net import wire
from swarmraft.net.auth import Accepted, Signer, Verifier, public_key
from swarmraft.net.keys import KeyFileError, load_private_key, load_public_keys
from swarmraft.net.sources import SourceError, open_source
from swarmraft.net.status import ReplyLimit, encode_reply
from swarmraft.net.swarmfile import SwarmFile, drone_file, load_swarm
from swarmraft.net.transport import Address, UDPTransport
from swarmraft.protocol import Keyring, Report, StepRecord, SwarmDrone
from swarmraft.protocol.audit import KEEP_STEPS
from swarmraft.protocol.drift import realigns
from swarmraft.protocol.drone import Applied
from swarmraft.protocol.memo import BoundedMemo, record_digest
from swarmraft.provenance import source_sha256
from swarmraft.raft import (
    Entry,
    EntryKind,
    Message,
    MsgType,
    NotLeader,
    ProposalDropped,
    RaftConfig,
    RaftNode,
    Role,
    Snapshot,
    SQLiteStorage,
)
from swarmraft.sim.lying import drops_report, falsify, move_offset
from swarmraft.sim.mission import MISSION_SNAPSHOTS
from swarmraft.sim.scenario import Scenario, find_scenario, shipped_scenarios
from swarmraft.sim.sensing import ScenarioWorld

_logger = logging.getLogger(__name__)
#: a step 0 further ahead than this is said when the node comes up (a start time given in
#: milliseconds waits for 55,000 years)
FAR_AHEAD_S = 86400.0

#: The wall clock and the loop's clock parting by more than this (s) reschedules the steps.
CLOCK_JUMP_S = 0.5

#: After the last step's deadline, a node keeps running this long so the last records commit.
END_GRACE_S = 1.5
#: Records older than this many steps when applied do not realign the INS (replayed after a restart).
REALIGN_STEPS = 5
#: A drone remembers what it reported this many steps back, for its step file.
REPORTED_KEPT = 100
#: Appends held for their audit at most (`_preaudit`); more are dropped as if lost (Raft sends
#: again what is not acknowledged). Audits slower than the steps would otherwise grow the
#: queue for as long as a run lasts.
HELD_APPS = 64


class NodeConfigError(ValueError):
    """The swarm file, scenario or keys do not fit this drone; one line."""


def load_node_scenario(swarm: SwarmFile) -> Scenario:
    """The swarm's scenario with its seed and step overrides; one-line NodeConfigError if bad."""
    path = find_scenario(swarm.scenario)
    if not path.is_file():
        if swarm.scenario.endswith(".toml"):  # a file, never a shipped name: the list is beside the point
            raise NodeConfigError(f"scenario: no file {path} (the swarm file's scenario)")
        raise NodeConfigError(
            f"scenario: no file {path} and no shipped scenario of that name "
            f"(shipped: {', '.join(shipped_scenarios())})"
        )
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise NodeConfigError(f"scenario {path}: unreadable or not TOML ({exc})") from None
    if swarm.seed is not None:
        data["seed"] = swarm.seed
    if swarm.step_s is not None:
        data["dt_s"] = swarm.step_s
    data.setdefault("raft", {})["tick_ms"] = swarm.tick_ms
    try:
        sc = Scenario(**data)
    except ValidationError as exc:
        said = one_line(exc, "", Scenario)
        if swarm.step_s is not None and said.startswith("dt_s:"):  # the swarm file's step_s set it
            raise NodeConfigError(f"step_s: {said.removeprefix('dt_s:').strip()}") from None
        raise NodeConfigError(f"scenario {path.name}: {said}") from None
    if sc.drones != len(swarm.drones):
        raise NodeConfigError(
            f"scenario {path.name}: {sc.drones} drones, the swarm file lists {len(swarm.drones)}"
        )
    if why := step_too_short(sc.dt_s, swarm.tick_ms):
        what = "step_s" if swarm.step_s is not None else f"scenario {path.name}: dt_s"
        raise NodeConfigError(f"{what}: {why}")
    end = swarm.start_unix_s + sc.steps * sc.dt_s
    if end < time.time():
        raise NodeConfigError(
            f"start_unix_s: step 0 was at {swarm.start_unix_s:.0f} ({_utc(swarm.start_unix_s)}), so the "
            f"scenario's {sc.duration_s:g} s ended {time.time() - end:.0f} s ago: nothing left to fly "
            "(give a start_unix_s ahead of now)"
        )
    return sc


def step_too_short(dt_s: float, tick_ms: float) -> str | None:
    """Why a step of ``dt_s`` cannot run on a Raft tick of ``tick_ms`` (None: it can). A step
    shorter than a tick is not driven at all: a step of 1 ms on the 10 ms tick sent 36,000
    reports in 12 s and applied nothing. (A step shorter than the leader's wait for reports
    works: each step's timers run on their own; 20 Hz committed 75 of 101 steps.)"""
    if dt_s * 1000 >= tick_ms:
        return None
    return (
        f"a step of {dt_s * 1000:g} ms is shorter than the Raft tick ({tick_ms:g} ms): "
        f"give at least {tick_ms / 1000:g} s"
    )


def _utc(unix_s: float) -> str:
    """A Unix time as UTC text, or what it is if no date can show it."""
    try:
        return datetime.datetime.fromtimestamp(unix_s, datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    except (OverflowError, OSError, ValueError):
        return "beyond any date"


def entries_per_append(n: int) -> int:
    """How many records of an n-drone swarm fit one MsgApp datagram (at most 64): a MsgApp
    must fit `wire.MAX_PAYLOAD`. A record carries its n signed reports (docs/audit.md)."""
    z = np.zeros(n)
    report = Report(0, 0, np.zeros(3), "gnss", z, np.zeros(3), bytes(64))
    rec = StepRecord(
        0,
        0,
        np.zeros((n, 3)),
        z > 0,
        z > 0,
        "unidentifiable",
        "x" * 32,
        "0" * 32,
        z,
        z,
        prior_step=0,
        prior_positions=np.zeros((n, 3)),
        prior_faulty=z > 0,
        reports=(report,) * n,
        signature=bytes(64),
    )
    per_entry = len(rec.encode()) + 21 + 64 + 256  # entry header, room for names and parameters
    return max(1, min(64, (wire.MAX_PAYLOAD - 54) // per_entry))


def warm_up_detector(world: ScenarioWorld) -> list[StepRecord]:
    """Run the detector on two steps with a throwaway drone and keys, the second with one
    report moved 40 m so that a drone is flagged: the first call takes 0.5 s (2 s on a busy
    machine: lazy imports and first-time setup) and the first step with a flagged drone 20 ms
    more than the next (the rival search, the re-inclusion and their compiled kernels load on
    first use). A newly elected leader, and every voter auditing its record, must not pay
    that inside a step: nine processes paying it at once at a spoof's onset skipped steps.
    Returns the two records."""
    n = world.sc.drones
    records = []
    keys = Keyring.generate(n, np.random.default_rng(0))
    drone = SwarmDrone(0, world.protocol, keys)
    for step in (0, 1):
        ins = world.ins_estimate(step, np.zeros(n), world.traj.positions[0])
        ranges = world.measured_ranges(step, ins)
        fix = world.fix[step].copy()
        if step == 1:
            fix[n // 2, 0] += 40.0
        for i in range(n):
            drone.receive(keys.sign(Report(step, i, fix[i], "gnss", ranges[i], None)))
        record = drone.verify_step(step, 0)
        if record is not None:
            drone.apply(drone.seal(record))
            records.append(record)
    # a record's re-estimate with a decided trusted set (a drone gated or missing) runs the
    # Levenberg-Marquardt kernel whatever the detector: under `paper`, which never loads it,
    # the first such step loaded it, or on a cold cache compiled it (43 s in one drone, the
    # swarm stalled behind it), inside the step
    c = world.protocol
    at = world.traj.positions[0][None]
    apart = np.linalg.norm(at[:, :, None] - at[:, None], axis=3)
    trusted = np.arange(n)[None] > 0
    # (exact data, sigma 0, has no information matrix: the warm-up only loads the code, so a
    # floor of 1 mm stands in for it)
    trusted_estimate(
        at,
        apart,
        trusted,
        gnss_covariance(*(max(s, 1e-3) for s in c.gnss_sigma)),
        max(c.range_sigma, 1e-3),
        x0=at,
        prior=at,
        prior_sigma=c.prior_sigma,
    )
    return records


def record_hash(data: bytes) -> str:
    """A committed record's identity across nodes: its bytes' SHA-256 (first 16 hex digits)."""
    return hashlib.sha256(data).hexdigest()[:16]


def _ids(mask: np.ndarray) -> list[int]:
    return [int(i) + 1 for i in np.flatnonzero(mask)]


def _jsonable(x: np.ndarray) -> list:
    return [[None if not np.isfinite(v) else round(float(v), 4) for v in row] for row in np.atleast_2d(x)]


def _levels(x: np.ndarray | None) -> list | None:
    """Protection levels for JSON: null where none (nan), "inf" where not protected."""
    if x is None:
        return None
    return ["inf" if np.isposinf(v) else None if not np.isfinite(v) else round(float(v), 4) for v in x]


#: The stop event's counter of what was sent, by the type sent.
_NOT_DROPS = ("accepted", "pieces")  # the verifier's counters that are not drops
_SENT_COUNTER = {Message: "sent_raft", Report: "sent_reports", wire.ReportAck: "sent_acks"}


class DroneHost:
    """Drone ``drone_id`` of ``swarm``; ``await run()`` until the scenario ends or a stop."""

    def __init__(self, swarm: SwarmFile, drone_id: int) -> None:
        if drone_id not in swarm.drones:
            raise NodeConfigError(f"--id: no drone {drone_id} in the swarm file (ids 1..{len(swarm.drones)})")
        if swarm.code_sha256 is not None and swarm.code_sha256 != source_sha256():
            raise NodeConfigError(
                f"the swarm file names swarmraft code {swarm.code_sha256[:12]}, this program is "
                f"{source_sha256()[:12]}: every drone must run the same code (a voter re-runs "
                "its leader's verification, and another version's records would be refused as "
                "lies); install that code here, or write the swarm file again with this one "
                "(or remove its code_sha256 line to fly mixed code unchecked)"
            )
        self.swarm, self.id, self.index = swarm, drone_id, drone_id - 1
        self.entry = swarm.drones[drone_id]
        self.sc = load_node_scenario(swarm)
        try:
            seed = load_private_key(self.entry.key)
            publics = load_public_keys(swarm.public_keys)
        except KeyFileError as exc:
            raise NodeConfigError(str(exc)) from None
        if publics.get(drone_id) != public_key(seed):
            raise NodeConfigError(
                f"{self.entry.key}: not the key {swarm.public_keys} lists for drone {drone_id}"
            )
        if missing := sorted(set(swarm.drones) - set(publics)):
            raise NodeConfigError(f"{swarm.public_keys}: no public key for drone {missing[0]}")
        self.seed = seed
        self.publics = publics
        self.peers = swarm.peers(drone_id)
        self.out = Path(swarm.out)
        if self.out.exists() and not self.out.is_dir():
            raise NodeConfigError(f"out: {self.out} is a file, not a folder (the swarm file's out)")
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # one line naming the field, not "[Errno 2] ... '/proc/nope'"
            raise NodeConfigError(
                f"out: cannot create {self.out} ({exc.strerror or exc}; the swarm file's out)"
            ) from None
        self.world = ScenarioWorld.build(self.sc)
        n = self.sc.drones
        keyring = Keyring(
            {self.index: SigningKey(seed)}, {i - 1: VerifyKey(publics[i]) for i in swarm.drones}
        )
        pc = self.sc.protocol
        # the audit (docs/audit.md), as the simulator's drones run it: this drone checks every
        # record before its Raft node takes it (the node's validator) or applies it
        # (the audit's evidence checks are computed ahead, beside the node: `_preaudit`)
        self.drone = SwarmDrone(
            self.index,
            self.world.protocol,
            keyring,
            audit=pc.audit,
            censor=(pc.censor_k, pc.censor_m),
            recompute_cache=BoundedMemo(4 * KEEP_STEPS) if pc.audit else None,
        )
        # the lying-leader fault: this drone lies from a SIGUSR1 on (`compromise`)
        self._lie = next((f for f in self.sc.fault if f.kind == "lying-leader"), None)
        self._lying = False
        self.raft_config = RaftConfig(
            id=drone_id,
            peers=tuple(i for i in sorted(swarm.drones) if i != drone_id),
            election_tick=self.sc.raft.election_tick,
            heartbeat_tick=self.sc.raft.heartbeat_tick,
            max_entries_per_msg=entries_per_append(n),
        )
        warm_up_detector(self.world)
        # readings, and the INS aligned to each fresh verified position
        try:
            self.source = open_source(swarm, drone_id, self.world)
        except SourceError as exc:
            raise NodeConfigError(str(exc)) from None
        self.counters: Counter[str] = Counter()
        self._pending: list[Callable[[], None]] = []
        self._wake: asyncio.Event | None = None
        self._stopping = False
        self._sent_to: dict[int, int | None] = {}
        self._timers: list[asyncio.TimerHandle] = []
        self._step_timers: list[asyncio.TimerHandle] = []  # the steps', rescheduled on a clock jump
        self._clock_offset = 0.0
        self._role: tuple[str, int] | None = None
        self._written: dict[int, str] = {}  # step -> record hash already in the step file
        self._verifying: asyncio.Future | None = None  # the leader's verification in its thread
        # appends held until the audit thread has checked their records' evidence (`_preaudit`)
        self._held_apps: deque[Message] = deque()
        self._preauditing = False
        self._backlog: list[Report] = []  # reports that arrived meanwhile
        self._decide_later: list[int] = []
        self._reported: dict[int, list] = {}  # step -> the position this drone reported
        self._reports: dict[int, Report | None] = {}  # step -> its report, kept 2 steps for resends
        self._heard: dict[int, float] = {}  # peer -> monotonic time of its last accepted datagram
        self._acked: set[int] = set()  # steps whose report the leader acknowledged
        # committed entries (and a leader's snapshot to restore), waiting for the drone to be free
        self._to_apply: deque[Entry | Snapshot] = deque()
        self._apply_audit: asyncio.Future | None = None  # the audit a committed record waits for
        self._apply_tried = -1  # the log index of the last record audited for its apply
        self.snapshots = MISSION_SNAPSHOTS  # as in the simulator: every 1000 entries, keeping 500
        self._applied_index = 0  # the last log index the drone's state holds
        self._snap_index = 0  # the index of the stored snapshot
        self._reply_limit = ReplyLimit()
        self._up_since = time.monotonic()

    # -- files ------------------------------------------------------------------------------
    @property
    def storage_path(self) -> Path:
        return drone_file(self.out, self.id, "sqlite")

    @property
    def steps_path(self) -> Path:
        return drone_file(self.out, self.id, "steps.jsonl")

    @property
    def events_path(self) -> Path:
        return drone_file(self.out, self.id, "events.jsonl")

    @property
    def sent_path(self) -> Path:
        return drone_file(self.out, self.id, "sent.csv")

    def _read_written_steps(self) -> None:
        """Steps already in the step file (from before a restart); a torn last line is cut."""
        if not self.steps_path.exists():
            return
        good = 0
        with self.steps_path.open("rb") as f:
            for line in f:
                try:
                    row = json.loads(line)
                except ValueError:
                    break
                if not line.endswith(b"\n"):
                    break
                self._written[row["step"]] = row.get("record") or ""
                good += len(line)
        with self.steps_path.open("r+b") as f:
            f.truncate(good)

    def _event(self, event: str, **fields: Any) -> None:
        self._events.write(json.dumps({"t": round(time.time(), 4), "event": event, **fields}) + "\n")
        self._events.flush()

    def _write_step(self, row: dict[str, Any]) -> None:
        step = row["step"]
        if step in self._written:
            if self._written[step] != (row.get("record") or ""):
                self.counters["replayed_record_differs"] += 1
                _logger.error("step %d: the record applied again differs from the one written before", step)
            return
        self._written[step] = row.get("record") or ""
        self._steps.write(json.dumps(row) + "\n")
        self._steps.flush()

    # -- running ----------------------------------------------------------------------------
    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        # the loop, verify and audit threads all verify: BLAS on one thread for good (a
        # context in another thread cannot set it once this one has restored it: `blas`)
        pin_one_blas_thread()
        self.out.mkdir(parents=True, exist_ok=True)
        self._wake = asyncio.Event()
        self.transport = await UDPTransport.bind(*self.entry.bind_address, self._on_datagram)
        self._disk = ThreadPoolExecutor(1, thread_name_prefix=f"drone-{self.id}-disk")
        self._cpu = ThreadPoolExecutor(1, thread_name_prefix=f"drone-{self.id}-verify")
        self._audit_pool = ThreadPoolExecutor(1, thread_name_prefix=f"drone-{self.id}-audit")
        self._loop = loop
        try:
            self.storage = SQLiteStorage(self.storage_path, check_same_thread=False)
        except sqlite3.DatabaseError as exc:  # a file of something else, or damaged
            raise NodeConfigError(f"{self.storage_path}: not a drone's Raft database ({exc})") from None
        self._read_written_steps()
        self._steps = self.steps_path.open("a")
        self._events = self.events_path.open("a")
        new_sent = not self.sent_path.exists()
        self._sent_file = self.sent_path.open("a")
        if new_sent:
            self._sent_file.write("step,raft,reports\n")
        self._sent_mark = (0, 0)
        self._stopped = loop.create_future()
        try:
            hs = self.storage.initial_state()
            # the drone's state from the stored snapshot; the node applies the tail after it
            if (snap := self.storage.snapshot()).index:
                self._restore(snap)
            self.node = RaftNode(
                self.raft_config,
                self.storage,
                random.Random(int.from_bytes(os.urandom(8))),
                validate=self._validate if self.drone.audit is not None else None,
                validate_snapshot=self._validate_snapshot if self.drone.audit is not None else None,
            )
            if self.drone.audit is not None:
                # the records this drone held as priors before a restart: its own log, every
                # entry of which it validated before persisting (a prior not held is refused)
                st = self.storage
                for e in st.entries(st.first_index(), st.last_index() + 1):
                    if e.kind == EntryKind.NORMAL:
                        self.drone.audit.remember(e.data)
            # Above every sequence number an earlier run sent: microseconds of the wall clock
            # (a run sends a few hundred datagrams a second, far fewer than a million).
            self.signer = Signer(self.id, self.seed, first_seq=time.time_ns() // 1000)
            self.verifier = Verifier(self.publics, own_id=self.id)
            self._event(
                "start",
                pid=os.getpid(),
                term=hs.term,
                vote=hs.vote,
                commit=hs.commit,
                last_index=self.storage.last_index(),
                first_seq=self.signer.next_seq,
                address=list(self.transport.local_address),
            )
            _logger.info(
                "drone %d up on %s:%d: term %d, log of %d entries, commit %d",
                self.id,
                *self.transport.local_address,
                hs.term,
                self.storage.last_index(),
                hs.commit,
            )
            ahead = self.swarm.start_unix_s - time.time()
            if ahead > FAR_AHEAD_S:  # said whatever -v says: the node would wait in silence
                _logger.warning(
                    "drone %d: step 0 is %.1f days from now (start_unix_s %.0f, %s; seconds since 1970, "
                    "not milliseconds)",
                    self.id,
                    ahead / 86400,
                    self.swarm.start_unix_s,
                    _utc(self.swarm.start_unix_s),
                )
            for sig in (signal.SIGTERM, signal.SIGINT):
                loop.add_signal_handler(sig, self.stop, sig.name)
            loop.add_signal_handler(signal.SIGUSR1, self.compromise)
            driver = asyncio.create_task(self._drive())
            driver.add_done_callback(lambda t: t.cancelled() or t.exception() is None or self.stop("error"))
            self._schedule_ticks(loop)
            self._schedule_steps(loop)
            self._usage_at_step_0: dict[str, Any] | None = None  # for the stop event
            at = self._loop_time_of(self.swarm.start_unix_s)
            self._timers.append(loop.call_at(at, lambda: setattr(self, "_usage_at_step_0", self._usage())))
            self._wake.set()
            await self._stopped
            self._stopping = True
            self._tick.cancel()
            for t in self._timers + self._step_timers:
                t.cancel()
            self._wake.set()
            await driver  # the write in flight, and what it releases, completes
            if self._verifying is not None:
                await asyncio.wait([self._verifying])  # its callback applies what waited
            if self._apply_audit is not None:
                await asyncio.wait([self._apply_audit])
            self._apply_queued()  # what is left, checked here (the node has stopped)
        finally:
            for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1):
                loop.remove_signal_handler(sig)
            self.transport.close()
            await self.transport.wait_closed()
            self._disk.shutdown(wait=True)
            self._cpu.shutdown(wait=True)
            self._audit_pool.shutdown(wait=True)
            self._finish_event()
            if (k := getattr(self, "_begun", None)) is not None and k < self.sc.steps:
                self._count_sent(k + 1)  # stopped mid-run: the datagrams of the step in progress
            self._steps.close()
            self._events.close()
            self._sent_file.close()
            self.storage.close()
            self.source.close()
        return 0

    def _finish_event(self) -> None:
        node = getattr(self, "node", None)
        st = node.status if node is not None else None
        self._event(
            "stop",
            reason=self._stop_reason if hasattr(self, "_stop_reason") else "error",
            term=st.term if st else None,
            commit=st.commit if st else None,
            last_index=st.last_index if st else None,
            last_step=self.drone.state.last_step,
            verifier={k: v for k, v in self.verifier.counters.items() if v}
            if hasattr(self, "verifier")
            else {},
            reports_rejected=self.drone.rejected,
            audit=self.audit_counts(),
            counters=dict(self.counters),
            **self._usage(),
            at_step_0=getattr(self, "_usage_at_step_0", None),
        )

    def _usage(self) -> dict[str, Any]:
        """What this process has used so far: CPU seconds (all threads, since it started) and
        the transport's datagrams and bytes, at a wall-clock time."""
        t = self.transport
        return {
            "unix_s": round(time.time(), 4),
            "cpu_s": round(time.process_time(), 4),
            "transport": {
                "sent": t.sent,
                "received": t.received,
                "bytes_sent": t.bytes_sent,
                "bytes_received": t.bytes_received,
            },
        }

    def stop(self, reason: str = "stop") -> None:
        """Stop at the next turn of the loop (safe from a signal handler)."""
        if not self._stopped.done():
            self._stop_reason = reason
            _logger.info("drone %d stopping (%s)", self.id, reason)
            self._stopped.set_result(None)

    def _push(self, action: Callable[[], None]) -> None:
        self._pending.append(action)
        assert self._wake is not None
        self._wake.set()

    async def _drive(self) -> None:
        """Apply queued ticks, messages and proposals to the node, then handle its Readies:
        persist (awaiting the disk thread; meanwhile new events only queue), send, apply,
        advance. The simulator's order (`sim.runtime.Cluster._process`)."""
        loop = asyncio.get_running_loop()
        node, storage = self.node, self.storage
        assert self._wake is not None
        while True:
            await self._wake.wait()
            self._wake.clear()
            # once stopping, the Ready in hand is finished (persisted, sent, applied) and no other begun
            while (self._pending or node.has_ready()) and not self._stopping:
                pending, self._pending = self._pending, []
                for action in pending:
                    try:
                        action()
                    except Exception:
                        self.counters["internal_error"] += 1
                        _logger.exception("drone %d: a node event failed", self.id)
                while (rd := node.ready()) is not None:
                    if rd.hard_state is not None or rd.entries or rd.snapshot is not None:
                        t0 = time.perf_counter()
                        await loop.run_in_executor(
                            self._disk, storage.save, rd.hard_state, rd.entries, rd.snapshot
                        )
                        self._time("save", t0)
                    for m in rd.messages:
                        self._send_raft(m)
                    # Committed entries go to the drone in log order, but not while it is
                    # verifying in its thread: they wait in a queue, and Raft goes on (a
                    # leader that waited here would send no heartbeats for as long as a
                    # verification takes, up to a second on a loaded machine, and lose its
                    # followers to an election).
                    if rd.snapshot is not None:
                        self._to_apply.append(rd.snapshot)
                    self._to_apply.extend(rd.committed)
                    self._apply_queued()
                    node.advance(rd)
                    plan = self.snapshots.plan(self._applied_index, self._snap_index, storage.first_index())
                    if plan is not None:  # on the disk thread, between saves
                        self._snap_index = plan[0]
                        t0 = time.perf_counter()
                        await loop.run_in_executor(
                            self._disk,
                            storage.create_snapshot,
                            plan[0],
                            self.drone.snapshot(),
                            plan[1],
                            node.conf_state_at(plan[0]),
                        )
                        self._time("snapshot", t0)
                self._note_role()
            if self._stopping:
                return

    def _apply_queued(self) -> None:
        """Apply the committed entries waiting in the queue, unless the drone is verifying.
        A record this drone has not audited yet (a learner's, or a voter's log replayed after
        a restart: up to a thousand records, tens of ms each) waits while the audit thread
        computes its checks, then is applied from them: before, those re-runs ran here, on
        the loop, and a restarted voter answered nothing for seconds. Once the node stops,
        what is left is applied here, checks and all."""
        self._audit_clock()  # a learner audits at apply
        while self._to_apply and self._verifying is None and self._apply_audit is None:
            item = self._to_apply[0]
            if not self._stopping and self._unaudited(item):
                # once per record: one whose checks the thread could not compute (undecodable)
                # is checked at apply, here
                self._apply_tried = item.index
                self.counters["audited_at_apply"] += 1
                self._apply_audit = self._loop.run_in_executor(
                    self._audit_pool, self._evidence_ahead, [item.data]
                )
                self._apply_audit.add_done_callback(self._audited_for_apply)
                return
            self._apply(self._to_apply.popleft())

    def _unaudited(self, item: Entry | Snapshot) -> bool:
        """A record whose checks are neither passed nor computed yet (`_apply_queued`)."""
        audit = self.drone.audit
        return (
            audit is not None
            and isinstance(item, Entry)
            and item.index != self._apply_tried
            and item.kind == EntryKind.NORMAL
            and not audit.passed(item.data)
            and record_digest(item.data) not in audit.cache
        )

    def _audited_for_apply(self, fut: asyncio.Future) -> None:
        self._apply_audit = None
        self._audit_failed(fut)  # the apply then checks it again (and refuses it if it raises)
        if not self._stopping:
            self._apply_queued()

    def _audit_failed(self, fut: asyncio.Future) -> None:
        """An audit-thread job that did not finish (cancelled, or raised) is counted and logged."""
        if fut.cancelled():
            self.counters["preaudit_failed"] += 1
        elif (exc := fut.exception()) is not None:
            self.counters["preaudit_failed"] += 1
            _logger.error("drone %d: an audit failed", self.id, exc_info=exc)

    def _note_role(self) -> None:
        now = (str(self.node.role), self.node.term)
        if now != self._role:
            self._role = now
            self._event("role", role=now[0], term=now[1], leader=self.node.lead)
            lead = f", leader {self.node.lead}" if self.node.lead else ""
            _logger.info("drone %d is %s in term %d%s", self.id, now[0], now[1], lead)

    # -- network ----------------------------------------------------------------------------
    def _send(self, to: int, obj: Message | Report | wire.ReportAck, counter: str | None = None) -> None:
        """``counter``: what the send counts as (default: by the type sent)."""
        addr = self.peers.get(to)
        if addr is None:
            self.counters["no_address"] += 1
            return
        self.counters[counter or _SENT_COUNTER[type(obj)]] += 1
        try:
            datagrams = self.signer.seal_all(obj)
        except wire.WireError as exc:
            self.counters["unsendable"] += 1
            _logger.warning("drone %d: cannot send to %d: %s", self.id, to, exc)
            return
        if len(datagrams) > 1:
            self.counters["sent_in_pieces"] += 1
        for data in datagrams:
            self.transport.send(addr, data)

    def _send_raft(self, m: Message) -> None:
        self._send(m.to, m)

    def _on_datagram(self, data: bytes, addr: Address) -> None:
        if (nonce := wire.status_request_nonce(data)) is not None:
            self._answer_status(nonce, addr)
            return
        got = self.verifier.check(data, addr)
        if not isinstance(got, Accepted):
            return
        self._heard[got.sender] = time.monotonic()
        if isinstance(got.message, Message):
            m = got.message
            if m.type in (MsgType.APP, MsgType.SNAP):
                self._audit_clock()
            if m.type in (MsgType.APP, MsgType.SNAP) and (self._held_apps or self._audits(m)):
                if len(self._held_apps) >= HELD_APPS:
                    # audits slower than the leader sends: dropped as if lost (Raft sends
                    # again what is not acknowledged)
                    self.counters["held_apps_dropped"] += 1
                    return
                self._held_apps.append(m)
                self._preaudit()
            else:
                self._push(lambda: self.node.step(m))
        elif isinstance(got.message, wire.ReportAck):
            self._acked.add(got.message.step)
        else:
            self._on_report(got.message)

    # -- status -----------------------------------------------------------------------------
    def status_fields(self) -> dict[str, Any]:
        """What `swarmraft status` shows of this drone (net.status): Raft state, steps, whom
        it heard from lately, the leader's view of each follower, the datagrams dropped."""
        st, node = self.node.status, self.node
        now = time.monotonic()
        # a peer counts as reachable if heard within the longest election timeout
        window_s = 2 * self.raft_config.election_tick * self.swarm.tick_ms / 1000
        peers = {}
        for p in self.raft_config.peers:
            age = now - self._heard[p] if p in self._heard else None
            entry: dict[str, Any] = {"heard_ms": None if age is None else round(age * 1000)}
            pr = node.prs.get(p) if node.role == Role.LEADER else None
            if pr is not None:
                entry.update(match=pr.match, next=pr.next, state="probe" if pr.probe else "replicate")
            peers[str(p)] = entry
        ages = [e["heard_ms"] for e in peers.values() if e["heard_ms"] is not None]
        reachable = sum(age <= window_s * 1000 for age in ages)
        n = len(self.swarm.drones)
        return {
            "drone": self.id,
            "pid": os.getpid(),
            "uptime_s": round(now - self._up_since, 1),
            "role": str(st.role),
            "term": st.term,
            "leader": st.leader,
            "commit": st.commit,
            "applied": st.applied,
            "last_index": st.last_index,
            "last_step": self.drone.state.last_step,
            "step_now": int((time.time() - self.swarm.start_unix_s) // self.sc.dt_s),
            "steps": self.sc.steps,
            "reachable_peers": reachable,
            "quorum": self._has_quorum(reachable, n, window_s),
            "peers": peers,
            "dropped": {k: v for k, v in self.verifier.counters.items() if v and k not in _NOT_DROPS},
            "accepted": self.verifier.counters.get("accepted", 0),
            "audit": self.audit_counts(),
        }

    def audit_counts(self) -> dict[str, Any] | None:
        """The audit's counts (None when the swarm does not audit): records refused at append
        and at apply, censorship findings, priors that could not be checked, falsified records
        this drone proposed (a lying-leader fault), and whether it lies."""
        audit = self.drone.audit
        if audit is None:
            return None
        return {
            "refused_entries": self.counters["audit_refused"],
            "refused_applies": self.drone.refused_applies,
            "censorship_findings": self.counters["censorship_findings"],
            "falsified_proposed": self.counters["falsified_proposed"],
            "lying": self._lying,
        }

    def _has_quorum(self, reachable: int, n: int, window_s: float) -> bool:
        """A leader: it and the peers it heard within ``window_s`` make a majority (as
        CheckQuorum counts). A follower: it heard its leader within ``window_s``."""
        if self.node.role == Role.LEADER:
            return reachable + 1 >= n // 2 + 1
        lead = self.node.lead
        heard = self._heard.get(lead) if lead is not None else None
        return heard is not None and time.monotonic() - heard <= window_s

    def _answer_status(self, nonce: int, addr: Address) -> None:
        if not self._reply_limit.allow():
            self.counters["status_refused"] += 1
            return
        self.counters["status_answered"] += 1
        try:
            payload = encode_reply({"nonce": nonce, **self.status_fields()})
            self.transport.send(addr, self.signer.seal_payload(wire.Kind.STATUS_REPLY, payload))
        except Exception:
            self.counters["internal_error"] += 1
            _logger.exception("drone %d: status answer failed", self.id)

    # -- steps ------------------------------------------------------------------------------
    def _loop_time_of(self, unix_s: float) -> float:
        return asyncio.get_running_loop().time() + (unix_s - time.time())

    def _schedule_ticks(self, loop: asyncio.AbstractEventLoop) -> None:
        period = self.swarm.tick_ms / 1000
        due = loop.time() + period

        def tick() -> None:
            nonlocal due
            self._push(self.node.tick)
            due += period
            now = loop.time()
            if due < now - 5 * period:  # the loop stalled: do not burst the missed ticks
                self.counters["ticks_late"] += 1
                due = now + period
            self._tick = loop.call_at(due, tick)

        self._tick = loop.call_at(due, tick)

    def _schedule_steps(self, loop: asyncio.AbstractEventLoop) -> None:
        """Every step's timers from the wall clock's step k onward, on the loop's clock, and the
        offset between the two clocks they assume (`_clock_moved`)."""
        sc = self.sc
        dt = sc.dt_s
        self._clock_offset = time.time() - loop.time()
        k0 = max(0, int(np.ceil((time.time() - self.swarm.start_unix_s) / dt)))
        dl = sc.protocol.deadline_ms / 1000
        timers = self._step_timers
        for k in range(k0, sc.steps + 1):
            at = self._loop_time_of(self.swarm.start_unix_s + k * dt)
            timers.append(loop.call_at(at, self._step, k))
            timers.append(loop.call_at(at + dl / 2, self._retry, k))
            timers.append(loop.call_at(at + dl, self._deadline, k))
        end = self._loop_time_of(self.swarm.start_unix_s + sc.steps * dt) + dl + END_GRACE_S
        # the last step's datagrams are counted when a step after it would begin, not at the
        # stop (which comes END_GRACE_S later, and would count that time to the last step)
        after = self._loop_time_of(self.swarm.start_unix_s + (sc.steps + 1) * dt)
        timers.append(loop.call_at(after, self._count_sent, sc.steps + 1))
        timers.append(loop.call_at(end, self.stop, "end of scenario"))

    def _clock_moved(self) -> bool:
        """Whether the wall clock and the loop's clock parted by more than CLOCK_JUMP_S since
        the steps were scheduled (the wall clock stepped, or the machine was paused while its
        wall clock ran on); if so the remaining steps are scheduled again from the wall clock.
        Without it every later step's timer fired at a moment the wall clock called over, and
        was skipped: on the busy 2-core machine a swarm committed nothing after 9 s of a 30 s
        run (211 steps `steps_missed_late` on every drone)."""
        loop = asyncio.get_running_loop()
        if abs(time.time() - loop.time() - self._clock_offset) <= CLOCK_JUMP_S:
            return False
        for t in self._step_timers:
            t.cancel()
        self._step_timers.clear()
        self.counters["clock_resyncs"] += 1
        _logger.warning("drone %d: the wall clock moved against the loop's: steps scheduled again", self.id)
        self._schedule_steps(loop)
        return True

    def _report(self, k: int) -> Report | None:
        r = self.source.reading(k)
        if r is None:
            self.counters["no_reading"] += 1
            return None
        return self.drone.make_report(k, r.position, r.kind, r.ranges, r.innovation, r.drift, r.ins)

    def _deliver_report(self, report: Report) -> None:
        lead = self.node.lead
        self._sent_to[report.step] = lead
        if lead is None:
            return
        if lead == self.id:
            self._on_report(report)
        else:
            self._send(lead, report)

    def _count_sent(self, k: int) -> None:
        """One line of ``drone-<id>.sent.csv``: the Raft datagrams and reports sent since the
        previous step began, counted to step k - 1 (written when step k begins)."""
        now = (self.counters["sent_raft"], self.counters["sent_reports"])
        if k > 0:
            raft, reports = now[0] - self._sent_mark[0], now[1] - self._sent_mark[1]
            self._sent_file.write(f"{k - 1},{raft},{reports}\n")
            self._sent_file.flush()
        self._sent_mark = now

    def _late(self, k: int, by_s: float) -> bool:
        """Whether step k's moment plus ``by_s`` has passed: a timer that fires that late (the
        process was frozen, or starved of CPU) must not act for a step that is over."""
        return time.time() > self.swarm.start_unix_s + k * self.sc.dt_s + by_s

    def _step(self, k: int) -> None:
        if self._clock_moved():
            return  # this timer's moment is stale; the new schedule takes the step that is due
        self._count_sent(k)
        self._begun = k
        if self._late(k, self.sc.protocol.deadline_ms / 1000):
            self.counters["steps_missed_late"] += 1  # no reading is taken for a step that is over
            return
        self._reports[k] = self._report(k)
        if self._reports[k] is not None:
            self._reported[k] = _jsonable(self._reports[k].position)[0]
        for old in [s for s in self._reported if s < k - REPORTED_KEPT]:
            del self._reported[old]
        for old in [s for s in self._reports if s < k - 2]:
            del self._reports[old]
        self._sent_to = {s: v for s, v in self._sent_to.items() if s >= k - 2}
        self._acked = {s for s in self._acked if s >= k - 2}
        if self._reports[k] is not None:
            self._deliver_report(self._reports[k])
            if self.drone.audit is not None:
                self._fan_out(self._reports[k])

    def _fan_out(self, report: Report) -> None:
        """The report to every other voter but the leader it went to, once (the audit's
        censorship check, docs/audit.md; the simulator's `Mission._fan_out`: only voters can
        depose a leader). As in the simulator, a drone does not hold its own report for the
        check: it has it from the start, and a leader whose loop ran late may well not have
        had it in time (the other voters hold it, from this fan-out)."""
        for peer in self.node.conf_state.voters:
            if peer in self.peers and peer != self._sent_to.get(report.step):
                self._send(peer, report, counter="sent_fanout")

    def _retry(self, k: int) -> None:
        """At half the deadline, resend step k's report if the leader did not acknowledge it,
        or if the leader changed (or became known) since it was sent (as the simulator's
        missions do)."""
        if self.drone.audit is not None:
            # reports of step k arriving later are not timely for the censorship check: the
            # leader has half a deadline more, and this resend, to get its own copy
            self._close_step(k)
        report = self._reports.get(k)
        if self._late(k, self.sc.protocol.deadline_ms / 1000):
            return
        lead = self.node.lead
        if report is None or lead is None:
            return
        if k in self._acked and lead == self._sent_to.get(k):
            return
        self.counters["reports_resent"] += 1
        self._deliver_report(report)

    def _on_report(self, report: Report) -> None:
        if self._lying and drops_report(self._lie, report):
            self.counters["reports_censored"] += 1
            return  # the lying leader drops the drone's reports (the simulator's Mission._receive)
        if self.drone.audit is not None:
            if report.drone != self.index:  # no drone holds its own (docs/audit.md)
                self._note_for_censorship(report)
            if self.node.role != Role.LEADER:
                return  # a fanned-out report, or one for a leader this drone no longer is
        if self._verifying is not None:
            self._backlog.append(report)
            return
        accepted = self.drone.receive(report)
        if accepted:  # acknowledged, so the drone does not resend it (simulator: Mission._receive)
            if report.drone == self.index:
                self._acked.add(report.step)
            else:
                self._send(report.drone + 1, wire.ReportAck(report.step, report.drone + 1))
        if accepted and self.drone.has_all(report.step) and self.node.role == Role.LEADER:
            self._decide(report.step)

    def _note_for_censorship(self, report: Report) -> bool:
        """Hold ``report`` for the censorship check (`Auditor.note_report`; not touched by
        `verify_step`) if it is timely: its step's half deadline has not passed by the clock.
        The `_retry` timer closes the step at that moment, but on a loaded machine it fires
        late, and a report read between the moment and the timer would count: on 2026-12-03,
        nine processes on 2 loaded cores (`accept_audit.py lying-net`) found their honest
        leader censoring in 8 of 18 missions before any lie (in one kept run the followers'
        reports, sent late by their starved loops, reached the leader after its deadline for
        12 steps in a row, and a voter whose timer fired late still held them as timely)."""
        audit = self.drone.audit
        if self._late(report.step, self.sc.protocol.deadline_ms / 2000):
            self._close_step(report.step)
        return audit.note_report(report)

    def _close_step(self, k: int) -> None:
        """Step k closes for the censorship check (`Auditor.close_step`): a record of it that
        came before is judged now, and a finding deposes the leader."""
        if k in self.drone.audit.closed:
            return
        self.drone.audit.close_step(k)
        self._take_suspicion()

    def _deadline(self, k: int) -> None:
        if self._late(k, self.sc.protocol.deadline_ms / 1000 + self.sc.dt_s):
            self.counters["deadlines_missed_late"] += 1  # a record this late would be stale
            return
        if self.node.role == Role.LEADER:
            # the reports already waiting in the socket first: the loop reads one datagram
            # per pass, and this timer ran before the rest. On 2026-12-03, nine processes on 2
            # loaded cores: leaders decided steps with their own report alone while the
            # others' reports waited, and voters holding them found the leader censoring
            self.counters["drained_at_deadline"] += self.transport.drain()
            if self.node.role != Role.LEADER:
                return  # deposed by what was waiting
            self._decide(k)

    def _decide(self, k: int) -> None:
        """The leader's verification of step k, in the verify thread (the detector takes tens
        of ms): until it returns, the drone is not touched (reports wait in a backlog, applying
        waits), so `SwarmDrone` is driven one call at a time, as in the simulator."""
        if self._stopping:
            return  # stopping: no new verification (its thread may be shut down already)
        if self._verifying is not None:
            self._decide_later.append(k)
            return
        loop = asyncio.get_running_loop()
        t0 = time.perf_counter()
        self._verifying = loop.run_in_executor(self._cpu, self.drone.verify_step, k, self.node.term)
        self._verifying.add_done_callback(lambda f: self._decided(f, t0))

    def _decided(self, fut: asyncio.Future, t0: float) -> None:
        self._verifying = None
        self._time("verify", t0)
        self._apply_queued()  # what committed meanwhile, before any new verification
        try:
            rec = fut.result()
        except Exception:
            self.counters["internal_error"] += 1
            _logger.exception("drone %d: verification failed", self.id)
            rec = None
        if rec is not None:
            step = rec.step

            def propose() -> None:
                if self.node.role != Role.LEADER or self.node.term != rec.term:
                    # deposed while verifying: a record of a term this drone no longer leads
                    # is dropped, not forwarded (the new leader's followers would refuse it:
                    # its term is not its entry's, docs/audit.md)
                    self.counters["proposals_not_leader"] += 1
                    return
                try:
                    self.node.propose(self._seal(rec))
                except NotLeader:
                    self.counters["proposals_not_leader"] += 1
                except ProposalDropped as exc:  # too much uncommitted: the step is skipped
                    self.counters["proposals_refused"] += 1
                    self._event("proposal_refused", step=step, reason=str(exc))

            self._push(propose)
        backlog, self._backlog = self._backlog, []
        for report in backlog:
            self._on_report(report)
        later, self._decide_later = self._decide_later, []
        for k in later:
            self._decide(k)

    def _seal(self, rec: StepRecord) -> bytes:
        """The leader's record as proposed: signed when the swarm audits (`SwarmDrone.seal`),
        falsified first if this drone lies (`sim.lying.falsify`, the simulator's lies)."""
        if self.drone.audit is None:
            return rec.encode()
        lie = falsify(rec, self._lie) if self._lying else None
        data = self.drone.seal(lie if lie is not None else rec)
        if lie is not None:
            self.counters["falsified_proposed"] += 1
            self._event("falsified", step=rec.step, term=rec.term, record=record_hash(data))
        return data

    # -- the audit (docs/audit.md) ----------------------------------------------------------
    def _audit_clock(self) -> None:
        """The audit's clock (`Auditor.at_step`) from the wall clock, which every drone of the
        swarm shares: a record for a step more than a few ahead of it is refused. From the
        wall clock, not the step timers: a loaded machine's timers fire late, and an honest
        record would then look ahead."""
        audit = self.drone.audit
        k = int((time.time() - self.swarm.start_unix_s) // self.sc.dt_s)
        if audit is not None and k >= 0:
            audit.at_step(k)

    def _audits(self, m: Message) -> bool:
        """Whether stepping ``m`` would re-run the audit (an append with a record this drone
        has not checked yet)."""
        audit = self.drone.audit
        if audit is not None and m.type == MsgType.SNAP:
            return True  # a leader's snapshot: its records are audited before it is installed
        return (
            audit is not None
            and m.type == MsgType.APP
            and any(e.kind == EntryKind.NORMAL and not audit.passed(e.data) for e in m.entries)
        )

    @staticmethod
    def _records_of(m: Message) -> list[bytes]:
        """The records an append or a snapshot carries, as the audit checks them."""
        if m.type == MsgType.SNAP:
            try:
                state = Applied.decode(m.snapshot.data)
            except Exception:  # noqa: BLE001 - undecodable: the validator says why
                return []
            return [rec.encode() for _, rec in sorted(state.records.items())]
        return [e.data for e in m.entries if e.kind == EntryKind.NORMAL]

    def _preaudit(self) -> None:
        """Steps the held appends in order, each once the audit thread has computed its
        records' evidence checks (`Auditor.evidence_ahead`: the signatures and the re-run,
        tens of ms, up to hundreds with `joint`'s set search on a loaded machine); the node
        then validates from that cache. Meanwhile the node goes on with everything else: it
        answers its leader's heartbeats, so a leader whose voters all audit a slow record at
        once keeps its quorum (stepped in the audit thread, the node waiting for it, nine
        voters' 276-308 ms audits on 2 cores cost their leader its quorum: docs/audit.md).
        Appends wait behind a held one, keeping their order."""
        if self._preauditing or self._stopping:
            return
        while self._held_apps:
            m = self._held_apps[0]
            # an append the node will drop unread (a deposed leader's, a stale term's: the
            # liar's next records, sent while this drone audited its first lie) is not audited
            audited = not self.node.ignores(m) and self._audits(m)
            data = self._records_of(m) if audited else []
            if not data:
                self._held_apps.popleft()
                self._push(lambda m=m: self.node.step(m))
                continue
            t0 = time.perf_counter()
            job = self._loop.run_in_executor(self._audit_pool, self._evidence_ahead, data)
            self._preauditing = True

            def done(fut: asyncio.Future, t0: float = t0) -> None:
                self._preauditing = False
                if self._stopping:
                    return  # the loop is closing: nothing more is stepped or audited
                self._audit_failed(fut)  # the node's validator then checks it again
                self._time("audit", t0)
                held = self._held_apps.popleft()
                self._push(lambda: self.node.step(held))
                self._preaudit()

            job.add_done_callback(done)
            return

    def _evidence_ahead(self, data: list[bytes]) -> None:
        """In the audit thread: the evidence checks of the records ``data`` (`_preaudit`)."""
        for d in data:
            self.drone.audit.evidence_ahead(d)

    def _validate(self, entry: Entry) -> bool:
        """The Raft node's validator (its drone's `Auditor.validate`): a refused record and a
        censorship finding are counted and logged; a censorship finding starts a forced
        election (a refused record starts one in Raft). The simulator's `Mission._validate`."""
        ok = self._audited(self.drone.audit.validate, entry, entry.term, entry.index)
        self._take_suspicion()
        return ok

    def _validate_snapshot(self, snap: Snapshot) -> bool:
        """The Raft node's validator of a leader's snapshot (`Auditor.validate_snapshot`; its
        records' checks computed ahead in the audit thread): a refusal is counted and logged."""
        return self._audited(self.drone.audit.validate_snapshot, snap, self.node.term, snap.index)

    def _audited(self, check: Callable[[Any], bool], item: Entry | Snapshot, term: int, index: int) -> bool:
        """``check(item)`` timed (the part the audit thread did not compute ahead); a
        refusal counted, logged and an `audit_refused` event (step -1: a snapshot)."""
        refused = self.drone.audit.refused
        n_refused = len(refused)
        t0 = time.perf_counter()
        ok = check(item)
        self._time("validate", t0)  # the evidence computed ahead ("audit"): the rest
        if not ok:
            step, reason = refused[n_refused]
            self.counters["audit_refused"] += 1
            self._event("audit_refused", step=step, term=term, index=index, reason=reason)
            what = f"the record of step {step}" if step >= 0 else "its leader's snapshot"
            _logger.warning("drone %d: refused %s: %s", self.id, what, reason)
        return ok

    def _take_suspicion(self) -> None:
        """A censorship finding of the audit (after a record, or a step's close) deposes the
        leader of the term it was made in (`_censorship_found`)."""
        audit = self.drone.audit
        term = audit.omission_term
        why = audit.take_suspicion()
        if why is not None:
            self._censorship_found(why, term)

    def _censorship_found(self, why: str, term: int) -> None:
        """The leader of ``term`` censors: deposed (`RaftNode.depose`) unless the term moved on
        meanwhile."""
        self.counters["censorship_findings"] += 1
        self._event("censorship", term=term, why=why)
        _logger.warning("drone %d: the leader of term %d censors: %s", self.id, term, why)

        # called inside the node's step (its validator): deposed once that step is done, the
        # leader named now (by then the node may have become a pre-candidate, leaderless)
        lead = self.node.lead
        self._loop.call_soon(self._push, lambda: self.node.depose(lead, term))

    def compromise(self) -> None:
        """SIGUSR1: from now on this drone lies whenever it leads, as the scenario's
        lying-leader fault says (`swarmraft launch` sends it to the leader at the fault's time)."""
        if self._lie is None:
            self.counters["compromise_ignored"] += 1
            self._event("compromise_ignored", why="the scenario has no lying-leader fault")
            return
        if not self._lying:
            self._lying = True
            f = self._lie
            self._event(
                "compromised",
                mode=f.mode,
                drone=f.drone,
                offset_m=move_offset(f),  # the shift in effect (null outside move)
                role=str(self.node.role),
                term=self.node.term,
            )

    def _time(self, what: str, t0: float) -> None:
        ms = (time.perf_counter() - t0) * 1000
        self.counters[f"{what}_count"] += 1
        self.counters[f"{what}_ms_total"] += round(ms)
        self.counters[f"{what}_ms_max"] = max(self.counters[f"{what}_ms_max"], round(ms))

    # -- applying ---------------------------------------------------------------------------
    def _restore(self, snap: Snapshot) -> None:
        """The drone's replicated state from a snapshot (its own on restart, or the leader's);
        the snapshot's records not yet in the step file are written to it."""
        self.drone.restore(snap.data)
        self._applied_index = self._snap_index = snap.index
        for rec in self.drone.state.records.values():
            self._write_step(self._record_row(rec, rec.encode(), time.time(), from_snapshot=snap.index))

    def _record_row(self, rec: StepRecord, data: bytes, now: float, **extra: int) -> dict:
        """A committed step's row of the step file (``extra``: the log index it was applied
        at, or the snapshot it came from)."""
        row = {"step": rec.step, "committed": True, "status": rec.status, "term": rec.term, **extra}
        return row | {
            "record": record_hash(data),
            "digest": rec.digest,
            "detector": rec.detector,
            "faulty": _ids(rec.faulty),
            "missing": _ids(rec.missing),
            "positions": _jsonable(rec.positions),
            "hpl": _levels(rec.hpl),
            "vpl": _levels(rec.vpl),
            "reported": self._reported.get(rec.step),
            "applied_unix_s": round(now, 4),
        }

    def _apply(self, entry: Entry | Snapshot) -> None:
        if isinstance(entry, Snapshot):
            self._restore(entry)
            return
        self._applied_index = entry.index
        if entry.kind != EntryKind.NORMAL:  # a no-op, or a membership change: no record
            return
        before, refused = self.drone.state.last_step, self.drone.refused_applies
        rec = self.drone.apply(entry.data)
        if self.drone.refused_applies > refused:
            step, reason = self.drone.audit.refused[-1]
            self._event("audit_refused_apply", step=step, index=entry.index, reason=reason)
        if rec is None:
            return
        now = time.time()
        for s in range(before + 1, rec.step):
            self._write_step(
                {"step": s, "committed": False, "status": "skipped", "reported": self._reported.get(s)}
            )
        self._write_step(self._record_row(rec, entry.data, now, index=entry.index))
        i = self.index
        k_now = min(int((now - self.swarm.start_unix_s) / self.sc.dt_s), self.sc.steps)
        if rec.step >= k_now - REALIGN_STEPS and realigns(rec, i, self.drone.config.drift):
            self.source.realign(rec.step, rec.positions[i])


def run_node(swarm_path: str | Path, drone_id: int) -> int:
    """Run drone ``drone_id`` of the swarm file until the scenario ends or SIGTERM/SIGINT;
    the exit status. Bad configuration raises NodeConfigError, a failed bind BindError."""
    swarm = load_swarm(swarm_path)
    host = DroneHost(swarm, drone_id)
    return asyncio.run(host.run())
