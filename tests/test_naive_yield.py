"""``naive_yield`` (on by default): a tracker that only the consensus updated last frame (a naive
tracker: its gate is wide because this node does not know where the target is) gives up a
measurement its gate took when a tracker the node measures, and that took nothing of this
camera, lies nearer to it within the co-motion reach; the second stage then gives the
measurement to the nearest left-over. Figures from the configuration alone."""
from __future__ import annotations

import numpy as np

from edge_node.core import Detection, TrackerConfig
from edge_node.core.gallery import Gallery
from edge_node.core.state import NodeState
from fakes import box_at, make_nodes
from protocol.messages import TrackerId

A, B = TrackerId((0, 1)), TrackerId((2, 1))


def associate(cfg: TrackerConfig, z=(4.7, 5.0)) -> dict:
    """Node 0 holds A, measured every frame (informed, ``P`` of a converged track: 5 cm) at
    (4, 5), and B, 1.5 m on, known only by consensus (naive: not informed, ``ell`` 1, ``P`` of
    a birth prior, 2 m). Its camera measures one person at ``z``: 0.7 m from A, 0.8 m from B,
    outside A's gate. Returns which tracker the measurement went to (``None``: neither)."""
    node = make_nodes({0: ()}, cfg)[0]
    state = NodeState(1)
    P_a = np.diag([0.05 ** 2] * 2 + [0.05 ** 2] * 2 + [0.1 ** 2] * 2)
    P_b = np.diag([2.0 ** 2] * 2 + [0.3 ** 2] * 2 + [1.0 ** 2] * 2)
    for tid, xy, P, informed, ell in ((A, (4.0, 5.0), P_a, True, 0), (B, (5.5, 5.0), P_b, False, 1)):
        x = np.array([*xy, 0.5, 1.7, 0.0, 0.0])
        state.insert(tid, Gallery(), x_bar=x, P=P, x_hat=x, M=P, informed=informed, ell=ell,
                     estimated=True)
    state.begin_frame()
    obs, _ = node.measurer(node.cameras[0], [Detection(box_at(*z), None)])
    left = node.associator(state, 0, 10, obs)
    got = [state.ids[i] for i in np.flatnonzero(state.raw[:, 0] >= 0)]
    assert len(got) + len(left) == 1
    return got[0] if got else None


def test_a_naive_tracker_yields_a_measurement_to_a_nearer_measured_one():
    assert associate(TrackerConfig(naive_yield=False)) == B  # the wide gate takes it
    assert associate(TrackerConfig(naive_yield=True)) == A
    # nearer to B than to A: B keeps it either way
    assert associate(TrackerConfig(naive_yield=True), z=(5.0, 5.0)) == B
