"""A neighbour whose measurements lag (issue 39's ``stale``: a box re-sending an old frame's
message as new) is found by the lag of its measurements behind the node's estimates, estimated
by least squares on the node's velocities (edge_node/core/trust.py, "Lag"); an honest neighbour
with late messages, noisy detections and a poor registration is not."""
import numpy as np
import pytest

from edge_node.core import TrackerConfig
from edge_node.core.trust import LAGGING, QUARANTINED, TRUSTED, lag_estimate
from edge_node.faults import FaultyNode
from edge_node.forgery import Forger
from fakes import det, graph, make_nodes
from protocol import codec

FPS = 25.0
START = 40  # the frame node 2 turns stale
# four people 1 m/s in four directions (a lag is told from an offset by velocities that differ)
WALKERS = [((1.0, 2.0), (1.0, 0.0)), ((8.0, 1.0), (0.0, 1.0)), ((9.0, 8.0), (-1.0, 0.0)),
           ((2.0, 9.0), (0.0, -1.0))]


def walk(frames, lag=None, delay=0, offset=(0.0, 0.0), noise=0.0, cfg=None):
    """Three nodes, each neighbour of the others, every camera seeing ``WALKERS``. Node 2 is
    stale from ``START`` with ``lag`` frames (None: honest); its messages reach the others
    ``delay`` frames late (their own frame number kept; the nodes take late messages), its
    camera's calibration is off by ``offset`` metres and its detections carry ``noise`` metres of
    position noise. Returns the nodes."""
    nodes = make_nodes(graph("complete", 3), cfg or TrackerConfig(), offsets={2: offset})
    n2 = nodes[2]
    forger = (Forger([FaultyNode(2, "stale", START, None, lag=lag)], n2.cameras[0], 1.0,
                     1.0 / FPS) if lag else None)
    rng = np.random.default_rng(11)
    pending = []  # node 2's messages on their way: (frame due, wire)
    for k in range(frames):
        t = k / FPS
        where = [(x + vx * t, y + vy * t) for (x, y), (vx, vy) in WALKERS]
        dets = {i: [det(x + (noise * rng.normal() if i == 2 else 0.0),
                        y + (noise * rng.normal() if i == 2 else 0.0), p, rng)
                    for p, (x, y) in enumerate(where)] for i in nodes}
        msgs = {i: n.prepare(k, dets[i]) for i, n in nodes.items()}
        if forger is not None:
            msgs[2] = forger.message(k, msgs[2])
        wire = {i: codec.encode(m) for i, m in msgs.items()}
        pending.append((k + delay, wire[2]))
        due = [w for kk, w in pending if kk == k]
        pending = [(kk, w) for kk, w in pending if kk > k]
        for i, n in nodes.items():
            inbox = [codec.decode(wire[j], expect_sender=j) for j in n.neighbours if j != 2]
            if i != 2:
                inbox += [codec.decode(w, expect_sender=2) for w in due]
            n.update(inbox, stale_ok=delay > 0)
    return nodes


def test_a_neighbour_lagging_twenty_frames_is_found_twenty_frames_behind_and_quarantined():
    """Node 2 re-sends from ``START`` the message of 20 frames ago: its measurements of people
    walking 1 m/s in four directions are 0.8 m behind where they are, a lag of 20 / 25 = 0.8 s
    behind the honest nodes' own cameras (whatever its information does to their estimates:
    both lags are taken against the same estimates). Without online registration (which
    otherwise lets the honest cameras' offsets follow the estimates a little) the estimate is
    within 2.5 frames (0.1 s) of 0.8 s; the honest neighbour's is 0. Its excess over
    ``trust_lag`` 0.3 s is several standard errors (each lag's about 1.7 frames) once the
    estimate has filled (it remembers about 50 frames): its lag's CUSUM passes ``trust_suspect``
    and ``trust_quarantine`` within 70 frames of ``START``, for the reason ``lagging``; nobody
    is suspected before ``START``."""
    for cfg in (TrackerConfig(registration=False), TrackerConfig()):
        nodes = walk(START + 120, lag=20, cfg=cfg)
        for i in (0, 1):
            t = nodes[i].trust.of[2]
            assert t.state == QUARANTINED and t.reason == LAGGING and t.lagging_frames > 0
            assert START < t.changes[0][0] and t.first_quarantine <= START + 70
            honest = nodes[i].trust.of[1 - i]
            assert honest.state == TRUSTED and not honest.changes and abs(honest.lag) < 0.1 / FPS
        if not cfg.registration:
            assert nodes[0].trust.of[2].lag == pytest.approx(20 / FPS, abs=2.5 / FPS)
        else:
            assert 15 / FPS < nodes[0].trust.of[2].lag < 21 / FPS
    summary = nodes[0].stats.trust[2]
    assert summary["reason"] == LAGGING and summary["lagging_frames"] > 0


def test_a_stale_neighbour_is_trusted_again_once_its_frames_are_fresh():
    """A lag of 20 frames for 80 frames, then fresh messages again: node 2 is quarantined, and
    its lag's sum, bounded at twice ``trust_quarantine``, falls once the estimate has forgotten
    the old frames (``trust_lag_frames``); after ``trust_readmit`` calm frames node 2 is
    trusted again, with its lag back within 2 frames of 0."""
    cfg = TrackerConfig()
    nodes = make_nodes(graph("complete", 3), cfg)
    n2 = nodes[2]
    forger = Forger([FaultyNode(2, "stale", START, START + 80, lag=20)], n2.cameras[0], 1.0,
                    1.0 / FPS)
    rng = np.random.default_rng(11)
    for k in range(START + 260):
        t = k / FPS
        where = [(x + vx * t, y + vy * t) for (x, y), (vx, vy) in WALKERS]
        if t > 5.0:  # back and forth, to stay in view
            where = [(x + vx * (10.0 - t), y + vy * (10.0 - t)) for (x, y), (vx, vy) in WALKERS]
        msgs = {i: n.prepare(k, [det(x, y, p, rng) for p, (x, y) in enumerate(where)])
                for i, n in nodes.items()}
        msgs[2] = forger.message(k, msgs[2])
        for i, n in nodes.items():
            n.update([codec.decode(codec.encode(msgs[j]), expect_sender=j) for j in n.neighbours])
    for i in (0, 1):
        t = nodes[i].trust.of[2]
        assert [s for _, s in t.changes][-1] == TRUSTED and t.first_quarantine is not None
        assert abs(t.lag) < 2 / FPS


def test_an_honest_neighbour_late_noisy_and_poorly_registered_is_not_lagging():
    """Node 2 honest, but its messages arrive 3 frames late (0.12 s, their frame number true),
    its calibration 0.3 m off and its detections 5 cm noisy: its measurements are 0.12 m behind
    where the people are when heard, which the frame number explains, and 0.3 m off, which the
    offset explains. Its estimated lag stays within a frame of 0 and it is never suspected."""
    nodes = walk(START + 90, delay=3, offset=(0.3, 0.0), noise=0.05)
    for i in (0, 1):
        t = nodes[i].trust.of[2]
        assert t.state == TRUSTED and not t.changes and t.lagging_frames == 0
        assert abs(t.lag) < 1 / FPS


def test_the_lag_by_least_squares_by_hand():
    """Normal equations written out for two entries (``W = I``): velocities (1, 0) and (0, 1),
    innovations ``e = b - tau v`` with ``b = (0.2, -0.1)`` and ``tau = 0.5``: (-0.3, -0.1) and
    (0.2, -0.6). Exactly fitted (3 unknowns, 4 equations, no residual): tau = 0.5, variance
    ``1 / (v^T v - v^T (sum W)^-1 v summed)`` = 1 / (2 - 1) = 1."""
    v = np.array([[1.0, 0.0], [0.0, 1.0]])
    e = np.array([0.2, -0.1]) - 0.5 * v
    N = np.array([2.0, 0.0, 2.0, -1.0, -1.0, 2.0])  # sum W, -sum W v, sum v^T W v
    r = np.array([e[:, 0].sum(), e[:, 1].sum(), -(v * e).sum(), (e * e).sum(), 2.0])
    tau, var = lag_estimate(N, r)
    assert tau == pytest.approx(0.5) and var == pytest.approx(1.0)
    # one velocity only: a lag cannot be told from an offset
    assert lag_estimate(np.array([1.0, 0.0, 1.0, -1.0, 0.0, 1.0]),
                        np.array([0.5, 0.0, -0.5, 0.25, 1.0]))[1] == float("inf")
