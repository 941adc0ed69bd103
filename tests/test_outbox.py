"""The one sending path (edge_node/outbox.py) that both shells use."""
import numpy as np

from edge_node.core.trigger import EventTrigger, TriggerConfig
from edge_node.faults import FaultPlan
from edge_node.outbox import Outbox
from protocol import codec
from protocol.messages import FrameMessage, TrackerInfo


def msg(k, n_trackers=2, appearance=False, ell=0, u=1.0):
    infos = tuple(TrackerInfo((0, c), np.full(6, float(c)), np.r_[np.full(4, u), 0, 0],
                              np.diag([u] * 4 + [0, 0]), ell,
                              np.ones((2, 8)) if appearance else None, 0)
                  for c in range(n_trackers))
    return FrameMessage("net", 0, k, infos)


def test_sync_sends_the_same_bytes_to_every_neighbour_and_counts_them():
    ob = Outbox(0, (2, 1))
    out = ob.send(msg(0))
    payload = codec.encode(msg(0))
    assert out == [(1, payload), (2, payload)]
    c = ob.counters
    assert c.bytes_per_link == {1: len(payload), 2: len(payload)}
    assert (c.messages, c.frames_sent, c.tracker_entries) == (2, 1, 4)
    assert Outbox(0, ()).send(msg(0)) == []  # no neighbours, nothing to send


def test_faults_lose_delay_and_duplicate_per_link():
    plan = FaultPlan.from_dict({"link": [{"src": 0, "dst": 1, "delay": 2},
                                         {"src": 0, "dst": 2, "loss": 1.0},
                                         {"src": 0, "dst": 3, "duplicate": 1.0}]})
    ob = Outbox(0, (1, 2, 3), plan)
    out = ob.send(msg(5))
    assert [d for d, _ in out] == [3, 3]  # 1 is late, 2 lost, 3 twice
    assert ob.due(6) == []
    assert [d for d, _ in ob.due(7)] == [1]  # two frames late
    assert ob.due(7) == []  # delivered once
    assert ob.counters.messages == 3  # handed to three links, whatever the links then did


def test_a_rejoined_neighbour_gets_the_resync_message():
    ob = Outbox(0, (1, 2))
    out = dict(ob.send(msg(3), resync={2}, resync_message=lambda m: msg(3, appearance=True)))
    assert codec.decode(out[1]).trackers[0].appearance is None
    assert codec.decode(out[2]).trackers[0].appearance is not None
    assert ob.counters.appearance_entries == 2  # two trackers with appearance, on one link


def test_event_trigger_keeps_silent_and_counts_what_it_saved():
    trig = EventTrigger(TriggerConfig(heartbeat_frames=5), dt=0.04)
    ob = Outbox(0, (1,), trigger=trig)
    assert len(ob.send(msg(0))) == 1  # news: sent
    quiet = msg(1, u=0.0)  # nothing measured, no drift, no ell news
    quiet = FrameMessage("net", 0, 1, tuple(
        TrackerInfo(t.id, t.x_bar, np.zeros(6), np.zeros((6, 6)), 0, None, 0) for t in quiet.trackers))
    assert ob.send(quiet) == []
    assert ob.counters.frames_skipped == 1
    assert ob.counters.bytes_saved == len(codec.encode(quiet))


def test_a_message_that_breaks_the_wire_rules_is_counted_not_sent():
    bad = FrameMessage("net", 0, 0, (TrackerInfo((0, 0), np.full(6, np.nan), np.zeros(6),
                                                 np.zeros((6, 6)), 0),))
    ob = Outbox(0, (1,))
    assert ob.send(bad) == []
    assert ob.counters.encode_errors == 1 and "non_finite" in ob.last_error


def test_async_resync_sends_the_trackers_the_trigger_withheld():
    """Event-triggered: a neighbour that came back with an empty state gets every tracker of
    the frame at once, also in a frame the trigger keeps silent, each tracker with its
    appearance; the neighbour that stayed gets only what the trigger keeps (here nothing)."""
    from dataclasses import replace

    from edge_node.core.trigger import EventTrigger, TriggerConfig

    ob = Outbox(0, (1, 2), trigger=EventTrigger(TriggerConfig(heartbeat_frames=5), dt=0.04))
    ob.send(msg(0))  # both trackers are news once
    quiet = FrameMessage("net", 0, 1, tuple(
        TrackerInfo(t.id, t.x_bar, np.zeros(6), np.zeros((6, 6)), 0, None, 0)
        for t in msg(1).trackers))

    def with_appearance(m):
        return replace(m, trackers=tuple(replace(t, appearance=np.ones((2, 8)))
                                         for t in m.trackers))
    out = dict(ob.send(quiet, resync={2}, resync_message=with_appearance))
    assert sorted(out) == [2]  # the stayer: nothing (the trigger keeps this frame silent)
    got = codec.decode(out[2]).trackers
    assert [t.id for t in got] == [(0, 0), (0, 1)]
    assert all(t.appearance is not None for t in got)


def test_a_heartbeat_as_long_as_kappa_is_refused():
    """A receiver forgets an entry kappa frames after it: heartbeats must come sooner."""
    import pytest

    from edge_node.core.params import ConfigError
    from edge_node.core.trigger import EventTrigger, TriggerConfig

    EventTrigger(TriggerConfig(heartbeat_frames=14), dt=0.04, kappa=15)
    with pytest.raises(ConfigError, match="heartbeat_frames must be below tracker.kappa"):
        EventTrigger(TriggerConfig(heartbeat_frames=15), dt=0.04, kappa=15)
