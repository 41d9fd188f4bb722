"""Report signatures: one Ed25519 key pair per drone (the `cryptography` library). The leader
drops reports whose signature does not verify against the sender's public key."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from swarmraft.protocol.records import Report


@dataclass(frozen=True)
class Keyring:
    """Private keys of the drones this process speaks for, public keys of all."""

    private: dict[int, Ed25519PrivateKey]
    public: dict[int, Ed25519PublicKey]

    @classmethod
    def generate(cls, n: int, rng: np.random.Generator) -> Keyring:
        """Keys derived from the generator, so a seeded mission is reproducible."""
        private = {i: Ed25519PrivateKey.from_private_bytes(rng.bytes(32)) for i in range(n)}
        return cls(private, {i: k.public_key() for i, k in private.items()})

    def sign(self, report: Report) -> Report:
        return replace(report, signature=self.private[report.drone].sign(report.body()))

    def verify(self, report: Report) -> bool:
        key = self.public.get(report.drone)
        if key is None:
            return False
        try:
            key.verify(report.signature, report.body())
        except InvalidSignature:
            return False
        return True
