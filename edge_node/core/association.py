"""Local Data Association (paper Section III-B, eqs. 5-7) and the optimal assignment.

Cost of pairing tracker ``i`` with measurement ``j``: ``s_a * s_d`` where ``s_d = d / alpha``
(eq. 6) for a Mahalanobis distance ``d < tau`` (eq. 5) and ``s_a`` is the minimum cosine
distance to the tracker's gallery (eq. 7). Pairs outside the gate are never assigned; nor
(our addition) pairs whose appearance distance exceeds ``appearance_gate``, because the product
cost lets a detection very close to a prediction win whatever it looks like. The
assignment minimises the total cost (Hungarian, ``scipy.optimize.linear_sum_assignment``), not
a greedy pick. SciPy is imported at the first assignment, not with the core: it is most of a
camera process's import time, which ``edge_node run`` spends while it waits for its network.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge_node.core.config import Slice
import edge_node.core.reidquality as reidquality
from edge_node.core.gallery import Gallery
from edge_node.core.reidquality import ReidQuality, Thresholds
from edge_node.core.stacks import Columns
from edge_node.geometry import norms


@dataclass(frozen=True)
class AssociationSettings(Slice):
    """What the local data association reads (eqs. 5-7, its second stage and the appearance
    thresholds' defaults); each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    tau: float
    alpha_lda: float
    unknown_appearance: float
    appearance_gate: float
    recover: bool
    tau_gda: float
    alpha_gda: float
    comotion_gate: float
    merge_appearance: float
    epsilon: float
    units_per_metre: float
    fps: float


FORBIDDEN = 1e9




def _hungarian(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.optimize.linear_sum_assignment`` (imported on first use: see the module docstring)."""
    # SciPy is heavy (see the module docstring): imported here, on first use
    from scipy.optimize import linear_sum_assignment
    return linear_sum_assignment(cost)

@dataclass(eq=False, slots=True)
class Candidate:
    """What the associator needs of one tracker: prediction, prior covariance, gallery (a
    per-frame value, read only; not a frozen dataclass, whose checked ``__setattr__`` doubles
    the cost of building one per tracker and frame)."""

    x_bar: np.ndarray
    P: np.ndarray
    gallery: Gallery | None


@dataclass(eq=False, slots=True)
class Observation:
    """What the associator needs of one measurement: ``z``, ``R`` and the descriptor; ``raw``
    is what the caller knows the measurement by, not read here (the node: the row of the
    camera's box measurement before any registration correction). Read only, not frozen: see
    ``Candidate``."""

    z: np.ndarray
    R: np.ndarray
    descriptor: np.ndarray | None
    raw: object = None


class Observations(Columns):
    """One camera frame's observations with their ``z`` ``(n, 4)`` and ``R`` ``(n, 4, 4)``
    stacked (as the node computes them, for all boxes at once): the association reads the
    columns instead of stacking them from rows again. ``[j]`` is row ``j`` as an
    :class:`Observation` (``raw`` its row number: what the node knows it by). Any sequence of
    :class:`Observation` works where this does."""

    __slots__ = ("z", "R", "descriptors")

    def __init__(self, z: np.ndarray, R: np.ndarray, descriptors: Sequence[np.ndarray | None]):
        self.z, self.R, self.descriptors = z, R, descriptors

    def _row(self, j: int) -> Observation:
        return Observation(self.z[j], self.R[j], self.descriptors[j], j)


class Candidates(Columns):
    """The trackers of one association with their ``x_bar`` ``(n, 6)`` and ``P`` ``(n, 6, 6)``
    stacked (the node holds them so): the association reads the columns instead of stacking
    them from rows. ``[i]`` is row ``i`` as a :class:`Candidate`. Any sequence of
    :class:`Candidate` works where this does."""

    __slots__ = ("x_bar", "P", "galleries")

    def __init__(self, x_bar: np.ndarray, P: np.ndarray, galleries: Sequence[Gallery | None]):
        self.x_bar, self.P, self.galleries = x_bar, P, galleries

    def _row(self, i: int) -> Candidate:
        return Candidate(self.x_bar[i], self.P[i], self.galleries[i])


def _column(items: Sequence[Candidate] | Sequence[Observation], name: str) -> np.ndarray:
    """``name`` (``z``, ``R``, ``x_bar``, ``P``) of every item, stacked: an ``Observations``'
    or ``Candidates``' own column."""
    if isinstance(items, (Observations, Candidates)):
        return getattr(items, name)
    return np.array([getattr(o, name) for o in items])


def mahalanobis_matrix(trackers: Sequence[Candidate], obs: Sequence[Observation]) -> np.ndarray:
    """Eq. 5 for every pair: ``d_ij`` with ``V = P_xy + R_xy``; shape ``(n_trackers, n_obs)``.

    Vectorised with the closed-form inverse of the 2x2 ``V``, each of its four entries (and of
    the innovation's two) an ``(n_trackers, n_obs)`` table from a column of trackers plus a row
    of measurements (contiguous: a tenth of the work of broadcasting ``(n, m, 2, 2)`` stacks).
    """
    P = _column(trackers, "P")[:, :2, :2].reshape(-1, 4).T[:, :, None]  # 4 x (n, 1)
    R = _column(obs, "R")[:, :2, :2].reshape(-1, 4).T[:, None, :]  # 4 x (1, m)
    x = _column(trackers, "x_bar")[:, :2].T[:, :, None]  # 2 x (n, 1)
    z = _column(obs, "z")[:, :2].T[:, None, :]  # 2 x (1, m)
    a, b, c, d = P[0] + R[0], P[1] + R[1], P[2] + R[2], P[3] + R[3]  # V = P_xy + R_xy
    det = a * d - b * c
    ex, ey = z[0] - x[0], z[1] - x[1]
    q = (d * ex * ex - (b + c) * ex * ey + a * ey * ey) / det  # e^T V^-1 e
    return np.sqrt(np.maximum(q, 0.0))


def appearance_matrix(trackers: Sequence[Candidate], obs: Sequence[Observation],
                      unknown: float, where: np.ndarray | None = None) -> np.ndarray:
    """Eq. 7 for every pair; ``unknown`` where a gallery or a descriptor is missing. With
    ``where`` (a boolean ``(n_trackers, n_obs)`` mask) only those pairs are scored (the others
    hold ``unknown``): the pairs outside the geometric gate are never assigned, and scoring a
    query against a gallery is most of the association's arithmetic."""
    A = np.full((len(trackers), len(obs)), float(unknown))
    descs = obs.descriptors if isinstance(obs, Observations) else [o.descriptor for o in obs]
    known = [d for d in descs if d is not None]
    if not known:
        return A
    if len(known) == len(descs):
        has = np.ones(len(descs), bool)
        Q = np.array(known, float)
    else:
        has = np.array([d is not None for d in descs], bool)
        Q = np.zeros((len(obs), len(known[0])))
        Q[has] = np.array(known)
    Q /= np.maximum(norms(Q, axis=1, keepdims=True), 1e-12)
    pairs = np.broadcast_to(has, A.shape) if where is None else where & has
    pair_rows, pair_cols = np.nonzero(pairs)  # row-major: each tracker's columns together, in order
    if not len(pair_rows):
        return A
    first = np.ones(len(pair_rows), bool)  # where a tracker's pairs begin
    np.not_equal(pair_rows[1:], pair_rows[:-1], out=first[1:])
    starts = first.nonzero()[0].tolist()
    rows, cols = pair_rows.tolist(), pair_cols.tolist()
    galleries = trackers.galleries if isinstance(trackers, Candidates) else [t.gallery for t in trackers]
    sims, seg, scored = [], [], []  # cosines, where each pair's begin in them, the pairs
    at = 0
    for a, b in zip(starts, starts[1:] + [len(rows)]):
        g = galleries[rows[a]]
        n = 0 if g is None else len(g)
        if not n:
            continue
        # one product per tracker over its gated queries: a row of cosines against its gallery
        # per query; the maxima of all pairs in one call below
        if b - a == 1:  # one query (the common case): matrix times vector, two thirds of the
            # instructions of the product of matrices (the same numbers with NumPy's OpenBLAS
            # on 3000 random galleries; a score only ranks and gates, so a last bit could not
            # move a track unless two pairs tied)
            sims.append(np.dot(g.matrix(), Q[cols[a]]))
            seg.append(at)
            scored.append(a)
        else:
            sims.append(g.similarities(Q[cols[a:b]]).ravel())
            seg.extend(range(at, at + (b - a) * n, n))
            scored.extend(range(a, b))
        at += (b - a) * n
    if scored:
        pick = np.array(scored)
        A[pair_rows.take(pick), pair_cols.take(pick)] = 1.0 - np.maximum.reduceat(np.concatenate(sims), seg)
    return A


def cost_matrix(trackers: Sequence[Candidate], obs: Sequence[Observation],
                cfg: AssociationSettings, appearance: bool = True, gate: float | None = None,
                learn: ReidQuality | None = None) -> np.ndarray:
    """Eqs. 5-7: ``s_a * s_d`` inside the gate, ``FORBIDDEN`` outside (``s_d`` alone without
    appearance, the paper's ``dkf`` configuration). ``gate``: the appearance gate (default
    ``appearance_gate``); ``learn``: a node's :class:`ReidQuality`, given this frame's
    distances of one person (:func:`reidquality.samples`)."""
    if not trackers or not obs:
        return np.zeros((len(trackers), len(obs)))
    d = mahalanobis_matrix(trackers, obs)
    s_d = d / cfg.alpha_lda
    allowed = d < cfg.tau
    cost = s_d
    if appearance:
        s_a = appearance_matrix(trackers, obs, np.nan, where=allowed)
        if learn is not None:
            _learn(learn, allowed, s_a)
        s_a = np.where(np.isnan(s_a), cfg.unknown_appearance, s_a)
        cost = s_a * s_d
        # With s_d close to 0 the product ignores appearance; a pair that is clearly two
        # different people (s_a above the gate) is never assigned, however close.
        allowed &= s_a <= (cfg.appearance_gate if gate is None else gate)
    return np.where(allowed, cost, FORBIDDEN)


def _learn(quality: ReidQuality, allowed: np.ndarray, s_a: np.ndarray) -> None:
    """One camera's frame into ``quality``: the lone pairs' distances (one person)."""
    _, _, same = reidquality.samples(allowed, s_a)
    quality.learn(same, np.zeros(0))


def assign(cost: np.ndarray) -> list[tuple[int, int]]:
    """Minimum-cost assignment over the allowed pairs; returns ``(row, col)`` sorted by row."""
    if cost.size == 0:
        return []
    rows, cols = _hungarian(cost)
    return sorted((int(r), int(c)) for r, c in zip(rows, cols) if cost[r, c] < FORBIDDEN)


def recover(trackers: Sequence[Candidate], obs: Sequence[Observation],
            taken: Sequence[tuple[int, int]], cfg: AssociationSettings,
            th: Thresholds | None = None) -> list[tuple[int, int]]:
    """Second stage of the LDA (our addition): a measurement no tracker took, next to a tracker
    that took none, within the distributed global association's gate ``tau_gda`` (Euclidean,
    ``V = I``, paper III-C) and looking like it (``s_a <= merge_appearance``), is that tracker.

    Why: a camera's view of a target can disagree with the network's fused estimate by more than
    ``R`` and ``P`` allow (a fused ``P`` is small; a real calibration can be off by up to 1 m at
    some places of an image, which no global correction removes). Rejected, such a measurement
    would start a duplicate tracker every other frame, merged again at once. Without appearance
    the pair must be within the co-motion gate instead, and so it must where appearance cannot
    tell (``s_a`` between the learned ``match`` and ``veto``, ``reidquality``).
    """
    th = th or Thresholds.of(cfg)
    rows = sorted(set(range(len(trackers))) - {i for i, _ in taken})
    cols = sorted(set(range(len(obs))) - {j for _, j in taken})
    if not rows or not cols:
        return []
    sub_t = [trackers[i] for i in rows]
    sub_o = [obs[j] for j in cols]
    d = norms(_column(obs, "z")[cols][None, :, :2]
              - _column(trackers, "x_bar")[rows][:, None, :2], axis=2)
    s_a = appearance_matrix(sub_t, sub_o, np.nan)
    known = ~np.isnan(s_a)
    like = known & (s_a <= th.match)  # looks like it
    unsure = ~known | ((s_a > th.match) & (s_a <= th.veto))  # appearance cannot tell
    # appearance matching: the GDA's gate; unknown or undecided: the co-motion gate, tighter
    allowed = (like & (d < cfg.m(cfg.tau_gda))) | (unsure & (d < cfg.m(cfg.comotion_gate)))
    s = np.where(like, np.maximum(np.nan_to_num(s_a), 1e-3), cfg.unknown_appearance)
    cost = np.where(allowed, s * d / cfg.m(cfg.alpha_gda), FORBIDDEN)
    return [(rows[a], cols[b]) for a, b in assign(cost)]


class LocalDataAssociation:
    """LDA of one camera's frame: the optimal tracker-measurement pairs under the cost of eqs.
    5-7. ``appearance=False`` is the paper's ``dkf`` configuration: geometry only, and the node
    keeps no descriptors (``descriptor`` drops them on intake). ``quality``: the node's measured
    re-id (``reidquality``), which learns from every frame and sets the appearance thresholds;
    None: the configured ones."""

    def __init__(self, cfg: AssociationSettings, appearance: bool = True,
                 quality: ReidQuality | None = None):
        self.cfg = cfg
        self.appearance = appearance
        self.quality = quality if appearance else None

    @property
    def thresholds(self) -> Thresholds:
        return self.quality.thresholds if self.quality is not None else Thresholds.of(self.cfg)

    def descriptor(self, d: np.ndarray | None) -> np.ndarray | None:
        """A detection's or a neighbour's descriptor as this node keeps it (float64), or None."""
        return None if d is None or not self.appearance else np.asarray(d, float)

    def __call__(self, trackers: Sequence[Candidate], obs: Sequence[Observation]
                 ) -> list[tuple[int, int]]:
        gate = self.thresholds.gate  # this frame's, before it learns from it
        return assign(cost_matrix(trackers, obs, self.cfg, self.appearance, gate, self.quality))

    def recover(self, trackers: Sequence[Candidate], obs: Sequence[Observation],
                taken: Sequence[tuple[int, int]]) -> list[tuple[int, int]]:
        """Pairs of the second stage (:func:`recover`)."""
        if not self.cfg.recover:
            return []
        return recover(trackers, obs, taken, self.cfg, self.thresholds)
