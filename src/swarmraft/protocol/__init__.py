"""The SwarmRaft drone: signed reports, the leader's verification into a StepRecord, and the
replicated state machine that applies committed records. Uses `raft` and `estimation`."""

from swarmraft.protocol.drone import Applied, ProtocolConfig, SwarmDrone
from swarmraft.protocol.records import Report, StepRecord, reports_digest
from swarmraft.protocol.signing import Keyring

__all__ = ["Applied", "Keyring", "ProtocolConfig", "Report", "StepRecord", "SwarmDrone", "reports_digest"]
