"""The fault relay (`net.relay`) between plain UDP sockets on 127.0.0.1: it forwards to the
right drone, applies loss, duplication, delay, partitions and one-way cuts from the
simulator's link model, changes them while running, and draws from the seed it is given."""

import random
import socket
import time

import pytest

from swarmraft.net.launch import free_udp_ports
from swarmraft.net.relay import RelayThread
from swarmraft.sim.network import LinkModel


class Drones:
    """Three 'drones': bound sockets, with a relay between them."""

    def __init__(self, link: LinkModel, seed: int = 0, n: int = 3):
        self.socks = {}
        for i in range(1, n + 1):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            s.settimeout(0.01)
            self.socks[i] = s
        targets = {i: s.getsockname() for i, s in self.socks.items()}
        self.relay = RelayThread(targets, link, seed)
        self.via = self.relay.start()

    def send(self, frm: int, to: int, data: bytes) -> None:
        self.socks[frm].sendto(data, self.via[to])

    def received(self, i: int, wait_s: float = 0.3) -> list[bytes]:
        """What drone i has received, waiting until nothing came for ``wait_s``."""
        out, quiet_until = [], time.monotonic() + wait_s
        while time.monotonic() < quiet_until:
            try:
                data, _ = self.socks[i].recvfrom(65535)
            except TimeoutError:
                continue
            out.append(data)
            quiet_until = time.monotonic() + wait_s
        return out

    def close(self):
        self.relay.stop()
        for s in self.socks.values():
            s.close()


@pytest.fixture
def drones(request):
    link, seed = getattr(request, "param", (LinkModel((0.0, 0.0)), 0))
    d = Drones(link, seed)
    yield d
    d.close()


def test_it_forwards_each_datagram_to_its_drone_unchanged(drones):
    for k in range(20):
        drones.send(1, 2, b"to 2 #%d" % k)
        drones.send(3, 1, b"to 1 #%d" % k)
    assert sorted(drones.received(2)) == sorted(b"to 2 #%d" % k for k in range(20))
    assert sorted(drones.received(1)) == sorted(b"to 1 #%d" % k for k in range(20))
    assert drones.received(3, 0.05) == []
    c = drones.relay.counters()
    assert c["received"] == c["forwarded"] == 40 and c["foreign"] == 0


def test_partition_cut_and_heal_change_while_it_runs(drones):
    r = drones.relay
    r.call(r.relay.partition, [[1, 2], [3]])
    drones.send(1, 2, b"inside")
    drones.send(1, 3, b"across")
    drones.send(3, 1, b"across back")
    assert drones.received(2) == [b"inside"]
    assert drones.received(3, 0.05) == [] and drones.received(1, 0.05) == []
    r.call(r.relay.heal)
    r.call(r.relay.cut, 1, 3)  # one way
    drones.send(1, 3, b"cut")
    drones.send(3, 1, b"the other way")
    assert drones.received(3, 0.1) == [] and drones.received(1) == [b"the other way"]
    r.call(r.relay.heal)
    drones.send(1, 3, b"healed")
    assert drones.received(3) == [b"healed"]
    assert r.counters()["cut"] == 3


def test_a_stranger_passes_only_without_a_partition(drones):
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        stranger.sendto(b"hello", drones.via[2])
        assert drones.received(2) == [b"hello"]
        drones.relay.call(drones.relay.relay.partition, [[1, 2, 3]])
        stranger.sendto(b"hello again", drones.via[2])
        assert drones.received(2, 0.1) == []
        assert drones.relay.counters()["foreign"] == 2
    finally:
        stranger.close()


@pytest.mark.parametrize("drones", [(LinkModel((0.0, 0.0), loss=0.3, duplicate=0.3), 7)], indirect=True)
def test_loss_and_duplication_follow_the_link_model_and_its_seed(drones):
    sent, got = 400, []
    for batch in range(8):  # in batches, read as they come: within the sockets' buffers
        for k in range(50 * batch, 50 * batch + 50):
            drones.send(1, 2, b"%d" % k)
        got += drones.received(2, 0.1)
    c = drones.relay.counters()
    # the relay's own draws, replayed: the same seed gives the same copies
    rng, link = random.Random(7), LinkModel((0.0, 0.0), loss=0.3, duplicate=0.3)
    want = sum(len(link.delays(rng)) for _ in range(sent))
    assert len(got) == want == c["forwarded"]
    assert c["duplicated"] > 0 and c["lost"] > 0
    assert 0.55 * sent < len(set(got)) < 0.85 * sent  # about 1 - 0.3 (- 0.3 x 0.3 x 0.3) arrive


def test_delay_holds_each_datagram_back(drones):
    r = drones.relay
    r.call(r.relay.set_all, delay_ms=(150.0, 150.0))
    t0 = time.monotonic()
    drones.send(2, 3, b"late")
    drones.socks[3].settimeout(2.0)
    data, _ = drones.socks[3].recvfrom(100)
    assert data == b"late" and time.monotonic() - t0 >= 0.15


def test_it_binds_the_ports_it_is_given_and_releases_them_on_stop():
    ports = free_udp_ports(3)
    socks = []
    for _ in range(3):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    relay = RelayThread({i + 1: s.getsockname() for i, s in enumerate(socks)}, LinkModel(), 0)
    via = relay.start(ports={i + 1: p for i, p in enumerate(ports)})
    assert [via[i][1] for i in (1, 2, 3)] == ports
    relay.stop()
    for p in ports:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", p))
        s.close()
    for s in socks:
        s.close()


def test_a_drone_answers_a_stranger_back_through_the_relay(drones):
    """What a drone sends to its own relay port goes to the last outside address that reached
    that port, as through a NAT: how `swarmraft status` is answered through the relay."""
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.settimeout(2.0)
    try:
        stranger.sendto(b"how are you?", drones.via[2])
        assert drones.received(2) == [b"how are you?"]
        drones.socks[2].sendto(b"fine", drones.via[2])  # a drone answers the address it heard from
        data, addr = stranger.recvfrom(100)
        assert data == b"fine" and addr == drones.via[2]
        assert drones.relay.counters()["answered_outside"] == 1
        assert drones.received(2, 0.05) == []  # not looped back to the drone itself
    finally:
        stranger.close()
