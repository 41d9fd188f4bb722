"""The live view and .rrd recordings of a mission (rerun, the ``live`` extra): one function,
`log_step`, writes step k of a `MissionLog` to a rerun RecordingStream; `StepStream` calls it
as the steps of a running mission become known (the simulator's per-step hook, a networked
swarm's step files) and again when a record arrives late; `record_mission` replays a finished
mission. `ViewerServer` runs rerun's gRPC server and web viewer (served from the wheel, bound
to 127.0.0.1) as a child process whose buffer is bounded.

Entity layout, one batched entity per kind (every drone in one array, drone i at index i - 1):
``swarm/truth``, ``swarm/reported``, ``swarm/verified`` (points), ``swarm/repairs`` (arrows from
a flagged drone's report to its verified position), ``swarm/protection`` (ellipsoids of
half-sizes hpl, hpl, vpl), ``swarm/leader``; ``errors/verified`` (one scalar per drone: the
verified position's distance to the truth, m); ``raft`` (leader id and term);
``latency/commit_ms``; ``events``.
Timelines: ``time`` (mission seconds) and ``step``.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarmraft.sim.mission import MissionLog

APPLICATION_ID = "swarmraft"
#: The viewer server keeps at most this much of the stream for late-connecting browsers; the
#: oldest data goes first (rerun's --server-memory-limit).
SERVER_MEMORY_LIMIT = "256MiB"
DEFAULT_PORT = 9090

# Status of a drone in a step, its code in the `drone_status` array and its colour (RGB).
HONEST, FLAGGED, JAMMED, MISSING = 0, 1, 2, 3
STATUS_NAMES = ("honest", "flagged", "jammed", "missing")
STATUS_COLOURS = np.array(
    [
        (46, 134, 222),  # honest: blue
        (231, 76, 60),  # flagged: red
        (243, 156, 18),  # jammed (GNSS outage, reporting INS): orange
        (149, 165, 166),  # missing (no report, or not alive): grey
    ],
    np.uint8,
)
TRUTH_COLOUR = (60, 60, 60)
LEADER_COLOUR = (241, 196, 15)
PROTECTION_COLOUR = (175, 190, 205)

LEGEND = """\
**verified** (large, labelled): blue honest, red flagged, orange jammed (GNSS outage), grey
missing; **reported** (small), same colours; **truth** dark grey; **red arrows** from a flagged
drone's report to its verified position; **wireframes** protection levels (hpl, hpl, vpl);
**gold** the leader.
"""


class LiveExtraMissing(RuntimeError):
    """rerun-sdk is not installed: a one-line error naming the option that needs it."""


def require_rerun(option: str = "--live") -> Any:
    """The rerun module, or LiveExtraMissing saying how to install it."""
    try:
        import rerun
    except ImportError:
        raise LiveExtraMissing(f"{option} needs the live extra: pip install 'swarmraft[live]'") from None
    return rerun


def drone_status(log: MissionLog, k: int) -> np.ndarray:
    """(n,) status codes of step k: missing (not alive, no report, or missing from the
    record), flagged (by the step's record), jammed (in a GNSS outage), else honest."""
    status = np.full(log.scenario.drones, HONEST)
    status[log.outage[k]] = JAMMED
    status[log.committed[k] & log.faulty[k]] = FLAGGED
    no_report = ~np.isfinite(log.reported[k]).all(axis=1)
    status[~log.alive[k] | no_report | (log.committed[k] & log.missing[k])] = MISSING
    return status


def drone_colours(n: int) -> np.ndarray:
    """(n, 3) distinct colours for the drones' error series."""
    from matplotlib import colormaps

    cmap = colormaps["tab20" if n > 10 else "tab10"]
    return (np.array([cmap(i % cmap.N)[:3] for i in range(n)]) * 255).astype(np.uint8)


def blueprint(rr: Any) -> Any:
    """The layout: the 3-D swarm on the left; errors, Raft, latency and the event log on the right."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(origin="/swarm", name="swarm (ENU, m)"),
                rrb.TextDocumentView(origin="/legend", name="legend"),
                row_shares=[6, 1],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/errors/verified", name="error of verified positions, m"),
                rrb.TimeSeriesView(origin="/raft", name="leader and term"),
                rrb.TimeSeriesView(origin="/latency", name="commit latency, ms"),
                rrb.TextLogView(origin="/events", name="events"),
                row_shares=[3, 2, 2, 3],
            ),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline="time", play_state="following"),
    )


def new_stream(rr: Any, name: str) -> Any:
    return rr.RecordingStream(APPLICATION_ID, recording_id=f"{name}-{time.time_ns()}")


def log_static(rec: Any, log: MissionLog) -> None:
    """What does not change over a mission: the frame, the legend, the series' names and colours."""
    import rerun as rr

    n = log.scenario.drones
    names = [f"drone {i}" for i in range(1, n + 1)]
    colours = drone_colours(n)
    rec.log("swarm", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("legend", rr.TextDocument(LEGEND, media_type=rr.MediaType.MARKDOWN), static=True)
    rec.log("errors/verified", rr.SeriesLines(names=names, colors=colours), static=True)
    rec.log("raft", rr.SeriesLines(names=["leader (drone id, 0 = none)", "term"]), static=True)
    rec.log("latency/commit_ms", rr.SeriesLines(names="step start to first apply, ms"), static=True)


def _error(a: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - truth, axis=1)


def _last_flags(log: MissionLog, k: int) -> np.ndarray:
    """(n,) each drone's flag in the last committed record before step k in which it was
    present (not missing); False where there is none."""
    flags = np.zeros(log.faulty.shape[1], bool)
    open_ = np.ones_like(flags)
    for j in range(k - 1, -1, -1):
        if not log.committed[j]:
            continue
        seen = open_ & ~log.missing[j]
        flags[seen] = log.faulty[j, seen]
        open_ &= ~seen
        if not open_.any():
            break
    return flags


def step_events(log: MissionLog, k: int) -> list[tuple[str, str]]:
    """(level, text) of step k: the mission's events since step k-1 (crashes, partitions,
    loss), a new leader (of a record, against the previous record's), drones flagged (and
    recovered to a verified position) or cleared, the first of a run of skipped steps and the
    first record after one."""
    out: list[tuple[str, str]] = []
    t, dt = float(log.t[k]), log.scenario.dt_s
    for te, what in log.events:
        if (k == 0 and te <= t) or (t - dt < te <= t):
            out.append(("WARN", what))
    prior = _previous_record(log, k)
    if log.committed[k] and (prior is None or log.leader[k] != log.leader[prior]):
        out.append(("INFO", f"leader: drone {int(log.leader[k])} (term {log.term[k]})"))
    if not log.committed[k]:
        if k == 0 or log.committed[k - 1]:
            out.append(("WARN", f"steps skipped from step {k} (no record)"))
        return out
    if k and not log.committed[k - 1]:
        out.append(("INFO", f"records again from step {k}"))
    # a drone missing from a record (its report lost) keeps the flag it had when last judged:
    # neither 'cleared' there nor 'flagged' again after
    before = _last_flags(log, k)
    present = ~log.missing[k]
    for i in np.flatnonzero(log.faulty[k] & ~before & present):
        v, r = log.verified[k, i], log.reported[k, i]
        if np.isfinite(v).all() and np.isfinite(r).all():
            out.append(
                ("ERROR", f"drone {i + 1} flagged; recovered {np.linalg.norm(v - r):.1f} m from its report")
            )
        else:
            out.append(("ERROR", f"drone {i + 1} flagged"))
    if k and log.committed[k - 1]:
        for i in np.flatnonzero(~log.faulty[k] & before & present):
            out.append(("INFO", f"drone {i + 1} cleared"))
    return out


def _previous_record(log: MissionLog, k: int) -> int | None:
    """The last step before k with a record (a walk back over the skipped steps only, so a
    stream of S steps costs O(S), not O(S^2))."""
    j = k - 1
    while j >= 0 and not log.committed[j]:
        j -= 1
    return j if j >= 0 else None


def log_step(
    rec: Any,
    log: MissionLog,
    k: int,
    errors: dict[str, np.ndarray] | None = None,
    *,
    with_events: bool = True,
    with_truth: bool = True,
) -> None:
    """Step k of ``log`` into the recording stream ``rec``: the swarm (truth, reported and
    verified positions coloured by status, repair arrows, protection levels, the leader), the
    per-drone errors, leader, term, commit latency and (``with_events``) the step's events.
    ``errors["swarmraft"]`` (S, n), the verified positions' errors, is used where given (a
    results folder's own numbers); else the errors are computed against ``log.truth``."""
    import rerun as rr

    n = log.scenario.drones
    rec.set_time("step", sequence=k)
    rec.set_time("time", duration=float(log.t[k]))
    status = drone_status(log, k)
    colours = STATUS_COLOURS[status]
    truth, reported = log.truth[k], log.reported[k]
    verified = log.verified[k] if log.committed[k] else np.full((n, 3), np.nan)
    ids = np.arange(1, n + 1)
    if with_truth and np.isfinite(truth).any():
        rec.log("swarm/truth", rr.Points3D(truth, colors=TRUTH_COLOUR, radii=0.4))
    has_r = np.isfinite(reported).all(axis=1)
    rec.log("swarm/reported", rr.Points3D(reported[has_r], colors=colours[has_r], radii=0.7))
    has_v = np.isfinite(verified).all(axis=1)
    lead = int(log.leader[k])
    labels = [f"{i}*" if i == lead else str(i) for i in ids[has_v]]
    rec.log(
        "swarm/verified",
        rr.Points3D(verified[has_v], colors=colours[has_v], radii=1.4, labels=labels, show_labels=True),
    )
    flagged = (status == FLAGGED) & has_v & has_r
    rec.log(
        "swarm/repairs",
        rr.Arrows3D(
            origins=reported[flagged],
            vectors=verified[flagged] - reported[flagged],
            colors=STATUS_COLOURS[FLAGGED],
        ),
    )
    hpl, vpl = log.hpl[k], log.vpl[k]
    prot = has_v & np.isfinite(hpl) & np.isfinite(vpl) & log.committed[k]
    half = np.stack([hpl[prot], hpl[prot], vpl[prot]], axis=1)
    rec.log(
        "swarm/protection",
        rr.Ellipsoids3D(
            centers=verified[prot], half_sizes=half, colors=PROTECTION_COLOUR, fill_mode="majorwireframe"
        ),
    )
    where = verified[lead - 1] if lead and has_v[lead - 1] else reported[lead - 1] if lead else None
    if where is not None and np.isfinite(where).all():
        rec.log(
            "swarm/leader", rr.Points3D([where], colors=LEADER_COLOUR, radii=2.4, labels=[f"leader {lead}"])
        )
    else:
        rec.log("swarm/leader", rr.Points3D(np.zeros((0, 3))))
    e_ver = errors["swarmraft"][k] if errors is not None else _error(verified, truth)
    rec.log("errors/verified", rr.Scalars(e_ver))
    rec.log("raft", rr.Scalars([float(lead), float(log.term[k])]))
    if np.isfinite(log.latency_ms[k]):
        rec.log("latency/commit_ms", rr.Scalars(float(log.latency_ms[k])))
    if with_events:
        for level, text in step_events(log, k):
            rec.log("events", rr.TextLog(text, level=level))


def log_events(rec: Any, log: MissionLog, k: int) -> None:
    """The events of step k (`step_events`) into the stream's text log, at step k's time."""
    import rerun as rr

    rec.set_time("step", sequence=k)
    rec.set_time("time", duration=float(log.t[k]))
    for level, text in step_events(log, k):
        rec.log("events", rr.TextLog(text, level=level))


@dataclass
class StepStream:
    """Logs the steps of a running mission as they become known: `update(log, upto)` logs
    every step not yet logged up to ``upto``, and logs again a step whose record has arrived
    since; a step's events are logged once it has its record, or once it is ``settle_steps``
    behind ``upto`` without one (so a late record is not first told as a skipped step), in
    step order. `finish(log)` does the same with the mission's final log, so the stream ends
    with the records and events the results hold."""

    rec: Any
    with_truth: bool = True
    settle_steps: int = 2
    logged: dict[int, bool] = field(default_factory=dict)  # step -> had a record when logged
    waiting: set[int] = field(default_factory=set)  # steps logged without their record yet
    steps_logged: int = 0
    events_upto: int = -1  # the last step whose events are logged

    def update(
        self,
        log: MissionLog,
        upto: int,
        errors: dict[str, np.ndarray] | None = None,
        settle: int | None = None,
    ) -> None:
        upto = min(upto, len(log.t) - 1)
        for k in range(len(self.logged), upto + 1):
            self._log(log, k, errors)
        for k in sorted(s for s in self.waiting if s <= upto and log.committed[s]):
            self._log(log, k, errors)
        settle = self.settle_steps if settle is None else settle
        k = self.events_upto + 1
        while k <= upto and (log.committed[k] or k <= upto - settle):
            log_events(self.rec, log, k)
            self.events_upto = k
            k += 1

    def finish(self, log: MissionLog, errors: dict[str, np.ndarray] | None = None) -> None:
        self.update(log, len(log.t) - 1, errors, settle=0)

    def _log(self, log: MissionLog, k: int, errors: dict[str, np.ndarray] | None) -> None:
        log_step(self.rec, log, k, errors, with_events=False, with_truth=self.with_truth)
        self.logged[k] = bool(log.committed[k])
        if self.logged[k]:
            self.waiting.discard(k)
        else:
            self.waiting.add(k)
        self.steps_logged += 1


def record_mission(log: MissionLog, errors: dict[str, np.ndarray] | None, path: Path) -> int:
    """Write a finished mission to an .rrd file (`swarmraft record DIR`); the steps written."""
    rr = require_rerun("swarmraft record DIR")
    rec = new_stream(rr, log.scenario.name)
    rec.save(str(path), default_blueprint=blueprint(rr))
    log_static(rec, log)
    stream = StepStream(rec)
    stream.finish(log, errors)
    rec.flush()
    rec.disconnect()
    return stream.steps_logged


# -- the viewer server -----------------------------------------------------------------------


class PortInUse(ValueError):
    pass


def check_port_free(port: int, option: str = "--port") -> None:
    """A one-line error if 127.0.0.1:port cannot be bound (another viewer, say)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            raise PortInUse(
                f"{option}: 127.0.0.1:{port} is in use; choose another port with {option}"
            ) from None


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _listening(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def rerun_command() -> list[str]:
    """rerun's own binary (the wheel's ``rerun_cli/rerun``), so the server is one process that
    stops when told (``python -m rerun`` is a wrapper that would leave the binary running)."""
    try:
        import rerun_cli

        binary = Path(rerun_cli.__file__).parent / "rerun"
        if binary.is_file() and os.access(binary, os.X_OK):
            return [str(binary)]
    except ImportError:
        pass
    return [sys.executable, "-m", "rerun"]


@contextmanager
def ctrl_c_raises() -> Iterator[None]:
    """Inside the block Ctrl-C (SIGINT) raises KeyboardInterrupt even where the process
    started with SIGINT ignored: a shell script's background job, or any parent that ignores
    it, passes that on, and Python then leaves it ignored. A command that says it waits "until
    Ctrl-C" must mean it. The handler before is put back after; off the main thread (where no
    handler can be set) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        if before is not None:  # None: set outside Python, cannot be put back from here
            signal.signal(signal.SIGINT, before)


def _die_with_parent() -> None:
    """In the server's process before it runs: on Linux, SIGTERM it when its parent dies (a
    killed mission leaves no server behind)."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


@dataclass
class ViewerServer:
    """rerun's gRPC server and web viewer as a child process on 127.0.0.1: the web page at
    ``port``, the stream at a free port, at most SERVER_MEMORY_LIMIT of it buffered. With
    ``rrd``, the server plays that file instead of taking a stream."""

    port: int = DEFAULT_PORT
    rrd: Path | None = None
    memory_limit: str = SERVER_MEMORY_LIMIT
    grpc_port: int = 0
    proc: subprocess.Popen | None = None

    def start(self, timeout_s: float = 30.0) -> None:
        check_port_free(self.port)
        self.grpc_port = self.grpc_port or free_tcp_port()
        cmd = [*rerun_command()]
        cmd += [str(self.rrd)] if self.rrd is not None else []
        cmd += [
            "--serve-web",
            "--bind",
            "127.0.0.1",
            "--port",
            str(self.grpc_port),
            "--web-viewer-port",
            str(self.port),
            "--server-memory-limit",
            self.memory_limit,
        ]
        self._log = tempfile.TemporaryFile()  # its messages, for the error line if it stops
        self.proc = subprocess.Popen(
            cmd,
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            preexec_fn=_die_with_parent,  # noqa: PLW1509 (no threads run Python here yet)
        )
        end = time.monotonic() + timeout_s
        while not (_listening(self.port) and _listening(self.grpc_port)):
            if self.proc.poll() is not None:
                self._log.seek(0)
                err = self._log.read().decode(errors="replace")
                last = [ln for ln in err.splitlines() if ln.strip()][-1:] or ["no message"]
                raise RuntimeError(f"the rerun viewer server stopped: {last[0]}")
            if time.monotonic() > end:
                self.stop()
                raise RuntimeError(f"the rerun viewer server did not listen within {timeout_s:g} s")
            time.sleep(0.1)

    @property
    def grpc_url(self) -> str:
        return f"rerun+http://127.0.0.1:{self.grpc_port}/proxy"

    @property
    def url(self) -> str:
        """The page to open: the web viewer, connected to the stream."""
        from urllib.parse import quote

        return f"http://127.0.0.1:{self.port}/?url={quote(self.grpc_url, safe='')}"

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    def wait(self, timeout_s: float | None = None) -> None:
        """Until the server ends, ``timeout_s`` passes (None: no limit) or Ctrl-C (then stop
        it; KeyboardInterrupt goes on to the caller)."""
        end = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            with ctrl_c_raises():
                while self.proc is not None and self.proc.poll() is None:
                    if end is not None and time.monotonic() >= end:
                        break
                    time.sleep(0.2 if end is None else max(0.0, min(0.2, end - time.monotonic())))
        finally:
            self.stop()

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def open_stream(rr: Any, name: str, server: ViewerServer | None, record: Path | None) -> Any:
    """A recording stream to the viewer server, to an .rrd file, or both, with the layout."""
    rec = new_stream(rr, name)
    sinks = []
    if server is not None:
        sinks.append(rr.GrpcSink(server.grpc_url))
    if record is not None:
        sinks.append(rr.FileSink(str(record)))
    rec.set_sinks(*sinks, default_blueprint=blueprint(rr))
    return rec


class Pacer:
    """Sleeps so that step k is shown at ``k * dt_s / speed`` seconds after the first call."""

    def __init__(self, dt_s: float, speed: float) -> None:
        self.dt_s, self.speed = dt_s, speed
        self.t0: float | None = None
        self.behind_s = 0.0  # the most the run has been behind its pace

    def wait(self, k: int) -> None:
        now = time.monotonic()
        if self.t0 is None:
            self.t0 = now - k * self.dt_s / self.speed
        due = self.t0 + k * self.dt_s / self.speed
        if due > now:
            time.sleep(due - now)
        else:
            self.behind_s = max(self.behind_s, now - due)
