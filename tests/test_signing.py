"""Report signatures (`protocol.signing.Keyring`): the memo of checked signatures must give
what checking again would, and stay bounded."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from swarmraft.protocol import Keyring, Report
from swarmraft.protocol.signing import MEMO_STEPS


class CountingKey:
    """A public key that counts its signature checks."""

    def __init__(self, key) -> None:  # noqa: ANN001
        self.key, self.calls = key, 0

    def verify(self, data: bytes, signature: bytes) -> bytes:
        self.calls += 1
        return self.key.verify(data, signature)


def keyring(n: int = 4) -> Keyring:
    keys = Keyring.generate(n, np.random.default_rng(3))
    return Keyring(keys.private, {i: CountingKey(k) for i, k in keys.public.items()})


def report(keys: Keyring, step: int = 0, drone: int = 1) -> Report:
    return keys.sign(
        Report(step, drone, np.array([1.0, 2.0, 3.0]), "gnss", np.array([np.nan, 5.0, 6.0, 7.0]), None)
    )


def test_a_remembered_check_answers_only_the_same_bytes_and_signature() -> None:
    keys = keyring()
    good = report(keys)
    assert keys.verify(good) and keys.verify(good) and keys.verify(replace(good))
    assert keys.public[1].calls == 1  # checked once, then remembered
    # the same signature over other bytes, other bytes' signature, another drone's key: refused
    moved = replace(good, position=np.array([1.0, 2.0, 3.5]))
    assert not keys.verify(moved) and not keys.verify(moved)
    other = report(keys, step=1)
    assert keys.verify(other)
    assert not keys.verify(replace(other, signature=good.signature))
    assert not keys.verify(replace(good, drone=2))
    assert not keys.verify_bytes(1, good.body(), good.signature[:-1] + bytes([good.signature[-1] ^ 1]))
    assert not keys.verify_bytes(9, good.body(), good.signature)  # no such drone
    assert not keys.verify_bytes(1, good.body(), "not bytes")  # type: ignore[arg-type]
    assert keys.verify(good)


def test_the_memo_keeps_only_the_newest_checks() -> None:
    keys = keyring()
    limit = MEMO_STEPS * (4 + 1)
    first = report(keys, step=0)
    for step in range(limit + 10):
        assert keys.verify(report(keys, step=step))
    assert len(keys.checked) == limit
    calls = keys.public[1].calls
    assert keys.verify(first) and keys.public[1].calls == calls + 1  # forgotten: checked again


def test_a_report_body_is_encoded_once_and_a_replaced_report_encodes_its_own() -> None:
    keys = keyring()
    good = report(keys)
    body = good.body()
    assert good.body() is body  # kept, not encoded again
    assert Report.decode(good.encode()).body() == body  # what was signed is what is sent
    moved = replace(good, position=np.array([1.0, 2.0, 3.5]))
    assert moved.body() != body and moved.body()[:12] == body[:12]  # same header, new position


def test_a_drone_does_not_check_its_own_signature_again_unless_its_keys_disagree(monkeypatch) -> None:
    import swarmraft.protocol.signing as signing

    calls = []
    real = signing._check
    monkeypatch.setattr(signing, "_check", lambda *a: calls.append(1) or real(*a))
    keys = Keyring.generate(3, np.random.default_rng(5))
    own = report(keys, drone=1)
    assert keys.verify(own) and calls == []  # remembered when signed
    # a public key that is not the private key's: nothing remembered, the check refuses
    wrong = Keyring(keys.private, {**keys.public, 1: keys.public[2]})
    assert not wrong.verify(report(wrong, drone=1)) and calls == [1]


def test_a_decoded_report_keeps_its_bytes_only_where_they_are_its_encoding(monkeypatch) -> None:
    """A decoded report's `body` is the bytes it came in (not encoded again: an audit reads
    17 a step), which are its encoding; bytes with a header bit no decoder reads are not:
    such a report's body is encoded again, so its signature is checked over what it says."""
    keys = Keyring.generate(4, np.random.default_rng(1))
    good = report(keys)
    data = good.encode()
    got = Report.decode(data)
    calls = []
    real = Report._encode_body
    monkeypatch.setattr(Report, "_encode_body", lambda self: calls.append(1) or real(self))
    assert got.body() == data[: len(data) - 64] == real(got) and not calls and keys.verify(got)
    odd = bytearray(data)
    odd[9] |= 8  # the parts byte: a part no decoder reads
    back = Report.decode(bytes(odd))
    assert back.body() == good.body() != bytes(odd[: len(odd) - 64]) and calls == [1]
    assert keys.verify(back)  # the signature covers the encoding, which is the same
