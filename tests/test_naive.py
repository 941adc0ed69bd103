"""A tracker a node knows only from its neighbours (no measurement information of its own or
theirs: Kalman-consensus's naive node) is gated with a covariance bounded by the drop counter
``ell`` (eq. 8) (``Associator.gate_covariances``, ``TrackerConfig.naive_bound``).

The figures are derived here from the configuration alone: the bound is ``calib_sigma^2 +
((ell + 1) dt birth_vel_sigma)^2`` on the position block's largest eigenvalue; the naive
tracker's own covariance grows from the birth prior by ``birth_vel_sigma`` per second."""
from __future__ import annotations

import numpy as np
import pytest

from edge_node.core import Detection, TrackerConfig
from fakes import SELECTIVE, box_at, make_nodes, step

CHAIN = {0: (1,), 1: (0, 2), 2: (1,)}


def walker(k: int) -> Detection:
    """Person A: 1 m/s along x at y = 3 m."""
    return Detection(box_at(1.0 + 0.04 * k, 3.0), None)


def top(P: np.ndarray) -> float:
    return float(np.linalg.eigvalsh(P[:2, :2])[-1])


def test_a_naive_node_gates_as_well_as_ell_says():
    """Node 2 of the chain 0-1-2 hears of A only through node 1, whose camera does not see A
    either: no information ever reaches node 2, only node 1's estimate through the consensus
    term. After 60 frames (2.4 s) node 2's own covariance has grown from the birth prior to
    metres; it gates with the bound of ``ell`` = 1 (node 1 sends 0 for a target it has
    information on); nodes 0 and 1 gate with their own covariances."""
    cfg = TrackerConfig(**SELECTIVE)
    nodes = make_nodes(CHAIN, cfg)
    for k in range(60):
        out = step(nodes, k, {0: [walker(k)]})
    m = cfg.m
    t2 = nodes[2].trackers[(0, 0)]
    assert t2.ell == 1 and not t2.informed
    assert nodes[0].trackers[(0, 0)].informed and nodes[1].trackers[(0, 0)].informed
    limit = m(cfg.calib_sigma) ** 2 + (2 * cfg.dt * m(cfg.birth_vel_sigma)) ** 2
    assert top(t2.P) > (1.5 * m(cfg.birth_vel_sigma)) ** 2 > 10 * limit
    gates = {i: nodes[i].associator.gate_covariances(nodes[i].state, nodes[i].state.P)
             for i in (0, 1, 2)}
    gate = gates[2][nodes[2].state.row((0, 0))]
    assert top(gate) == pytest.approx(limit, rel=1e-12)
    np.testing.assert_allclose(gate * top(t2.P) / limit, t2.P, rtol=1e-12)  # scaled as a whole
    for i in (0, 1):
        t = nodes[i].trackers[(0, 0)]
        assert top(t.P) < limit
        np.testing.assert_array_equal(gates[i][nodes[i].state.row((0, 0))], t.P)
    # the consensus keeps node 2's estimate on node 0's either way
    x = {i: {t.id: t for t in out[i]}[(0, 0)].x[:2] for i in out}
    assert np.linalg.norm(x[2] - x[0]) < 0.05


@pytest.mark.parametrize("bound", [True, False])
def test_a_naive_node_does_not_take_another_person_for_the_target(bound):
    """From frame 60 camera 2 sees person B standing 2.5 m from A's path. With the bound,
    node 2 gives B a tracker of its own and every node keeps A where A walks; gating with the
    naive covariance grown from the birth prior, node 2 takes B's detections for A."""
    cfg = TrackerConfig(naive_bound=bound, **SELECTIVE)
    nodes = make_nodes(CHAIN, cfg)
    b = Detection(box_at(4.0, 5.5), None)
    far = 0.0
    for k in range(90):
        out = step(nodes, k, {0: [walker(k)], 2: [b] if k >= 60 else []})
        if k >= 60:
            truth = np.array([1.0 + 0.04 * k, 3.0])
            a = [{t.id: t for t in out[i]}.get((0, 0)) for i in out]
            far = max(far, max(np.linalg.norm(t.x[:2] - truth) if t else np.inf for t in a))
    if bound:
        assert far < 0.3, far
        assert {t.id for t in out[2]} == {(0, 0), (2, 0)}
        assert nodes[2].stats.births == 1
    else:
        assert far > 0.5, far


def test_a_naive_node_still_takes_the_target_itself():
    """From frame 60 camera 2 sees A too: node 2 associates A's detections with the tracker
    it adopted (no birth), and from then on it has information of its own."""
    nodes = make_nodes(CHAIN, TrackerConfig())
    for k in range(90):
        out = step(nodes, k, {0: [walker(k)], 2: [walker(k)] if k >= 60 else []})
    assert nodes[2].stats.births == 0
    assert [t.id for t in out[2]] == [(0, 0)] and out[2][0].observed
    assert nodes[2].trackers[(0, 0)].informed
