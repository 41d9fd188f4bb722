"""The protocol's memos (`protocol.memo`): what they return must be what computing again gives."""

from __future__ import annotations

import hashlib

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
