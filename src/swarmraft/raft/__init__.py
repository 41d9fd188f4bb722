"""A Raft core as a pure state machine in the style of etcd-io/raft: no I/O, no clock, no
global randomness. Knows nothing of drones."""

from swarmraft.raft.log import RaftLog, RaftSafetyError
from swarmraft.raft.membership import ConfChange, ConfChangeType, ConfState
from swarmraft.raft.node import RaftNode
from swarmraft.raft.progress import Inflights, Progress
from swarmraft.raft.snapshots import SnapshotPolicy, pack_entries, unpack_entries
from swarmraft.raft.storage import Compacted, MemoryStorage, SQLiteStorage, Storage
from swarmraft.raft.types import (
    ConfChangeRefused,
    Entry,
    EntryKind,
    HardState,
    LeaderTransferring,
    Message,
    MsgType,
    NotLeader,
    ProposalDropped,
    RaftConfig,
    ReadState,
    Ready,
    Role,
    Snapshot,
    Status,
)

__all__ = [
    "ConfChange",
    "ConfChangeRefused",
    "ConfChangeType",
    "ConfState",
    "Compacted",
    "Entry",
    "EntryKind",
    "HardState",
    "LeaderTransferring",
    "Inflights",
    "MemoryStorage",
    "Message",
    "MsgType",
    "NotLeader",
    "Progress",
    "ProposalDropped",
    "RaftConfig",
    "RaftLog",
    "RaftNode",
    "RaftSafetyError",
    "ReadState",
    "Ready",
    "Role",
    "SQLiteStorage",
    "Snapshot",
    "SnapshotPolicy",
    "Status",
    "Storage",
    "pack_entries",
    "unpack_entries",
]
