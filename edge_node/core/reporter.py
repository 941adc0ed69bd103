"""The reporter role: the tracks a node reports after a frame (returned by ``update``, written,
drawn and evaluated), with each camera's own boxes (``views``).

A tracker is reported unless it has coasted more than ``report_coast`` frames (its ``ell``
grew that many frames in a row: no camera of the network has seen the target since; it is
still predicted, fused, merged and kept until eq. 8 drops it). The test is on the *growth* of
``ell``, not its value: a node ``h`` hops from the cameras that see a target holds
``ell = h - 1`` while they see it. Besides, what the network has not decided yet is not shown
as a second id: a young tracker on its way to merging into a reported older one
(``hide_pending``), or reported under the older id while the older is not reported
(``pending_alias``), and a new tracker that may still be a dropped one re-appearing
(``reappear``). A new tracker beside an older one is tentative, not reported, until the id it
is reported under is ``report_age`` frames old, counted from its birth at its camera: a
duplicate that some camera started beside a person's tracker and that the manager merges
within its first frames is never shown (the M-of-N confirmation of track initiation, by age,
as the birth already took two observations). Beside means within ``report_near`` of a tracker
of earlier rank (``identity.rank``) than the id it is reported under (an alias's own older
tracker does not count) that the node's co-motion evidence does not know for a second person
(``manager.two_people``; without the DTM every pair is two people, so nothing is held back). A
person who walks in away from everyone is shown at once, and an id once shown is not held back
again while young (the node decides once; a node that hears of the older tracker a frame late
shows the duplicate from its first frame). With ``report_near`` 0 every new tracker is
tentative, and every node starts reporting it in the same frame. By negative evidence
a tracker one of the node's own cameras should have measured for
``views.unseen_limit()`` frames in a row, and none did, is not reported
(``views.OwnViews.expect``: a neighbour's false person, or a knocked camera's, that walks where
this camera looks; the limit learnt from how long the node's cameras miss real people, at least
``report_unseen``). Pure and deterministic.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_node.core.identity import rank
from edge_node.core.state import NodeState
from edge_node.core.types import Track
from protocol.messages import TrackerId
from edge_node.core.config import Slice


@dataclass(frozen=True)
class ReporterSettings(Slice):
    """What the reporter role reads; each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    report_coast: int
    report_age: int
    report_near: float
    hide_pending: bool
    pending_alias: bool
    comotion_frames: int
    reappear_age: int
    reappear_hide: int
    units_per_metre: float


class Reporter:
    """``manager``: the DTM's rules (``pending``, ``awaiting``); ``young``, ``gone``: the
    lifecycle's views of new and dropped trackers (re-appearance); ``views``: what each camera
    draws (``OwnViews`` or a fake); ``settings``: the configuration's report parameters."""

    def __init__(self, manager, young, gone, views, settings):
        self.manager = manager
        self.young = young
        self.gone = gone
        self.views = views
        self.cfg = settings
        # ids a young tracker has been reported under (id -> birth frame): once shown, an id
        # is not held back again while young (the rule decides once, not frame by frame)
        self._shown_young: dict[TrackerId, int] = {}

    def __call__(self, state: NodeState, k: int) -> list[Track]:
        cfg = self.cfg
        if not len(state):
            return []
        ids = state.ids
        keep = state.estimated & (state.coast <= cfg.report_coast)
        limit = self.views.unseen_limit()  # 0: negative evidence hides nothing
        if limit:  # not what this node's own cameras should see and do not
            keep &= state.unseen < limit
        shown = np.flatnonzero(keep)
        hidden: set[TrackerId] = set()
        alias: dict[TrackerId, TrackerId] = {}
        if cfg.pending_alias or (cfg.hide_pending and len(shown) > 1):
            shown_ids = {ids[i] for i in shown.tolist()}
            pend = self.manager.pending(dict(zip(ids, state.born.tolist())))
            if cfg.hide_pending and len(shown) > 1:
                new = k - cfg.comotion_frames
                hidden = {young for young, old in pend
                          if old in shown_ids and state.since[state.row(young)] >= new}
            if cfg.pending_alias:
                for young, old in pend:
                    if (old not in shown_ids and young in shown_ids and young not in alias
                            and old not in alias.values()):
                        alias[young] = old
        age = k - state.born.take(shown)  # frames since each birth at its camera
        fresh = shown[age < cfg.reappear_age + cfg.reappear_hide]
        if len(fresh):  # not yet told whether they are a dropped tracker re-appearing
            gone = self.gone()
            hidden |= {ids[i] for i in fresh.tolist()
                       if self.manager.awaiting(self.young(state, i), gone, k)}
        if cfg.report_age:  # tentative while the id it is reported under is young
            young = [i for i in shown[age < cfg.report_age].tolist()
                     if ids[i] not in alias
                     or k - state.born[state.row(alias[ids[i]])] < cfg.report_age]
            if young and cfg.report_near:
                was = self._shown_young
                young = self._beside_older(state, [i for i in young
                                                   if alias.get(ids[i], ids[i]) not in was],
                                           alias)
            hidden |= {ids[i] for i in young}
        if hidden:
            shown = np.array([i for i in shown.tolist() if ids[i] not in hidden], np.intp)
        if cfg.report_age and cfg.report_near:
            self._remember_young(state, shown, alias, k)
        if not len(shown):
            return []
        x_hat = state.x_hat.take(shown, axis=0)  # the tracks' own
        boxes = self.views.boxes(state, shown, k, x_hat, self.manager.two_people)
        M = state.M.take(shown, axis=0)
        seen = state.seen_any().take(shown).tolist()
        ell = state.ell.take(shown).tolist()
        return [Track._built(alias.get(ids[i], ids[i]), k, x, M_i, s, e, b)
                for i, x, M_i, s, e, b in zip(shown.tolist(), x_hat, M, seen, ell, boxes)]

    def _remember_young(self, state: NodeState, shown: np.ndarray,
                        alias: dict[TrackerId, TrackerId], k: int) -> None:
        """Note the ids the young trackers of ``shown`` are reported under; forget those no
        longer young (the memory holds at most the ids born in the last ``report_age``
        frames)."""
        ids, born, age = state.ids, state.born, self.cfg.report_age
        was = {t: b for t, b in self._shown_young.items() if k - b < age}
        for i in shown[k - born.take(shown) < age].tolist():
            t = alias.get(ids[i], ids[i])
            was.setdefault(t, int(born[state.row(t)]))
        self._shown_young = was

    def _beside_older(self, state: NodeState, rows: list[int],
                      alias: dict[TrackerId, TrackerId] | None = None) -> list[int]:
        """The ``rows`` (young trackers) within ``report_near`` of an estimated tracker of
        earlier rank (``identity.rank``) than the id each is reported under (its own, or
        the older one of ``alias``, which is not judged against itself) that the manager does
        not know for a second person: the duplicates the manager may still merge, not a
        person who walked in alone. The distances of every young tracker to every other in
        one array operation; the ranks of the few near pairs compared in Python (ids are
        tuples)."""
        if not rows:
            return []
        alias = alias or {}
        ids, born = state.ids, state.born
        older = np.flatnonzero(state.estimated)
        diff = state.x_hat[older, None, :2] - state.x_hat[None, rows, :2]
        j, c = np.nonzero(np.hypot(diff[..., 0], diff[..., 1]) < self.cfg.m(self.cfg.report_near))
        pairs, col = [], []
        for o, y in zip(older[j].tolist(), c.tolist()):
            i = rows[y]
            r = alias.get(ids[i], ids[i])  # the id it is reported under
            if ids[o] != r and o != i and rank(int(born[o]), ids[o]) < rank(int(born[state.row(r)]), r):
                pairs.append((ids[i], ids[o]))
                col.append(y)
        if not pairs:
            return []
        apart = self.manager.two_people(pairs).tolist()
        return [rows[y] for y in sorted({y for y, a in zip(col, apart) if not a})]
