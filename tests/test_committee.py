"""The voting committee's rules (protocol.committee): who votes first, and the one change a
leader proposes when a voter dies, a learner catches up or a drone comes back."""

import pytest

from swarmraft.protocol.committee import initial_committee, next_change
from swarmraft.raft.membership import ConfChange, ConfChangeType, ConfState

PROMOTE, REMOVE, ADD = ConfChangeType.PROMOTE, ConfChangeType.REMOVE, ConfChangeType.ADD_LEARNER
SWARM = tuple(range(1, 10))


def change(conf, silent=None, caught_up=SWARM, swarm=SWARM, leader=1, size=5, dead_after_s=1.0, leaving=()):
    return next_change(conf, leader, swarm, silent or {}, caught_up, size, dead_after_s, leaving)


def test_the_lowest_ids_vote_first():
    assert initial_committee((9, 3, 1, 7, 5, 2, 4), 5) == ConfState((1, 2, 3, 4, 5), (7, 9))
    assert initial_committee((2, 1), 5) == ConfState((1, 2), ())


@pytest.mark.parametrize("size", [0, 2, 9, -1])
def test_committee_size_must_be_odd_and_at_most_7(size):
    with pytest.raises(ValueError, match="odd"):
        initial_committee(SWARM, size)


def test_a_healthy_committee_is_left_alone():
    assert change(initial_committee(SWARM, 5)) is None


def test_a_dead_voter_is_replaced_by_a_promoted_learner_then_removed():
    conf = initial_committee(SWARM, 5)
    silent = {3: 1.5}
    cc = change(conf, silent)
    assert cc == ConfChange(PROMOTE, 6)  # the lowest live caught-up learner
    conf = conf.apply(cc)
    cc = change(conf, silent)
    assert cc == ConfChange(REMOVE, 3)
    conf = conf.apply(cc)
    assert conf.voters == (1, 2, 4, 5, 6) and change(conf, silent) is None


def test_silence_shorter_than_the_limit_is_not_death():
    assert change(initial_committee(SWARM, 5), {3: 0.9}) is None


def test_only_a_caught_up_live_learner_is_promoted():
    conf = initial_committee(SWARM, 5)
    assert change(conf, {3: 2.0, 6: 2.0}, caught_up=(6, 7, 8)) == ConfChange(PROMOTE, 7)
    assert change(conf, {3: 2.0}, caught_up=()) is None  # nobody can take its place: keep it


def test_the_leader_itself_is_never_dead():
    conf = initial_committee(SWARM, 5)
    assert change(conf, {1: 10.0}, leader=1) is None


def test_a_drone_back_in_the_swarm_rejoins_as_a_learner():
    conf = ConfState((1, 2, 4, 5, 6), (7, 8, 9))  # 3 was removed while it was down
    assert change(conf) == ConfChange(ADD, 3)
    assert change(conf, {3: 5.0}) is None  # still silent: not added


def test_a_joining_drone_is_added_as_a_learner_and_waits_for_a_place():
    conf = initial_committee(range(1, 9), 5)  # drone 9 is not in the swarm yet
    assert change(conf, swarm=range(1, 9)) is None
    conf = conf.apply(change(conf))  # it joins: the swarm is 1..9
    assert conf == ConfState((1, 2, 3, 4, 5), (6, 7, 8, 9)) and change(conf) is None


def test_a_leaving_voter_is_replaced_first_then_removed():
    conf = initial_committee(SWARM, 5)
    swarm = [i for i in SWARM if i != 3]
    steps = []
    while (cc := change(conf, swarm=swarm, leaving={3})) is not None:
        steps.append(cc)
        conf = conf.apply(cc)
    assert steps == [ConfChange(PROMOTE, 6), ConfChange(REMOVE, 3)]
    assert conf == ConfState((1, 2, 4, 5, 6), (7, 8, 9))


def test_a_leaving_voter_waits_for_a_learner_catching_up_but_not_for_none():
    conf = initial_committee(SWARM, 5)
    swarm = [i for i in SWARM if i != 3]
    assert change(conf, swarm=swarm, leaving={3}, caught_up=()) is None  # 6-9 are catching up
    alone = ConfState((1, 2, 3, 4, 5))  # no learner at all: it goes at once
    assert change(alone, swarm=(1, 2, 4, 5), leaving={3}) == ConfChange(REMOVE, 3)


def test_a_leaving_learner_is_removed_and_never_added_back():
    conf = initial_committee(SWARM, 5)
    swarm = [i for i in SWARM if i != 8]
    assert change(conf, swarm=swarm, leaving={8}) == ConfChange(REMOVE, 8)
    conf = conf.apply(ConfChange(REMOVE, 8))
    assert change(conf, swarm=swarm) is None  # a new leader hears "everyone": 8 is not in the swarm


def test_the_leader_never_removes_itself_but_prepares_its_place():
    conf = initial_committee(SWARM, 5)
    swarm = [i for i in SWARM if i != 1]
    assert change(conf, swarm=swarm, leaving={1}) == ConfChange(PROMOTE, 6)
    assert change(conf.apply(ConfChange(PROMOTE, 6)), swarm=swarm, leaving={1}) is None


def test_without_a_committee_every_caught_up_learner_votes_and_a_leaver_goes_at_once():
    conf, swarm = ConfState((1, 2, 3, 4), (5,)), (1, 2, 3, 4, 5)
    assert change(conf, size=None, swarm=swarm) == ConfChange(PROMOTE, 5)
    assert change(conf, size=None, swarm=swarm, caught_up=()) is None
    left = (1, 3, 4, 5)
    assert change(conf, size=None, swarm=left, caught_up=(), leaving={2}) == ConfChange(REMOVE, 2)
    assert change(ConfState((1, 2, 3, 4)), {3: 9.0}, size=None, swarm=swarm[:4]) is None  # a dead voter stays
