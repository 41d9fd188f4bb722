"""A Raft core as a pure state machine in the style of etcd-io/raft: no I/O, no clock, no
global randomness. Knows nothing of drones."""

from swarmraft.raft.log import RaftLog, RaftSafetyError
from swarmraft.raft.node import Progress, RaftNode
from swarmraft.raft.storage import MemoryStorage, SQLiteStorage, Storage
from swarmraft.raft.types import (
    Entry,
    EntryKind,
    HardState,
    Message,
    MsgType,
    NotLeader,
    RaftConfig,
    Ready,
    Role,
    Status,
)

__all__ = [
    "Entry",
    "EntryKind",
    "HardState",
    "MemoryStorage",
    "Message",
    "MsgType",
    "NotLeader",
    "Progress",
    "RaftConfig",
    "RaftLog",
    "RaftNode",
    "RaftSafetyError",
    "Ready",
    "Role",
    "SQLiteStorage",
    "Status",
    "Storage",
]
