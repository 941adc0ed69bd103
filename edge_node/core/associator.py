"""The associator role: one camera's measurements against the node's trackers (paper III-B).

The local data association (``association.LocalDataAssociation``: eqs. 5-7, the optimal
assignment, and the second stage for the left-overs) pairs measurements with trackers; each
pair adds the measurement's information ``u, U`` (eq. 2) to its tracker's row of the node's
table and offers the detection's descriptor to the tracker's gallery. A measurement outside
the gate that the second stage still gives to a tracker counts only as much as the gate
allows (its ``R`` grown). What no tracker took goes back to the caller (the initiator's).

The gate's covariance is the tracker's ``P``, except for a tracker only the consensus updated
last frame (the naive-node bound, :meth:`Associator.gate_covariances`); with ``naive_yield``
such a tracker gives up a measurement that a nearer tracker this node measures should decide
(:meth:`Associator.yielded`). Pure and deterministic.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import edge_node.core.dkf as dkf
from edge_node.core.association import Candidates, LocalDataAssociation, Observation, Observations
from edge_node.core.state import NodeState
from edge_node.core.config import Slice


@dataclass(frozen=True)
class AssociatorSettings(Slice):
    """What the associator role reads (the gate, the gallery's admission, the naive-node bound);
    each parameter's rule and doc is in its section of ``config.TrackerConfig``."""

    tau: float
    naive_bound: bool
    naive_yield: bool
    comotion_gate: float
    gallery_admit: float
    calib_sigma: float
    birth_vel_sigma: float
    kappa: int
    units_per_metre: float
    fps: float


class Associator:
    """``lda``: the association itself (``LocalDataAssociation`` or a fake); ``settings``: the
    configuration's association parameters (``tau``, ``naive_bound``, ``gallery_admit``, and
    for the naive-node bound ``calib_sigma``, ``birth_vel_sigma``, ``kappa``)."""

    def __init__(self, lda: LocalDataAssociation, settings):
        self.lda = lda
        self.cfg = settings

    def __call__(self, state: NodeState, c: int, k: int, obs: Observations) -> list[Observation]:
        """Associate camera ``c``'s (its column in the table) observations of frame ``k``;
        returns those no tracker took."""
        if not len(obs):
            return []
        P = state.P
        if self.cfg.naive_bound and len(state):
            P = self.gate_covariances(state, P)
        cands = Candidates(state.x_bar, P, state.galleries)
        assigned: set[int] = set()
        pairs = self.lda(cands, obs)
        if pairs and self.cfg.naive_yield and self.cfg.naive_bound:
            pairs = self.yielded(state, obs, pairs)
        if pairs:
            rows = np.array([i for i, _ in pairs], np.intp)
            js = np.array([j for _, j in pairs], np.intp)
            u, U = dkf.informations(obs.z.take(js, axis=0), obs.R.take(js, axis=0))
            state.add_information(rows, c, u, U, js)
            admit = self.cfg.gallery_admit
            for i, j in pairs:
                state.galleries[i].offer(obs.descriptors[j], k, admit)
                assigned.add(j)
        for i, j in self.lda.recover(cands, obs, pairs):
            # outside the gate: R grown until the innovation sits on it; no registration residual
            o = obs[j]
            u, U = dkf.information(o.z, self.on_gate(state.x_bar[i], state.P[i], o))
            state.add_information(np.array([i]), c, u[None], U[None], np.array([j]), residual=False)
            assigned.add(j)
        return [obs[j] for j in range(len(obs)) if j not in assigned]

    def gate_covariances(self, state: NodeState, P: np.ndarray) -> np.ndarray:
        """The covariances the LDA gates with (eq. 5): ``P``, except for a tracker whose last
        update had no measurement information (``informed`` false: neither this node's
        cameras nor a neighbour's entries measured it; adopted from neighbours, say). Eq. 4
        corrects such a tracker by the consensus term alone, which keeps its mean on the
        neighbours' but leaves ``M = P`` growing from the birth prior however well the network
        measures the target (Kalman-consensus's naive node, Kamal, Farrell & Roy-Chowdhury
        2013). With ``ell`` (eq. 8) saying the network measured the target ``ell + 1`` frames
        ago at most, the mean is known to a camera's measurement (``calib_sigma``) plus that
        many frames of a walker's unknown velocity (``birth_vel_sigma``), and ``P`` is scaled
        down where its position block's largest eigenvalue exceeds that square. Measured before
        (terrace-full chain, no descriptors, seed 0): a node two hops from the only camera that
        saw a person gated with 2.3 m per axis after 1.4 s of adoption, took another person's
        detection 4 m away for that person, and the co-motion rule then merged the two. The
        filter's own ``M`` is not touched: the consensus pull (``gamma M``) stays the paper's."""
        cfg = self.cfg
        ell = state.ell + 1.0
        naive = self.naive(state)
        if not naive.any():
            return P
        bound = cfg.m(cfg.calib_sigma) ** 2 + (ell * cfg.dt * cfg.m(cfg.birth_vel_sigma)) ** 2
        top = np.linalg.eigvalsh(P[:, :2, :2])[:, -1]
        scale = np.where(naive, np.minimum(bound / np.maximum(top, 1e-300), 1.0), 1.0)
        return P * scale[:, None, None]

    def naive(self, state: NodeState) -> np.ndarray:
        """Rows whose last update had no measurement information (``gate_covariances``)."""
        return ~state.informed & (state.ell + 1.0 <= self.cfg.kappa)

    def yielded(self, state: NodeState, obs, pairs: list[tuple[int, int]]
                ) -> list[tuple[int, int]]:
        """``naive_yield``: ``pairs`` without those in which a naive tracker (no measurement
        information at this node last frame: its gate is wide because this node does not know
        where the target is, not because the target is there) took a measurement that lies
        nearer, within the second stage's co-motion reach (``comotion_gate``), to a tracker with
        measurement information that took nothing of this camera; the second stage
        (``recover``) then decides that measurement among the left-over trackers, nearest first.
        Measured before (terrace-full chain, no descriptors, seed 0): node 0's camera measured
        one person 0.74 m from that person's tracker, outside its tight gate, and 1.12 m from
        another person's, which node 0 knew only by consensus; the naive tracker took it and
        followed the wrong person on nodes 0-1 while nodes 2-3 kept it on its own, and node 1
        then merged the two people (docs/tuning.md, "A naive tracker yields")."""
        naive = self.naive(state)
        taken = {i for i, _ in pairs}
        free = np.flatnonzero(~naive)
        free = free[~np.isin(free, list(taken))]
        if not len(free) or not naive[[i for i, _ in pairs]].any():
            return pairs
        reach = self.cfg.m(self.cfg.comotion_gate)
        xy = state.x_bar[free, :2]
        out = []
        for i, j in pairs:
            if naive[i]:
                z = obs.z[j][:2]
                d_naive = float(np.linalg.norm(z - state.x_bar[i, :2]))
                d = np.linalg.norm(xy - z, axis=1)
                if (d < min(reach, d_naive)).any():
                    continue  # left to the second stage
            out.append((i, j))
        return out

    def on_gate(self, x_bar: np.ndarray, P: np.ndarray, o: Observation) -> np.ndarray:
        """``R`` of a measurement outside the LDA gate, scaled so that its Mahalanobis distance
        (eq. 5) equals the gate ``tau``: it counts, but only as much as the gate allows."""
        e = o.z[:2] - x_bar[:2]
        V = P[:2, :2] + o.R[:2, :2]
        d2 = float(e @ np.linalg.solve(V, e))
        R = o.R.copy()
        f = max(d2 / self.cfg.tau**2, 1.0)
        R[:2, :2] = (P[:2, :2] + R[:2, :2]) * f - P[:2, :2]
        return R
