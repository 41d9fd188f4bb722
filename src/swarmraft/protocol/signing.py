"""Report signatures: one Ed25519 key pair per drone (PyNaCl, chosen by the measurement in
`benchmarks/bench_crypto.py`: it verifies about twice as fast as `cryptography`). The leader
drops reports whose signature does not verify against the sender's public key. The same
32-byte seed is a drone's key for its reports and for its datagrams (`swarmraft.net.auth`).

A report is verified several times where it travels (its sender's censorship note, the
leader's note and inbox, each auditor's evidence check; in the simulator every drone shares
one keyring): `Keyring` remembers the outcome per (drone, signature, digest of the bytes) for
the last `MEMO_STEPS` steps' worth of signatures, so each signature is checked once."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np
from nacl.exceptions import BadSignatureError
from nacl.signing import SigningKey, VerifyKey

from swarmraft.protocol.memo import BoundedMemo
from swarmraft.protocol.records import Report

#: steps' worth of signature checks (one per drone and step, plus the record's) remembered
MEMO_STEPS = 32


@dataclass(frozen=True)
class Keyring:
    """Private keys of the drones this process speaks for, public keys of all."""

    private: dict[int, SigningKey]
    public: dict[int, VerifyKey]
    checked: BoundedMemo = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "checked", BoundedMemo(MEMO_STEPS * (len(self.public) + 1)))

    @classmethod
    def generate(cls, n: int, rng: np.random.Generator) -> Keyring:
        """Keys derived from the generator, so a seeded mission is reproducible."""
        private = {i: SigningKey(rng.bytes(32)) for i in range(n)}
        return cls(private, {i: k.verify_key for i, k in private.items()})

    def sign(self, report: Report) -> Report:
        """The report signed by its drone's private key. The signature is remembered as
        checked (a drone need not verify its own report when a record carries it back),
        where the keyring's public key of that drone is the private key's own."""
        key = self.private[report.drone]
        signed = replace(report, signature=key.sign(report.body()).signature)
        if self.public.get(report.drone) == key.verify_key:
            self.checked[(report.drone, signed.signature, hashlib.sha256(signed.body()).digest())] = True
        return signed

    def verify(self, report: Report) -> bool:
        return self.verify_bytes(report.drone, report.body(), report.signature)

    def sign_bytes(self, drone: int, data: bytes) -> bytes:
        """Drone ``drone``'s 64-byte signature over ``data`` (a leader signing its record)."""
        return self.private[drone].sign(data).signature

    def verify_bytes(self, drone: int, data: bytes, signature: bytes) -> bool:
        key = self.public.get(drone)
        if key is None:
            return False
        if not isinstance(signature, bytes | bytearray) or not isinstance(data, bytes | bytearray):
            return _check(key, data, signature)  # not bytes: refused there, nothing to remember
        memo = (drone, bytes(signature), hashlib.sha256(data).digest())
        ok = self.checked.get(memo)
        if ok is None:
            ok = self.checked[memo] = _check(key, data, signature)
        return ok


def _check(key: VerifyKey, data: bytes, signature: bytes) -> bool:
    try:
        key.verify(data, signature)
    except (BadSignatureError, ValueError, TypeError):
        return False
    return True
