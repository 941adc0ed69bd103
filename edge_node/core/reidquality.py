"""What a node has measured of its re-id: the appearance distances of one person and of two
people, and the thresholds they set (ours; the paper's eq. 7 thresholds are constants).

Every appearance decision of the tracker is a threshold on a cosine distance ``s_a`` (eq. 7):
the association's gate (a pair farther apart is never assigned), the merge veto (galleries
farther apart are two people), an appearance match (a merge at once, the second stage of the
association) and re-identification (``epsilon``). Constants suit one re-id. With a weak one
different people fall within the match and ``epsilon`` of each other, so look-alikes merge at
once and a newcomer takes a dropped person's id (terrace-sim ring, seed 1, rank-1 0.5: ground
IDF1 0.857 against 0.926 without descriptors; re-identification by appearance off 0.890, the
association's appearance gate off 0.915, both 0.934; with this module 0.967).

So each node measures its re-id on its own frames, with labels that need no appearance:

* **one person**: a detection and a tracker that are each other's only partner inside the
  association's geometric gate (eq. 5) -- the distance of the detection's descriptor to the
  tracker's gallery (``association``);
* **two people**: two trackers near each other (within the merge rules' reach) that some camera
  measures as two this frame -- the distance between their galleries (``manager.find_merges``):
  exactly the look-alikes an appearance match must tell apart.

The distances go into two histograms (``BINS`` bins on ``[0, 2]``, the range of a cosine
distance), halved when a side holds more than ``reid_memory`` samples (a bounded memory that
follows a change of light or of camera). Once each side holds ``reid_samples``, the thresholds
are set by the error rate ``q = reid_error`` on each side, never past the configured values:

    gate    = max(appearance_gate, Q_same(1 - q))     a person's own detections pass
    veto    = max(merge_appearance, Q_same(1 - q))    a person's duplicates are not "two people"
    match   = min(merge_appearance, Q_two(q))         two people do not look like one
    epsilon = min(epsilon, Q_two(q))                  nor take each other's ids

(``Q_same``, ``Q_two`` the quantiles of the two histograms). With a good re-id the learned
quantiles lie beyond the configured values and nothing changes; with a weak one appearance
stops deciding where it cannot tell, and place and co-motion decide, as without descriptors.
Measured (terrace-sim ring, seed 1, rank-1 0.5; terrace-gt complete, seed 0, its rank-1 0.8):
nearby pairs seen as two are 0.058 / 0.062 / 0.092 apart at their 1 / 5 / 25 % quantiles on
the first and 0.12 / 0.315 / 0.50 on the second, while a person's duplicates merged by the
network are a median 0.18 and 0.19 apart on both. ``reid_error`` 0.05 keeps terrace-gt's
thresholds about where they were configured (``match`` 0.26, ``epsilon`` 0.25) and drops the
first's to 0.05; at 0.01 terrace-gt's fell to 0.12 and it lost 0.016 ground MOTA
(docs/tuning.md).
Pure and deterministic: the same frames give the same histograms on every shell.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_node.core.config import Slice


@dataclass(frozen=True)
class ReidSettings(Slice):
    """What a node's measured re-id reads; each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    appearance_gate: float
    epsilon: float
    merge_appearance: float
    reid_error: float
    reid_memory: int
    reid_samples: int


BINS = 200
TOP = 2.0  # a cosine distance is in [0, 2]
_EDGES = np.linspace(0.0, TOP, BINS + 1)


@dataclass(frozen=True)
class Thresholds:
    """The appearance thresholds a node decides with (see the module docstring)."""

    gate: float
    veto: float
    match: float
    epsilon: float

    @classmethod
    def of(cls, cfg: ReidSettings) -> "Thresholds":
        """The configured ones."""
        return cls(cfg.appearance_gate, cfg.merge_appearance, cfg.merge_appearance, cfg.epsilon)


class ReidQuality:
    """A node's histograms of appearance distances of one person (``same``) and of two people
    (``two``), and the :class:`Thresholds` they set."""

    def __init__(self, cfg: ReidSettings):
        self.cfg = cfg
        self.same = np.zeros(BINS)
        self.two = np.zeros(BINS)
        self.configured = Thresholds.of(cfg)
        self.thresholds = self.configured

    def learn(self, same: np.ndarray, two: np.ndarray) -> None:
        """Add a frame's distances (finite values only are counted) and set the thresholds."""
        changed = False
        for hist, d in ((self.same, same), (self.two, two)):
            d = np.asarray(d, float)
            d = d[np.isfinite(d)]
            if not len(d):
                continue
            hist += _counts(np.clip(d, 0.0, TOP))
            if hist.sum() > self.cfg.reid_memory:
                hist *= 0.5
            changed = True
        if changed:
            self.thresholds = self._thresholds()

    def _thresholds(self) -> Thresholds:
        c, q, need = self.configured, self.cfg.reid_error, self.cfg.reid_samples
        if self.same.sum() < need or self.two.sum() < need:
            return c
        high = quantile(self.same, 1.0 - q, upper=True)
        low = quantile(self.two, q, upper=False)
        return Thresholds(max(c.gate, high), max(c.veto, high), min(c.match, low),
                          min(c.epsilon, low))

    def summary(self) -> dict:
        t = self.thresholds
        return {"same": float(self.same.sum()), "two": float(self.two.sum()),
                "gate": t.gate, "veto": t.veto, "match": t.match, "epsilon": t.epsilon}


def _counts(d: np.ndarray) -> np.ndarray:
    """``np.histogram(d, bins=_EDGES)[0]`` for distances in ``[0, TOP]``, at a fraction of its
    cost: each distance's bin found by the same comparisons with the same edges (``edges[i] <=
    d < edges[i + 1]``, ``TOP`` itself in the last bin), so the counts are the same."""
    i = np.searchsorted(_EDGES, d, side="right") - 1
    return np.bincount(np.minimum(i, BINS - 1), minlength=BINS)


def quantile(hist: np.ndarray, p: float, upper: bool) -> float:
    """The ``p`` quantile of a histogram on ``[0, TOP]``: the upper edge of the bin where the
    cumulative count reaches ``p`` of the total (``upper``; a bound above), else its lower
    edge (a bound below)."""
    c = np.cumsum(hist)
    i = int(np.searchsorted(c, p * c[-1], side="left"))
    i = min(i, BINS - 1)
    return float(_EDGES[i + 1] if upper else _EDGES[i])


def samples(allowed: np.ndarray, s_a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From one camera's association: the pairs that are each other's only partner inside the
    geometric gate ``allowed`` (``(n_trackers, n_obs)``), as ``(rows, cols)``, and their
    distances ``s_a`` (NaN where a gallery or a descriptor is missing)."""
    if not allowed.size:
        e = np.zeros(0, np.intp)
        return e, e, np.zeros(0)
    lone = allowed & (allowed.sum(axis=1) == 1)[:, None] & (allowed.sum(axis=0) == 1)[None, :]
    rows, cols = lone.nonzero()
    return rows, cols, s_a[rows, cols]
