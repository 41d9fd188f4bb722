"""A memo (dict) that keeps only its newest items, for caches that must not grow with a
mission's length."""

from __future__ import annotations

from typing import Any


class BoundedMemo(dict):
    """A dict that forgets its oldest item (by insertion) once it holds more than ``limit``.
    For a memo of a pure function only: a forgotten item is computed again, to the same value."""

    def __init__(self, limit: int) -> None:
        if limit < 1:
            raise ValueError("BoundedMemo: limit must be >= 1")
        super().__init__()
        self.limit = limit

    def __setitem__(self, key: Any, value: Any) -> None:
        super().__setitem__(key, value)
        if len(self) > self.limit:
            del self[next(iter(self))]
