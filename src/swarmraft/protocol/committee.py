"""A voting committee for large swarms: a few voters, every other drone a Raft learner.

Raft's cost grows with its voters: every commit waits for a majority of them, and every
election asks all of them. etcd and Consul run 3-7 voters and keep the rest as non-voting
members. A swarm does the same: ``size`` drones (odd, at most 7) vote; the others are learners
that still report to the leader, receive the log and apply every committed record. The leader
verifies every drone's report whatever its role.

The rules are pure functions of what the leader knows, so every leader applies the same ones:

- `initial_committee`: the ``size`` lowest drone ids vote (every drone derives it from the
  swarm's list of ids alone, with nothing to agree on first);
- `next_change`: the one membership change the leader proposes now, if any. A voter the
  leader has not heard from for ``dead_after_s`` is replaced: first the lowest-id learner
  that is alive and caught up is promoted (the committee grows by one, so its quorum never
  depends on the dead voter more than before), then the dead voter is removed. A live member
  beyond the committee's size is demoted no further than that: once the committee is back to
  ``size`` voters nothing changes. A drone that is in the swarm but not a member (one that
  joins the swarm, or one removed when it was thought dead, and back) joins as a learner. A
  drone that leaves the swarm for good is removed: a voter once a learner took its place (or
  at once when none is left to wait for), never by itself as leader (it hands over first).

Who is in the swarm (joined and not left) is the mission's plan, the same for every drone, as
the list of ids `initial_committee` starts from: joins and leaves need no messages to agree on.
Only the leader proposes configuration changes (a follower's are not forwarded,
`RaftNode.propose_conf_change`): the order matters (promote before remove), and only the
leader knows who is caught up and whom it hears from.

Changes go one at a time (`raft.membership`: single-server changes; the leader refuses a new
one while one is uncommitted), so the leader calls `next_change` every step and proposes what
it returns.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

from swarmraft.raft.membership import ConfChange, ConfChangeType, ConfState

#: The largest committee: beyond 7 voters commits and elections slow down for no gain in
#: tolerated failures that a swarm needs (etcd's recommendation is the same).
MAX_COMMITTEE = 7


def check_size(size: int) -> None:
    if not (1 <= size <= MAX_COMMITTEE and size % 2 == 1):
        raise ValueError(f"committee size must be odd and in 1..{MAX_COMMITTEE}, got {size}")


def initial_committee(ids: Sequence[int], size: int) -> ConfState:
    """The first configuration: the ``size`` lowest ids vote, the rest are learners (all vote
    when there are no more than ``size``)."""
    check_size(size)
    ordered = sorted(ids)
    if len(set(ordered)) != len(ordered) or not ordered:
        raise ValueError("committee: drone ids must be distinct and at least one")
    return ConfState(tuple(ordered[:size]), tuple(ordered[size:]))


def next_change(
    conf: ConfState,
    leader: int,
    swarm: Collection[int],
    silent_s: Mapping[int, float],
    caught_up: Collection[int],
    size: int | None,
    dead_after_s: float,
    leaving: Collection[int] = (),
) -> ConfChange | None:
    """The change the leader should propose now, or None.

    ``swarm``: the ids of the drones in the swarm now (those that have joined and not left);
    ``silent_s[i]``: seconds since the leader last heard from drone i (its Raft answers, or
    its reports; a drone missing from it counts as just heard); ``caught_up``: the learners
    whose log is close enough to the leader's to be promoted; ``size``: the committee's size
    (None: no committee, every member votes: every caught-up learner is promoted and a dead
    voter is never removed). A dead voter stays while no learner can take its place: removing
    it would shrink the committee below ``size``, one failure closer to losing its quorum.

    ``leaving``: drones that left the swarm for good and are still members. A leaving learner
    is removed. A leaving voter is replaced as a dead one is (a live caught-up learner promoted
    first), but removed without a replacement when no live learner is left to wait for (a
    drone that left never answers again: keeping it a voter would only make the quorum wait for
    it; without a committee it is removed at once); the leader never removes itself (its host
    hands leadership over first)."""
    if size is not None:
        check_size(size)
    cap = size if size is not None else len(conf.members)
    gone = set(leaving)

    def alive(i: int) -> bool:
        return i not in gone and (i == leader or silent_s.get(i, 0.0) < dead_after_s)

    dead_voters = sorted(v for v in conf.voters if not alive(v) and v not in gone)
    leavers = sorted(v for v in conf.voters if v in gone and v != leader)
    ready = sorted(lr for lr in conf.learners if alive(lr) and lr in caught_up)
    staying = len(conf.voters) - len(dead_voters) - len(leavers) - (leader in gone)
    if staying < cap and ready:
        return ConfChange(ConfChangeType.PROMOTE, ready[0])
    if leavers and (size is None or len(conf.voters) > size or not any(alive(lr) for lr in conf.learners)):
        return ConfChange(ConfChangeType.REMOVE, leavers[0])
    if dead_voters and size is not None and len(conf.voters) > size:
        return ConfChange(ConfChangeType.REMOVE, dead_voters[0])
    if left := sorted(lr for lr in conf.learners if lr in gone):
        return ConfChange(ConfChangeType.REMOVE, left[0])
    back = sorted(i for i in set(swarm) - set(conf.members) if alive(i))
    if back:
        return ConfChange(ConfChangeType.ADD_LEARNER, back[0])
    return None
