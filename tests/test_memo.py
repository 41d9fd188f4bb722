"""The protocol's memos (`protocol.memo`): what they return must be what computing again gives."""

from __future__ import annotations

import hashlib
import sys
import threading

import pytest

from swarmraft.protocol import memo
from swarmraft.protocol.memo import DIGESTS_KEPT, BoundedMemo, record_digest


def test_a_bounded_memo_forgets_its_oldest_items():
    m = BoundedMemo(3)
    for k in range(5):
        m[k] = k * k
    assert list(m.items()) == [(2, 4), (3, 9), (4, 16)]
    with pytest.raises(ValueError, match="limit"):
        BoundedMemo(0)


def test_a_bounded_memo_written_from_several_threads_stays_whole_and_bounded():
    """A networked drone writes the same memos from its event loop and its audit thread
    (record digests, signature checks, re-runs). Forgetting the oldest item is two steps (find
    it, delete it): without a lock a thread switch between them raised KeyError or
    "dictionary changed size during iteration" in a writer, and the memo outgrew its limit."""
    m = BoundedMemo(2)
    errors: list[str] = []

    def write(base: int) -> None:
        try:
            for i in range(30_000):
                m[(base, i)] = i
        except Exception as e:  # noqa: BLE001 - any exception is the failure
            errors.append(repr(e))

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads as often as the interpreter can
    try:
        threads = [threading.Thread(target=write, args=(b,)) for b in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        sys.setswitchinterval(interval)
    assert errors == []
    assert len(m) <= 2
    assert all(m[k] == k[1] for k in m)


def test_a_record_digest_is_its_sha256_computed_once_per_bytes_object(monkeypatch):
    calls = []
    real = hashlib.sha256

    def counting(data):  # noqa: ANN001, ANN202
        calls.append(bytes(data))
        return real(data)

    monkeypatch.setattr(memo.hashlib, "sha256", counting)
    data = bytes(range(200)) * 50
    assert record_digest(data) == real(data).digest()
    assert record_digest(data) == real(data).digest() and len(calls) == 1  # remembered
    same = bytes(bytearray(data))  # equal bytes, another object: digested again, the same
    assert same is not data and record_digest(same) == real(data).digest() and len(calls) == 2
    other = data[:-1] + b"x"
    assert record_digest(other) == real(other).digest()
    # bytes that can change are never remembered
    buf = bytearray(data)
    assert record_digest(buf) == real(data).digest()
    buf[0] ^= 1
    assert record_digest(buf) == real(bytes(buf)).digest()
    # only the newest DIGESTS_KEPT objects are held (each keeps its bytes alive)
    held = [bytes([k]) * 100 for k in range(DIGESTS_KEPT + 5)]
    for b in held:
        assert record_digest(b) == real(b).digest()
    assert len(memo._digests) == DIGESTS_KEPT
    n = len(calls)
    assert record_digest(data) == real(data).digest() and len(calls) == n + 1  # forgotten
