"""Per-neighbour bounds and a node's own message: one message of thousands of plausible phantoms
must not make a node hold them all, nor make its own message unsendable; a neighbour whose
frames jump gets the resync (``edge_node/core/node.py``, ``edge_node/outbox.py``)."""
from __future__ import annotations

import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from edge_node.outbox import Outbox
from protocol import codec
from protocol.messages import FrameMessage, TrackerInfo
from sim_cluster.experiments import chaos
from tests.fakes import det, topdown_camera

PHANTOMS = 4096  # the codec's limit of trackers in one message


def phantom_message(sender: int, k: int, n: int = PHANTOMS) -> FrameMessage:
    return chaos.phantom_message("n", sender, k, n, seed=7)


def test_one_message_of_4096_phantoms_is_cut_and_adopted_at_a_bounded_rate():
    cfg = TrackerConfig()
    node = CameraNode(topdown_camera(0), [1], cfg, "n")
    msg = codec.decode(codec.encode(phantom_message(1, 0)))  # as it arrives: it is wire-valid
    node.prepare(0, [det(2.0, 3.0, 1)])
    node.update([msg])
    cap, rate = cfg.max_trackers_per_neighbour, cfg.max_adoptions_per_frame
    assert len(node.trackers) == rate  # 4,097 before (every phantom adopted in one frame)
    assert node.stats.rejected["too_many_trackers"] == PHANTOMS - cap
    assert node.stats.rejected["adoption_rate"] == cap - rate
    out = Outbox(0, [1])
    assert len(out.send(node.prepare(1, [det(2.0, 3.0, 1)]))) == 1  # it still sends
    node.update([])
    for k in range(2, 2 + cfg.kappa + 2):  # nobody tells of them again: gone within kappa
        node.prepare(k, [])
        node.update([])
    assert len(node.trackers) == 0


def test_the_trackers_a_node_holds_are_kept_first_when_a_message_is_cut():
    cfg = TrackerConfig(max_trackers_per_neighbour=8, max_adoptions_per_frame=8)
    node = CameraNode(topdown_camera(0), [1], cfg, "n")
    node.prepare(0, [])
    node.update([phantom_message(1, 0, n=4)])  # ids (1, 1000..1003) held
    assert len(node.trackers) == 4
    flood = phantom_message(1, 1, n=40)
    rows = list(flood.trackers)
    rows = rows[4:] + rows[:4]  # the held ids last in the message
    node.prepare(1, [])
    node.update([FrameMessage("n", 1, 1, tuple(rows))])
    assert {(1, 10**8 + i) for i in range(4)} <= set(node.trackers.ids())
    assert len(node.trackers) == 8


def test_our_own_message_over_the_limits_is_cut_to_fit_measured_first():
    limits = codec.Limits(max_trackers=100)
    infos = []
    for i in range(150):
        U = np.zeros((6, 6))
        u = np.zeros(6)
        if i % 30 == 7:  # five trackers this node measured, spread through the message
            U[:4, :4] = np.eye(4)
            u[:4] = [1.0, 2.0, 0.5, 1.7]
        infos.append(TrackerInfo((0, i), np.array([1.0, 2.0, 0.5, 1.7, 0.0, 0.0]), u, U, 0, born=0))
    out = Outbox(0, [1], limits=limits)
    sent = out.send(FrameMessage("n", 0, 3, tuple(infos)))
    assert len(sent) == 1 and out.counters.encode_errors == 0
    got = codec.decode(sent[0][1], limits=limits)
    ids = [t.id for t in got.trackers]
    assert len(ids) == 100 and out.counters.trackers_cut == 50
    assert {(0, i) for i in range(150) if i % 30 == 7} <= set(ids)  # every measured one kept
    assert ids == sorted(ids)  # in the message's order


def test_a_neighbour_whose_frames_jump_gets_the_resync():
    out = Outbox(0, [1, 2], rejoin_gap=15)
    full = lambda m: FrameMessage(m.network, m.sender, m.frame, m.trackers, sent_at=1.0)  # noqa: E731

    def send(k):
        return out.send(FrameMessage("n", 0, k), resync_message=full)

    for k in range(0, 10):
        out.heard([FrameMessage("n", 1, k), FrameMessage("n", 2, k)], k)
        assert {p for _, p in send(k)} == {codec.encode(FrameMessage("n", 0, k))}
    out.heard([FrameMessage("n", 1, 40), FrameMessage("n", 2, 24)], 40, stale_ok=True)  # 2: late
    out.heard([FrameMessage("n", 2, 25)], 40)  # sync: not this frame's, not taken
    sent = dict(send(41))
    assert codec.decode(sent[1]).sent_at == 1.0 and codec.decode(sent[2]).sent_at == 0.0
    assert out.counters.resyncs == 1
    assert codec.decode(dict(send(42))[1]).sent_at == 0.0  # once
