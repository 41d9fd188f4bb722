"""An attack written outside SwarmRaft, as docs/models.md ("Writing an attack") shows: one
spoofing transmitter moves all its victims together, every attacker reporting its own fix
shifted by the same offset (a uniform direction, magnitude uniform in [low, high], drawn per
trial).

Use it from Python after ``import common_shift`` (then ``build_config(..., attack={"name":
"common-shift"})`` and ``run_sweep``), or from the command line once a package declares it as
an entry point:

    [project.entry-points."swarmraft.attacks"]
    common_shift = "common_shift"
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarmraft.experiments.config import AttackConfig, register_attack
from swarmraft.world import Attack
from swarmraft.world.attacks import random_directions


@dataclass(frozen=True)
class CommonShift:
    """A position attack (`world.attacks.PositionAttack`): the reports (T, n, 3) attackers send."""

    low: float
    high: float

    def reports(self, rng: np.random.Generator, truth, reported, attackers):  # noqa: ANN001, ANN201
        T = truth.shape[0]
        shift = random_directions(rng, T) * rng.uniform(self.low, self.high, (T, 1))  # every draw from rng
        return np.where(attackers[..., None], reported + shift[:, None, :], reported)


@register_attack("common-shift")
def common_shift(config: AttackConfig) -> Attack:
    # the sweep's [attack] low and high (10-100 m by default); its own settings, if it had
    # any, would come in config.params
    return Attack(CommonShift(config.low, config.high))
