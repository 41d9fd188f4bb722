"""The live view measured: a 17-drone mission (the demo scenario with 17 drones) run by
`swarmraft mission --live` at real-time speed, its step and frame rates against the step
rate (10 steps/s at dt = 0.1 s), and the memory (RSS) of the viewer server process (rerun's
gRPC server and web viewer, which buffers the stream for browsers) and of the mission's own
process, sampled every second over the run.

    python benchmarks/bench_live.py               # 60 s of mission
    python benchmarks/bench_live.py --minutes 10  # the memory-bound check

No browser is connected (a browser's viewer is the user's own process, with its own memory
limit); the server's buffer is bounded by SERVER_MEMORY_LIMIT (docs/live.md). Then the cost
of logging one step: the mission's folder replayed to an .rrd (`swarmraft record DIR`).
"""

from __future__ import annotations

import argparse
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from swarmraft.sim.scenario import find_scenario
from swarmraft.viz.live import SERVER_MEMORY_LIMIT


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except FileNotFoundError:
            continue
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drones", type=int, default=17)
    ap.add_argument("--seconds", type=float, default=60.0, help="mission length, s")
    ap.add_argument("--minutes", type=float, default=None, help="mission length, min (overrides --seconds)")
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--viewer-memory", default=SERVER_MEMORY_LIMIT, help="the viewer server's buffer limit")
    args = ap.parse_args()
    seconds = args.minutes * 60 if args.minutes else args.seconds
    demo = find_scenario("demo").read_text()
    text = re.sub(r"(?m)^drones = \d+", f"drones = {args.drones}", demo)
    text = re.sub(r"(?m)^duration_s = \d+", f"duration_s = {seconds:g}", text)
    text = re.sub(r"(?m)^maps_at_s = .*", "maps_at_s = [5]", text)
    with tempfile.TemporaryDirectory(prefix="bench-live-") as tmp:
        scenario = Path(tmp) / "live17.toml"
        scenario.write_text(text)
        cmd = [sys.executable, "-m", "swarmraft", "mission", "--scenario", str(scenario)]
        cmd += ["--out", str(Path(tmp) / "out"), "--live", "--port", str(free_port())]
        cmd += ["--speed", f"{args.speed:g}", "--linger", "0", "--viewer-memory", args.viewer_memory]
        print(f"{args.drones} drones, {seconds:g} s of mission at speed {args.speed:g}, --live")
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        samples: list[tuple[float, float | None, float | None]] = []  # (s, server MB, mission MB)
        lines: list[str] = []
        threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()  # type: ignore[arg-type]
        t0 = time.monotonic()
        while proc.poll() is None:
            server = children(proc.pid)
            samples.append(
                (time.monotonic() - t0, max((rss_mb(c) or 0 for c in server), default=None), rss_mb(proc.pid))
            )
            time.sleep(1.0)
        proc.wait()
        time.sleep(0.5)
        cost = log_cost(Path(tmp) / "out", Path(tmp) / "cost.rrd") if proc.returncode == 0 else None
    rate = next((ln.strip() for ln in lines if ln.startswith("stream:")), None)
    if proc.returncode != 0 or rate is None:
        print("".join(lines[-20:]))
        sys.exit(f"the mission failed (status {proc.returncode})")
    print(rate)
    srv = [(t, s) for t, s, _ in samples if s]
    own = [(t, m) for t, _, m in samples if m]
    if srv:
        tenth = max(1, len(srv) // 10)
        first, last = srv[:tenth], srv[-tenth:]
        top = max(s for _, s in srv)
        print(
            f"viewer server RSS (limit on its buffer {args.viewer_memory}): max {top:.0f} MB; "
            f"mean over the first tenth of the run {sum(s for _, s in first) / len(first):.0f} MB, "
            f"over the last tenth {sum(s for _, s in last) / len(last):.0f} MB ({len(srv)} samples)"
        )
        marks = [srv[min(len(srv) - 1, round(q * (len(srv) - 1) / 10))] for q in range(11)]
        print("viewer server RSS over the run: " + ", ".join(f"{t:.0f} s {m:.0f} MB" for t, m in marks))
    if own:
        print(f"mission process RSS: max {max(m for _, m in own):.0f} MB, at the end {own[-1][1]:.0f} MB")
    if cost:
        print(f"logging one step of {args.drones} drones: {cost[0]:.1f} ms CPU, {cost[1]:.1f} ms wall")


def log_cost(folder: Path, rrd: Path) -> tuple[float, float]:
    """CPU and wall ms per step of logging the mission's folder to an .rrd (`record DIR`)."""
    from swarmraft.experiments.mission_folder import read_mission
    from swarmraft.viz.live import record_mission

    m = read_mission(folder)
    c0, t0 = time.process_time(), time.perf_counter()
    steps = record_mission(m.log, m.errors, rrd)
    return (time.process_time() - c0) / steps * 1000, (time.perf_counter() - t0) / steps * 1000


if __name__ == "__main__":
    main()
