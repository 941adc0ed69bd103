"""Message types exchanged between neighbouring cameras, one per node per frame.

Paper Section III-D: per active tracker the message carries ``(ID_i, x_bar_i, u_i, U_i, ell_i)``;
a tracker new to the sender additionally carries its appearance model (the descriptors of its
gallery, at most ``MAX_DESCRIPTORS``), which is the only time appearance crosses the network.
Merge announcements (``loser -> winner``) make all cameras converge on one id per target.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SCHEMA_VERSION = 1
STATE_DIM = 6  # x = (x, y, w, h, vx, vy)
MAX_DESCRIPTORS = 2

TrackerId = tuple[int, int]
"""``(camera, counter)``: the camera that created the tracker and that camera's counter."""


@dataclass(frozen=True, eq=False)
class TrackerInfo:
    """One tracker's consensus data from one camera for one frame.

    x_bar: predicted state ``A x_hat(k-1)``, shape (6,).
    u, U:  information vector and matrix of the local measurement (eq. 2); zeros when the
           sender has no measurement of this target this frame. ``U`` is symmetric (6, 6).
    ell:   frames since the last association by any camera, as the sender knows it (eq. 8).
    appearance: ``(n, D)`` descriptors, only when the tracker is new to the sender.
    born:  the frame its originating camera created it. Every camera ranks trackers by
           ``(born, id)``, so when two trackers turn out to be one target, all keep the older.
    """

    id: TrackerId
    x_bar: np.ndarray
    u: np.ndarray
    U: np.ndarray
    ell: int
    appearance: np.ndarray | None = None
    born: int = 0

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TrackerInfo):
            return NotImplemented
        if self.id != other.id or self.ell != other.ell or self.born != other.born:
            return False
        if not (np.array_equal(self.x_bar, other.x_bar) and np.array_equal(self.u, other.u)
                and np.array_equal(self.U, other.U)):
            return False
        if (self.appearance is None) != (other.appearance is None):
            return False
        return self.appearance is None or np.array_equal(self.appearance, other.appearance)


@dataclass(frozen=True)
class Merge:
    """Announcement that ``loser`` and ``winner`` are the same target; everyone keeps ``winner``.

    ``winner_born`` is the winner's birth frame, so a camera that only held the loser renames
    it with the winner's rank ``(born, id)`` intact.
    """

    loser: TrackerId
    winner: TrackerId
    winner_born: int = 0


@dataclass(frozen=True)
class FrameMessage:
    """Everything one camera tells one neighbour about frame ``frame``."""

    network: str
    sender: int
    frame: int
    trackers: tuple[TrackerInfo, ...] = ()
    merges: tuple[Merge, ...] = ()
    sent_at: float = 0.0  # seconds since the epoch at send; 0.0 in simulation
    version: int = field(default=SCHEMA_VERSION)

    def tracker(self, tid: TrackerId) -> TrackerInfo | None:
        for t in self.trackers:
            if t.id == tid:
                return t
        return None
