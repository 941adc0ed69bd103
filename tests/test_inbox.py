"""The inbox of a camera process (``edge_node/runtime/inbox.py``), without Zenoh: the frame
window, where the network is however far ahead, skipping, and what late, lost and overflowing
messages count as."""
from __future__ import annotations

import pytest

from edge_node.runtime.inbox import FRESH_S, FrameInbox
from protocol.messages import FrameMessage


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def msg(sender: int, frame: int) -> FrameMessage:
    return FrameMessage("n", sender, frame, trackers=())


@pytest.fixture
def box():
    clock = Clock()
    b = FrameInbox(0, (1, 2), max_pending_frames=8, clock=clock)
    b.liveliness(1, gone=False)
    b.liveliness(2, gone=False)
    b.clock_ = clock
    return b


def test_the_network_frame_is_learnt_however_far_ahead(box):
    """A node frozen for hours hears its neighbours at frames far beyond its inbox's window
    (8 frames here, 256 by default): it still learns where they are. (The transport kept a
    neighbour's frame only within the window ahead, so a node stalled over ~10 s never
    learnt it and never caught up.)"""
    box.collect(0, timeout=0.0)
    for f in (90_000, 90_001):
        box.accept(1, msg(1, f))
        box.accept(2, msg(2, f + 5))
    assert box.network_frame() == 90_001  # the least of the fresh neighbours' newest frames
    box.skip_to(90_001)
    got = box.collect(90_001, timeout=0.0)
    assert sorted(got) == [1]  # neighbour 1's message of that frame waited in the inbox


def test_one_lying_neighbour_cannot_fling_the_node_ahead(box):
    box.accept(1, msg(1, 40))
    box.accept(2, msg(2, 10**12))  # forged
    assert box.network_frame() == 40
    assert box.network_lead() == 10**12  # the most advanced: the loop bounds what it does with it


def test_the_lead_is_the_most_advanced_fresh_neighbour(box):
    box.accept(1, msg(1, 3134))
    box.accept(2, msg(2, 3137))
    assert (box.network_frame(), box.network_lead()) == (3134, 3137)
    box.clock_.t += FRESH_S + 0.1
    box.accept(1, msg(1, 3135))  # 2 silent since: not fresh
    assert (box.network_frame(), box.network_lead()) == (3135, 3135)


def test_a_neighbour_not_heard_lately_does_not_count(box):
    box.accept(1, msg(1, 40))
    box.accept(2, msg(2, 500))
    box.clock_.t += FRESH_S + 0.1  # both silent since (frozen)
    assert box.network_frame() is None
    box.accept(2, msg(2, 550))
    assert box.network_frame() == 550
    box.liveliness(2, gone=True)  # gone: neither its frame nor its waiting count
    assert box.network_frame() is None


def test_skipping_drops_the_skipped_frames_as_skipped_not_late(box):
    box.collect(0, timeout=0.0)
    for f in range(1, 7):
        box.accept(1, msg(1, f))
    box.skip_to(5)
    c = box.counters()
    assert c["skipped"] == {"1->0": 4} and c["late"] == {}
    assert sorted(box.collect(5, timeout=0.0)) == [1]
    assert box.drain(6)[0].frame == 6


def test_the_window_keeps_the_frames_needed_next(box):
    box.collect(0, timeout=0.0)
    for f in range(1, 20):  # a flood of future frames from one neighbour
        box.accept(1, msg(1, f))
    assert box.counters()["overflow"] == {"1->0": 11}
    assert box.collect(1, timeout=0.0)[1].frame == 1  # the next frame was not pushed out
    assert box.network_frame() is not None


def test_late_duplicate_and_lost_are_counted(box):
    box.accept(1, msg(1, 0))
    box.accept(1, msg(1, 0))
    box.accept(2, msg(2, 1))  # 2's frame 0 never comes: a later frame shows it lost
    got = box.collect(0, timeout=5.0)  # returns at once: nobody left to wait for
    assert sorted(got) == [1]
    box.accept(1, msg(1, 0))  # after frame 0 was done: late
    c = box.counters()
    assert c["duplicates"] == {"1->0": 1} and c["lost"] == {"2->0": 1} and c["late"] == {"1->0": 1}


def test_a_neighbour_that_sent_nothing_is_waited_for_only_the_grace(box):
    """A paced node's first frame: neighbour 2 is alive but still in its own start-up (it sent
    nothing): not waited for past the grace, and waited for again once it is heard in time."""
    box.accept(1, msg(1, 0))
    got = box.collect(0, timeout=30.0, silent_grace=0.0)  # (a real wait would take 30 s)
    assert sorted(got) == [1] and box.counters()["timeouts"] == {}
    box.accept(2, msg(2, 1))
    box.accept(1, msg(1, 1))
    assert sorted(box.collect(1, timeout=30.0)) == [1, 2]


def test_one_message_far_ahead_does_not_stop_the_wait_for_its_sender(box):
    """A link delivers in order, so a neighbour's next frame shows its current one lost; one
    message a second ahead (forged: the zombie probe's flood came for frame k + 25) does not:
    the frame's message is still waited for (here: until the timeout), not taken for lost, and
    node 1 stopped fusing node 0 for a second before the flood."""
    box.accept(1, msg(1, 0))
    box.accept(2, msg(2, 25))
    assert sorted(box.collect(0, timeout=0.0)) == [1]
    c = box.counters()
    assert c["lost"] == {} and c["timeouts"] == {"2->0": 1}


def test_a_node_behind_every_neighbour_does_not_wait_for_the_frame_it_is_at(box):
    """Back from a freeze: every fresh neighbour is far ahead, so the frame's messages will not
    come (the node skips next); no timeout is waited (it cost a second of catch-up)."""
    box.accept(1, msg(1, 3100))
    box.accept(2, msg(2, 3101))
    assert box.collect(100, timeout=5.0) == {}  # returns at once
    c = box.counters()
    assert c["timeouts"] == {} and c["lost"] == {"1->0": 1, "2->0": 1}


def test_a_neighbour_back_from_a_freeze_far_behind_is_not_waited_for(box):
    """Neighbour 2 comes back from a freeze and sends its frame 100 while this node is at
    3100: it will skip to us, so frame 3100 does not wait the timeout for it (its neighbours
    stood still a second), and it is waited for again once it is in time."""
    box.accept(1, msg(1, 3100))
    box.accept(2, msg(2, 100))  # late: counted, and it tells where neighbour 2 is
    assert sorted(box.collect(3100, timeout=5.0)) == [1]  # at once
    assert box.counters()["timeouts"] == {}
    box.accept(1, msg(1, 3101))
    box.accept(2, msg(2, 3101))  # caught up: in time again
    assert sorted(box.collect(3101, timeout=5.0)) == [1, 2]


def test_a_neighbour_back_after_going_away_is_waited_for_only_a_moment(box):
    """Neighbour 2's liveliness went away (it froze) and came back, and nothing of it has come
    since: both sides' messages of that moment went out before the link was back, so waiting
    the whole timeout for it (as its neighbours and the frozen node itself did, each for the
    other: 1 s of a 30 s freeze's 1.5 s catch-up) gains nothing; after ``BACK_GRACE_S`` it is
    lagging, and it is waited for again once heard in time."""
    from edge_node.runtime.inbox import BACK_GRACE_S

    box.liveliness(2, gone=True)
    box.liveliness(2, gone=False)
    box.clock_.t += BACK_GRACE_S
    box.accept(1, msg(1, 852))
    assert sorted(box.collect(852, timeout=0.0)) == [1]  # not waited for: no timeout
    assert box.counters()["timeouts"] == {}
    box.accept(1, msg(1, 853))
    box.accept(2, msg(2, 853))  # in time again: waited for from now on
    assert sorted(box.collect(853, timeout=5.0)) == [1, 2]
    box.accept(1, msg(1, 854))
    assert sorted(box.collect(854, timeout=0.0)) == [1]
    assert box.counters()["timeouts"] == {"2->0": 1}


def test_a_neighbour_heard_since_it_came_back_is_waited_for_as_before(box):
    box.liveliness(2, gone=True)
    box.liveliness(2, gone=False)
    box.accept(2, msg(2, 9))  # heard since (a frame it is past): not a stranger
    box.clock_.t += 10.0
    box.accept(1, msg(1, 10))
    assert sorted(box.collect(10, timeout=0.0)) == [1]
    assert box.counters()["timeouts"] == {"2->0": 1}
