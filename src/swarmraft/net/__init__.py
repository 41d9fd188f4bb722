"""The networked runtime's foundation: the datagram format (`wire`), signing and checking
datagrams with anti-replay (`auth`), key files (`keys`) and the UDP transport (`transport`).
The node runtime that drives `protocol.SwarmDrone` over them is not built yet (docs/net.md)."""
