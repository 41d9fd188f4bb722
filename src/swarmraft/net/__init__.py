"""The networked runtime: the datagram format (`wire`), signing and checking datagrams with
anti-replay (`auth`), key files (`keys`), the UDP transport (`transport`), the swarm file
(`swarmfile`), one drone process driving `protocol.SwarmDrone` and `raft.RaftNode` over them
(`node`), and a swarm of such processes on one machine (`launch`). See docs/net.md."""
