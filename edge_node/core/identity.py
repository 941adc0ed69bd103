"""Who is who on one node: tracker ids, birth ranks, merge aliases and their announcements,
and the trackers that were dropped (paper III-C).

* Ids are ``(camera, counter)``: this node's counter is its own and persists across restarts
  (``first_counter``), so an id is never reused.
* Rank ``(born, id)``: when two trackers turn out to be one target every node keeps the older,
  ties to the smaller id (the paper's "smallest id" for simultaneous initialisations).
* A merge ``loser -> winner`` is remembered as an alias (messages naming the loser reach the
  winner) and announced for ``merge_announce_frames`` frames so it propagates hop by hop.
* Dropped trackers: with the manager, their galleries are kept for re-identification
  (``reidstore.ReidStore``: at most ``max_old_trackers`` of them and ``max_old_mib`` of
  descriptors); without it, their ids are remembered so a neighbour cannot bring them back (a
  camera's drop decision is its own).

Every table is bounded: a node runs for months.
"""
from __future__ import annotations

from dataclasses import dataclass

from collections import OrderedDict

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.gallery import Gallery
from edge_node.core.reidstore import ReidStore
from protocol.messages import Merge, TrackerId


@dataclass(frozen=True)
class IdentitySettings(Slice):
    """What the identity book reads; each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    max_old_mib: float
    max_old_trackers: int
    merge_announce_frames: int


UNKNOWN_BIRTH = 2**62  # ranks an id whose birth frame this node never heard after every known one


def rank(born: int, tid: TrackerId) -> tuple[int, TrackerId]:
    """Merge order ``(born, id)``: the older tracker survives, ties to the smaller id."""
    return (born, tid)


def resolve(tid: TrackerId, aliases: dict[TrackerId, TrackerId]) -> TrackerId:
    """Follow merge announcements ``loser -> winner`` to the surviving id."""
    if tid not in aliases:  # most ids: no set built
        return tid
    seen = set()
    while tid in aliases and tid not in seen:
        seen.add(tid)
        tid = aliases[tid]
    return tid


class IdentityBook:
    def __init__(self, node_id: int, cfg: IdentitySettings, first_counter: int = 0):
        self.node_id = node_id
        self.cfg = cfg
        self.counter = int(first_counter)  # a restarted process continues, never reuses
        self.aliases: dict[TrackerId, TrackerId] = {}
        self.born: dict[TrackerId, int] = {}  # birth frame of every id this node has heard of
        self.old = ReidStore(cfg.max_old_trackers, int(cfg.max_old_mib * 2**20))  # dropped (DTM)
        self.dropped: OrderedDict[TrackerId, None] = OrderedDict()  # dropped ids (no DTM)
        self._announce: dict[tuple[TrackerId, TrackerId], int] = {}

    @property
    def last(self) -> dict[TrackerId, tuple[int, np.ndarray]]:
        """Where and when each tracker in :attr:`old` was dropped."""
        return self.old.last

    # -- ids and ranks ------------------------------------------------------------------------
    def new_id(self) -> TrackerId:
        tid = (self.node_id, self.counter)
        self.counter += 1
        return tid

    def resolve(self, tid: TrackerId) -> TrackerId:
        return resolve(tid, self.aliases)

    def note_born(self, tid: TrackerId, born: int) -> int:
        """The birth frame of ``tid``: the first one heard of wins (it is the same everywhere)."""
        return self.born.setdefault(tid, born)

    def rank(self, tid: TrackerId) -> tuple[int, TrackerId]:
        """:func:`rank` of ``tid`` (an id whose birth this node never heard of ranks last)."""
        return rank(self.born.get(tid, UNKNOWN_BIRTH), tid)

    # -- merges -------------------------------------------------------------------------------
    def alias(self, loser: TrackerId, winner: TrackerId, winner_born: int | None = None
              ) -> tuple[TrackerId, TrackerId] | None:
        """Record that ``loser`` and ``winner`` are one target; returns the resolved pair
        ``(loser, winner)`` in rank order (the older survives, whoever announced it), or
        ``None`` when they already are one id. The merge is queued for announcement."""
        if winner_born is not None:
            self.note_born(winner, winner_born)
        loser, winner = self.resolve(loser), self.resolve(winner)
        if loser == winner:
            return None
        if self.rank(winner) > self.rank(loser):
            loser, winner = winner, loser
        self.aliases[loser] = winner
        self._announce.setdefault((loser, winner), self.cfg.merge_announce_frames)
        return loser, winner

    def announcements(self) -> tuple[Merge, ...]:
        """This frame's merge announcements; each is repeated ``merge_announce_frames`` times."""
        merges = tuple(Merge(l, w, self.born.get(w, 0)) for (l, w) in sorted(self._announce))
        self._announce = {key: n - 1 for key, n in self._announce.items() if n > 1}
        return merges

    # -- dropped trackers ----------------------------------------------------------------------
    def retire(self, tid: TrackerId, gallery: Gallery, keep_gallery: bool,
               frame: int = 0, xy: np.ndarray | None = None, reid: bool = True,
               x: np.ndarray | None = None, seen: int | None = None) -> None:
        """``tid`` was dropped at ``frame`` (estimated at ``xy``, state ``x``, last seen at frame
        ``seen``): keep its gallery and where it went for re-identification (only for a later
        adoption of ``tid`` when not ``reid``), or only its id."""
        if keep_gallery:
            self.old.put(tid, gallery, frame, xy, reid, x, seen)
        else:
            self.dropped[tid] = None
            while len(self.dropped) > 10 * self.cfg.max_old_trackers:
                self.dropped.popitem(last=False)

    def forget(self, held: set[TrackerId]) -> None:
        """Bound the memory of a long-running node: the oldest merge aliases and the birth
        frames of ids no longer referenced go once the tables outgrow their limits."""
        limit = 10 * self.cfg.max_old_trackers
        while len(self.aliases) > limit:
            del self.aliases[next(iter(self.aliases))]
        if len(self.born) > 2 * limit:
            keep = held | set(self.old) | set(self.aliases) | set(self.aliases.values())
            self.born = {t: b for t, b in self.born.items() if t in keep}
