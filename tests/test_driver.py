"""The one frame driver (``edge_node/driver.py``) both shells use: a neighbour that came back
gets the whole frame with appearance, once; a resync for a neighbour that is down again is
forgotten; a neighbour whose frames jump is resynced at the next send; and a lockstep loop of
drivers gives the in-process network's tracks exactly."""
from __future__ import annotations

import numpy as np

from edge_node.core import CameraNode, TrackerConfig
from edge_node.driver import FrameDriver
from fakes import det, graph, topdown_camera
from protocol import codec


def _pair(cfg=None):
    cfg = cfg or TrackerConfig()
    return {i: FrameDriver(CameraNode(topdown_camera(i), (1 - i,), cfg, "t"), (1 - i,))
            for i in (0, 1)}


def _frame(drivers, k, dets, live=None):
    """Every driver sends, then every driver receives: the in-process network's order."""
    arrived = {i: [] for i in drivers}
    sent = {}
    for i, d in drivers.items():
        out, resync = d.send(d.prepare(k, dets.get(i, [])), live=live)
        sent[i] = resync
        for dst, payload in d.due(k) + out:
            arrived[dst].append(codec.decode(payload, expect_network="t", expect_sender=i))
    return {i: d.receive(k, arrived[i]) for i, d in drivers.items()}, arrived, sent


def _descriptors(rng, k):
    return {0: [det(2.0 + 0.04 * k, 3.0, 7, rng)], 1: [det(2.0 + 0.04 * k, 3.0, 7, rng)]}


def test_a_neighbour_that_came_back_gets_every_tracker_with_its_appearance_once():
    d = _pair()
    rng = np.random.default_rng(0)
    for k in range(30):
        _frame(d, k, _descriptors(rng, k))
    (tid,) = {t.id for t in d[0].node.tracks()}
    # node 1 restarts with an empty core; node 0 is told it came back
    d[1] = FrameDriver(CameraNode(topdown_camera(1), (0,), TrackerConfig(), "t",
                                  first_counter=d[1].node.next_counter), (0,))
    d[0].rejoined({1})
    tracks, arrived, sent = _frame(d, 30, _descriptors(rng, 30))
    assert sent[0] == {1} and d[0].outbox.counters.resyncs == 1
    (msg,) = arrived[1]
    assert [t.id for t in msg.trackers] == [tid] and msg.trackers[0].appearance is not None
    assert {t.id for t in tracks[1]} == {tid}  # it adopted the network's tracker, same id
    tracks, arrived, sent = _frame(d, 31, _descriptors(rng, 31))
    assert sent[0] == set() and arrived[1][0].trackers[0].appearance is None  # once


def test_a_resync_for_a_neighbour_that_is_down_again_is_forgotten():
    d = _pair()
    rng = np.random.default_rng(1)
    for k in range(5):
        _frame(d, k, _descriptors(rng, k))
    d[0].rejoined({1})
    _, _, sent = _frame(d, 5, _descriptors(rng, 5), live=set())
    assert sent[0] == set() and d[0].outbox.counters.resyncs == 0
    _, _, sent = _frame(d, 6, _descriptors(rng, 6))
    assert sent[0] == set() and d[0].outbox.counters.resyncs == 0


def test_a_neighbour_whose_frames_jump_is_resynced_at_the_next_send():
    cfg = TrackerConfig()
    d = _pair(cfg)
    rng = np.random.default_rng(2)
    for k in range(3):
        _frame(d, k, _descriptors(rng, k))
    # node 1 is heard again kappa + 2 frames later (it froze and skipped ahead)
    k = 3 + cfg.kappa + 2
    late = d[1].node
    d[1] = FrameDriver(CameraNode(topdown_camera(1), (0,), cfg, "t",
                                  first_counter=late.next_counter), (0,))
    for j in range(3, k):  # node 0 alone meanwhile
        d[0].prepare(j, _descriptors(rng, j)[0])
        d[0].receive(j, [])
    _frame(d, k, _descriptors(rng, k))
    assert d[0].outbox.counters.resyncs == 0  # heard the jump at frame k ...
    _, arrived, _ = _frame(d, k + 1, _descriptors(rng, k + 1))
    assert d[0].outbox.counters.resyncs == 1  # ... resynced at the next send
    resynced = arrived[1][0].trackers
    assert resynced and all(t.appearance is not None for t in resynced)


def test_lockstep_drivers_give_the_in_process_networks_tracks():
    """A ring of three driven here frame by frame equals ``run_network`` on the same scene."""
    from sim_cluster.network.inprocess import run_network
    from sim_cluster.scenarios.loader import load_scenario
    data = load_scenario("lab-sim", 0)
    frames = 40
    cfg = TrackerConfig().with_(fps=data.fps, units_per_metre=data.units_per_metre)
    adj = graph("ring", data.num_cameras)
    ref = run_network(data, adj, cfg, frames=frames, network="sim")
    d = {i: FrameDriver(CameraNode(data.cameras[i], adj[i], cfg, "sim"), adj[i])
         for i in adj}
    for k in range(frames):
        dets = data.frame(k).detections
        arrived = {i: [] for i in d}
        for i, dr in d.items():
            out, _ = dr.send(dr.prepare(k, dets[i]))
            for dst, payload in dr.due(k) + out:
                arrived[dst].append(codec.decode(payload, expect_network="sim", expect_sender=i))
        for i, dr in d.items():
            tracks = dr.receive(k, arrived[i])
            want = ref.tracks[i][k]
            assert [t.id for t in tracks] == [t.id for t in want]
            for a, b in zip(tracks, want):
                np.testing.assert_array_equal(a.x, b.x)
