"""A child process's output line by line with deadlines (the live-view tests): a reader thread
fills a queue, so a child that prints nothing cannot block a test past its deadline, and a
failure shows everything the child printed."""

from __future__ import annotations

import queue
import re
import signal
import subprocess
import threading
import time


def line_queue(proc: subprocess.Popen) -> queue.Queue:
    """The lines of ``proc``'s stdout, as they come (read by a daemon thread)."""
    q: queue.Queue = queue.Queue()

    def pump() -> None:
        for line in proc.stdout:  # type: ignore[union-attr]
            q.put(line)

    threading.Thread(target=pump, daemon=True).start()
    return q


def wait_line(q: queue.Queue, pattern: str, timeout_s: float, seen: list[str]) -> re.Match:
    """The first line matching ``pattern`` within ``timeout_s``; every line read is added to
    ``seen``. AssertionError with the output so far if none comes."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            line = q.get(timeout=0.5)
        except queue.Empty:
            continue
        seen.append(line)
        if m := re.search(pattern, line):
            return m
    raise AssertionError(f"no line matching {pattern!r} within {timeout_s:g} s; output:\n{''.join(seen)}")


def exit_code(proc: subprocess.Popen, q: queue.Queue, timeout_s: float, seen: list[str]) -> int:
    """``proc``'s exit status within ``timeout_s``. If it has not ended by then, SIGABRT (a
    child run with PYTHONFAULTHANDLER=1 prints every thread's stack) and AssertionError with
    everything it printed: where it hung, not only that it did."""
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        time.sleep(0.5)  # the reader thread's last lines
        while not q.empty():
            seen.append(q.get_nowait())
        raise AssertionError(f"still running {timeout_s:g} s on; output:\n{''.join(seen)}") from None
