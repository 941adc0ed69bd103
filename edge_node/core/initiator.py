"""Local tracker initialisation (paper III-C): a new target becomes a tracker once it has given
two observations (``init_observations``), which filters spurious detections.

Unassigned measurements wait here as *pending* observations of one camera; a later unassigned
measurement close enough on the ground (and similar enough in appearance, with LDA) extends the
chain; when a chain reaches ``init_observations`` it is handed back as a birth.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from edge_node.core.association import FORBIDDEN, Observation, assign
from edge_node.core.config import Slice
from edge_node.core.gallery import cosine_distance


@dataclass(frozen=True)
class InitiatorSettings(Slice):
    """What local initialisation reads; each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    candidate_appearance: float
    candidate_gate: float
    candidate_max_age: int
    init_observations: int
    units_per_metre: float
    fps: float


@dataclass
class Pending:
    """A chain of observations of a possible new target in one camera."""

    observations: list[Observation]
    frames: list[int] = field(default_factory=list)

    @property
    def last(self) -> Observation:
        return self.observations[-1]


class Initiator:
    """Pending observations of one camera and the rule that turns them into births."""

    def __init__(self, cfg: InitiatorSettings, appearance: bool = True):
        self.cfg = cfg
        self.appearance = appearance  # the two observations must look alike (LDA configurations)
        self.pending: list[Pending] = []

    def step(self, k: int, unassigned: list[Observation]) -> list[Pending]:
        """Feed frame ``k``'s unassigned observations; return the chains that are now births."""
        cfg = self.cfg
        self.pending = [p for p in self.pending if k - p.frames[-1] <= cfg.candidate_max_age]
        births: list[Pending] = []
        used: set[int] = set()
        if self.pending and unassigned:
            cost = np.full((len(self.pending), len(unassigned)), FORBIDDEN)
            gate = cfg.m(cfg.candidate_gate)
            for i, p in enumerate(self.pending):
                for j, o in enumerate(unassigned):
                    d = float(np.linalg.norm(o.z[:2] - p.last.z[:2]))
                    if d >= gate:
                        continue
                    if (self.appearance and o.descriptor is not None
                            and p.last.descriptor is not None
                            and cosine_distance(o.descriptor, p.last.descriptor)
                            > cfg.candidate_appearance):
                        continue
                    cost[i, j] = d
            kept: list[Pending] = []
            matched = dict(assign(cost))
            for i, p in enumerate(self.pending):
                if i in matched:
                    j = matched[i]
                    used.add(j)
                    p.observations.append(unassigned[j])
                    p.frames.append(k)
                    if len(p.observations) >= cfg.init_observations:
                        births.append(p)
                        continue
                kept.append(p)
            self.pending = kept
        for j, o in enumerate(unassigned):
            if j not in used:
                p = Pending([o], [k])
                if cfg.init_observations <= 1:
                    births.append(p)
                else:
                    self.pending.append(p)
        return births

    def clear(self) -> None:
        self.pending = []
