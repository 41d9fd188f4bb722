"""Which code this is: a SHA-256 of the package's source files, for the records of results
(a sweep's run.json) and for a swarm's drones, which must all run the same code (a voter
re-runs its leader's verification; another version's record would be refused as a lie)."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

ROOT = Path(__file__).resolve().parent


def add_package_sources(h: hashlib._Hash) -> None:
    """Feed ``h`` every source file of the package, by path, in sorted order."""
    for path in sorted(ROOT.rglob("*.py")):
        h.update(str(path.relative_to(ROOT)).encode())
        h.update(path.read_bytes())


@functools.cache
def source_sha256() -> str:
    """SHA-256 (hex) of the package's source files (`add_package_sources`)."""
    h = hashlib.sha256()
    add_package_sources(h)
    return h.hexdigest()
