"""Ground truth, sensors and attacks (numpy only). Every draw uses the generator passed in."""

from swarmraft.world.attacks import (
    AreaSpoof,
    Attack,
    DistanceEnlargement,
    Jump,
    RangeTamper,
    RigidCollusion,
    choose_attackers,
)
from swarmraft.world.geometry import flat_layer, formation, near_line, true_distances, uniform_cube
from swarmraft.world.gnss import GaussMarkov, GNSSModel
from swarmraft.world.ranging import ExactRanging, RSSIRanging, UWBRanging

__all__ = [
    "AreaSpoof",
    "Attack",
    "DistanceEnlargement",
    "ExactRanging",
    "GNSSModel",
    "GaussMarkov",
    "Jump",
    "RSSIRanging",
    "RangeTamper",
    "RigidCollusion",
    "UWBRanging",
    "choose_attackers",
    "flat_layer",
    "formation",
    "near_line",
    "true_distances",
    "uniform_cube",
]
