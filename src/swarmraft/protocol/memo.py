"""A memo (dict) that keeps only its newest items, for caches that must not grow with a
mission's length."""

from __future__ import annotations

import hashlib
import threading
from typing import Any


class BoundedMemo(dict):
    """A dict that forgets its oldest item (by insertion) once it holds more than ``limit``.
    For a memo of a pure function only: a forgotten item is computed again, to the same value.

    Writes may come from several threads (a networked drone's event loop and its audit
    thread share the record digests, signature checks and re-runs): an insertion and the
    forgetting it causes (find the oldest, delete it) hold a lock, so that no writer sees
    another's half-done forgetting. Reads (``get``, ``in``, ``[]``) are single dict
    operations and need none."""

    def __init__(self, limit: int) -> None:
        if limit < 1:
            raise ValueError("BoundedMemo: limit must be >= 1")
        super().__init__()
        self.limit = limit
        self._lock = threading.Lock()

    def __setitem__(self, key: Any, value: Any) -> None:
        with self._lock:
            super().__setitem__(key, value)
            while len(self) > self.limit:
                del self[next(iter(self))]


#: record bytes objects whose digest `record_digest` remembers (the newest)
DIGESTS_KEPT = 16
_digests = BoundedMemo(DIGESTS_KEPT)  # id(data) -> (data, its SHA-256)


def record_digest(data: bytes) -> bytes:
    """SHA-256 of a record's bytes, remembered for the last DIGESTS_KEPT bytes objects. A
    drone digests each record several times (has it passed, holding it, its evidence, its
    decoded copy), and in the simulator every drone holds the same bytes object: at 256
    drones these digests took 14 s of a 260 s mission. Remembered by the object itself (its
    id, checked by identity; bytes cannot change), so no other bytes can match."""
    if type(data) is not bytes:
        return hashlib.sha256(data).digest()
    hit = _digests.get(id(data))
    if hit is not None and hit[0] is data:
        return hit[1]
    digest = hashlib.sha256(data).digest()
    _digests[id(data)] = (data, digest)
    return digest
