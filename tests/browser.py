"""A headless Chromium for tests that look at what a person would see: the live viewer and the
HTML report.

`make test` installs Debian's `chromium` when it is missing (Playwright's own browser download
cannot work without internet), and Playwright drives that binary through ``executable_path``.
A missing browser fails the test with the command that installs it; it is never a skip.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

# What a machine with a closed network needs: no sandbox (root in CI), no GPU (software WebGL),
# and none of Chromium's background connections, each of which this network refuses.
CHROMIUM_ARGS = (
    "--no-sandbox",
    "--disable-gpu",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


def chromium_path() -> str:
    """The system Chromium, or a test failure that says how to install it."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    pytest.fail(
        "no chromium on PATH: `make test` installs it (apt-get install -y chromium); "
        "browser tests fail rather than skip without it"
    )


@contextmanager
def chromium_page(width: int = 1280, height: int = 800) -> Iterator:
    """A fresh headless page in a fresh profile; closed (and the profile removed) on exit."""
    from playwright.sync_api import sync_playwright

    executable = chromium_path()
    with tempfile.TemporaryDirectory(prefix="swarmraft-chromium-") as profile, sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            profile,
            executable_path=executable,
            headless=True,
            args=list(CHROMIUM_ARGS),
            viewport={"width": width, "height": height},
            env={**os.environ, "HOME": profile},
        )
        try:
            page = context.new_page()
            yield page
        finally:
            context.close()
