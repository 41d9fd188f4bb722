"""The live view's options for `mission` and `launch` (--live, --record, --speed, --port,
--linger), the session that runs the viewer server and the stream beside a mission, and
`swarmraft view FILE.rrd` (docs/live.md)."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from swarmraft.cli.app import console, main


class RrdFile(click.ParamType):
    """An .rrd file to write: a name ending in .rrd, not a folder, in a folder that exists."""

    name = "file.rrd"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Path:
        path = Path(value)
        if path.suffix.lower() != ".rrd":
            self.fail(f"{value}: give a file name ending in .rrd", param, ctx)
        if path.is_dir():
            self.fail(f"{value} is a folder", param, ctx)
        if not path.parent.is_dir():
            self.fail(f"no folder {path.parent}", param, ctx)
        return path


def live_options(f: Callable) -> Callable:
    """--live, --record, --port, --viewer-memory and --linger, in that order on the help page."""
    options = [
        click.option(
            "--live",
            is_flag=True,
            help="serve rerun's web viewer on 127.0.0.1 (URL printed) and stream the swarm to it "
            "while it flies (needs the live extra: pip install 'swarmraft[live]'; docs/live.md)",
        ),
        click.option(
            "--record",
            "record_to",
            type=RrdFile(),
            metavar="FILE.rrd",
            help="write the same stream to FILE.rrd (open it with `swarmraft view FILE.rrd`)",
        ),
        click.option(
            "--port",
            type=click.IntRange(1, 65535),
            default=None,
            help="with --live: the web viewer's port on 127.0.0.1 (its stream takes a free port) "
            "[default: 9090]",
        ),
        click.option(
            "--viewer-memory",
            "viewer_memory",
            default=None,
            metavar="SIZE",
            help="with --live: the most of the stream the viewer server keeps for browsers that "
            "connect late, oldest dropped first, e.g. 64MiB or 1GiB [default: 256MiB]",
        ),
        click.option(
            "--linger",
            type=click.FloatRange(min=0),
            default=None,
            help="with --live: keep the viewer up this many seconds after the mission "
            "[default: until Ctrl-C]",
        ),
    ]
    for option in reversed(options):
        f = option(f)
    return f


SPEED = click.option(
    "--speed",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="with --live: simulated seconds per wall-clock second [default: 1, real time]",
)


_SIZE = re.compile(r"^[0-9]+(\.[0-9]+)?\s*(B|KB|MB|GB|KiB|MiB|GiB)$")


def check_live_options(
    live: bool, speed: float | None, linger: float | None, port: int | None, viewer_memory: str | None = None
) -> None:
    """--speed, --linger, --port and --viewer-memory mean something with --live only."""
    given = (("--speed", speed), ("--linger", linger), ("--port", port), ("--viewer-memory", viewer_memory))
    for name, value in given:
        if value is not None and not live:
            raise click.BadParameter("only with --live", param_hint=name)
    if viewer_memory is not None and not _SIZE.match(viewer_memory):
        raise click.BadParameter(
            f"{viewer_memory!r}: give a size such as 64MiB, 512MB or 1GiB", param_hint="--viewer-memory"
        )


@dataclass
class LiveSession:
    """The viewer server (with --live), the recording stream (to it and/or an .rrd file) and
    the `StepStream` that logs the mission's steps; `close` ends the stream and, with --live,
    keeps the viewer up for ``linger`` seconds (None: until Ctrl-C)."""

    name: str
    live: bool
    record_to: Path | None
    port: int | None
    linger: float | None
    viewer_memory: str | None = None
    with_truth: bool = True
    settle_steps: int = 2  # events of a step without a record wait this many steps for it
    say: Any = console  # a rich Console: stderr when stdout carries JSON
    pacer: Any = None  # the simulator's `viz.live.Pacer`, when it paces the mission

    def start(self) -> None:
        from swarmraft.viz import live as vl

        rr = vl.require_rerun("--live" if self.live else "--record")
        self.server = None
        if self.live:
            self.server = vl.ViewerServer(
                port=self.port or vl.DEFAULT_PORT, memory_limit=self.viewer_memory or vl.SERVER_MEMORY_LIMIT
            )
            self.server.start()
            self.say.print(f"live view: {self.server.url}", soft_wrap=True)
        self.rec = vl.open_stream(rr, self.name, self.server, self.record_to)
        self.stream = vl.StepStream(self.rec, with_truth=self.with_truth, settle_steps=self.settle_steps)
        self.t0 = time.monotonic()
        self.t_last = self.t0

    def update(self, log: Any, k: int) -> None:
        """Log the steps of ``log`` known up to k (`StepStream.update`), timing the stream."""
        first = not self.stream.logged
        self.stream.update(log, k)
        now = time.monotonic()
        if first and self.stream.logged:
            self.t0 = now
        self.t_last = now

    def rate_line(self, dt_s: float) -> str:
        """Steps logged per wall-clock second, from the first to the last, against the
        mission's step rate; frames (every step logged, and logged again when its record came
        late) per second; and, when paced, how far the mission fell behind its pace."""
        steps, frames = len(self.stream.logged), self.stream.steps_logged
        took = max(self.t_last - self.t0, 1e-9)
        rate = (steps - 1) / took if steps > 1 else 0.0
        behind = "" if self.pacer is None else f"; at most {self.pacer.behind_s:.2f} s behind its pace"
        return (
            f"stream: {steps} steps in {took:.1f} s: {rate:.2f} steps/s against the mission's "
            f"{1 / dt_s:g}, {frames / took:.2f} frames/s ({frames - steps} late records logged again)"
            + behind
        )

    def static(self, log: Any) -> None:
        from swarmraft.viz.live import log_static

        log_static(self.rec, log)

    def close(self, final_log: Any = None, errors: Any = None) -> None:
        if final_log is not None:
            self.stream.finish(final_log, errors)
        self.rec.flush()
        self.rec.disconnect()
        if self.record_to is not None:
            self.say.print(f"wrote {self.record_to}", soft_wrap=True)
        if self.server is None:
            return
        from swarmraft.viz.live import ctrl_c_raises

        try:
            with ctrl_c_raises():  # before the line that says Ctrl-C works: none is lost between
                if self.linger is None:
                    self.say.print(f"the viewer stays up at {self.server.url} until Ctrl-C", soft_wrap=True)
                self.server.wait(self.linger)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        if getattr(self, "server", None) is not None:
            self.server.stop()


@main.command("view")
@click.argument("rrd", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--port", type=click.IntRange(1, 65535), default=9090, show_default=True, help="the web viewer's port"
)
def view(rrd: Path, port: int) -> None:
    """Open a recording (FILE.rrd, from --record or `swarmraft record DIR`) in rerun's web
    viewer, served on 127.0.0.1 (URL printed) until Ctrl-C."""
    from swarmraft.viz import live as vl

    if not rrd.is_file():
        raise click.BadParameter(f"no file {rrd}", param_hint="RRD")
    if rrd.suffix.lower() != ".rrd":
        raise click.BadParameter(f"{rrd} is not an .rrd recording", param_hint="RRD")
    vl.require_rerun("swarmraft view")
    with rrd.open("rb") as fh:  # a recording starts with rerun's magic, RRF and a version digit
        head = fh.read(4)
    if not head.startswith(b"RRF"):
        raise click.BadParameter(
            f"{rrd} is not a rerun recording (it starts with {head!r}, not RRF)", param_hint="RRD"
        )
    server = vl.ViewerServer(port=port, rrd=rrd)
    server.start()
    try:
        with vl.ctrl_c_raises():  # before the line that says Ctrl-C works: none is lost between
            console.print(f"viewing {rrd}: {server.url}", soft_wrap=True)
            console.print("Ctrl-C to stop")
            server.wait()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()


class FollowLaunch:
    """A thread that, every step interval while a networked swarm runs, reads what its drones
    have written (`net.results.LaunchTail`) and logs the steps that ended ``lag_steps`` ago
    (a record applied later still comes: `StepStream` logs it again)."""

    def __init__(self, session: LiveSession, tail: Any, start_unix_s: float, dt_s: float, lag_steps: int = 3):
        import threading

        self.session, self.tail = session, tail
        self.start_unix_s, self.dt_s, self.lag_steps = start_unix_s, dt_s, lag_steps
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._run, name="swarmraft-live", daemon=True)

    def start(self) -> None:
        self.session.static(self.tail.log)
        self.thread.start()

    def _run(self) -> None:
        while not self.done.wait(self.dt_s):
            k = int((time.time() - self.start_unix_s) / self.dt_s) - self.lag_steps
            if k < 0:
                continue
            self.tail.poll()
            self.session.update(self.tail.log, k)

    def stop(self) -> None:
        self.done.set()
        self.thread.join()
