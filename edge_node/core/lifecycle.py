"""The lifecycle role: which trackers a node holds and under which id (paper III-C, the
distributed tracker manager's decisions applied to the node's table).

* **births**: a chain of two observations (``initiator``) becomes a tracker, under the id of a
  dropped tracker it re-identifies (``manager.reidentify``) or a new one (``identity``);
* **adoptions** (case 1 of III-C): a tracker a neighbour tells of and this node does not hold;
* **eq. 8**: ``ell`` as the minimum over the inclusive neighbourhood, and ``coast``, the frames
  in a row it grew (what the node reports, ``reporter``);
* **merges**: announced by neighbours, found by the global association (``manager.merges``),
  re-appearances by motion (``reappear``) and the heir of a dropped id: the loser's row goes
  into the winner's, or, where the winner is not held here, the loser's row takes its id;
* **drops**: ``ell > kappa`` (eq. 8) or beyond the regional scope; the gallery is kept for
  re-identification (``identity.IdentityBook.retire``).

The rules are the manager's (``manager``, ``reappear``); this role only applies them, in a
fixed order, so every node that sees the same messages holds the same trackers. Pure and
deterministic.
"""
from __future__ import annotations

from dataclasses import dataclass

from collections import Counter
from collections.abc import Callable, Sequence

import numpy as np

import edge_node.core.dkf as dkf
from edge_node.core.association import Observation
from edge_node.core.entries import Entries
from edge_node.core.gallery import Gallery
from edge_node.core.identity import IdentityBook
from edge_node.core.manager import MergeView
from edge_node.core.model import birth_covariance, birth_state, quantize
from edge_node.core.reappear import Gone, Young, gone_trackers
from edge_node.core.state import NodeState
from protocol.messages import FrameMessage, TrackerId, TrackerInfo
from edge_node.core.config import Slice


@dataclass(frozen=True)
class LifecycleSettings(Slice):
    """What the lifecycle role reads (galleries, eq. 8's kappa, adoption, scope, the birth
    prior); each parameter's rule and doc is in its section of ``config.TrackerConfig``."""

    gallery_every: int
    gallery_size: int
    kappa: int
    max_adoptions_per_frame: int
    reappear_age: int
    scope_hops: int
    birth_pos_sigma: float
    birth_size_sigma: float
    birth_vel_sigma: float
    units_per_metre: float
    fps: float


class Lifecycle:
    """``manager``: the DTM's rules (``DistributedTrackerManager`` or ``IndependentTrackers``);
    ``book``: the node's ``IdentityBook``; ``settings``: the configuration's manager
    parameters; ``cameras``: the node's camera ids (its table's camera columns);
    ``descriptor``: how the node keeps a neighbour's descriptor (None drops it); ``stats``: the
    node's counters; ``rejected``: the screen's counter of refused entries (``adoption_rate``)."""

    def __init__(self, manager, book: IdentityBook, settings, cameras: Sequence[int],
                 descriptor: Callable, stats, rejected: Counter):
        self.manager = manager
        self.book = book
        self.cfg = settings
        self.cameras = list(cameras)
        self.mine = frozenset(cameras)
        self.descriptor = descriptor
        self.stats = stats
        self.rejected = rejected
        self.P_birth = birth_covariance(settings)

    def _gallery(self) -> Gallery:
        return Gallery(self.cfg.gallery_size, self.cfg.gallery_every)

    # -- births -------------------------------------------------------------------------------
    def birth(self, state: NodeState, k: int, c: int, observations: Sequence[Observation]) -> None:
        """Local initialisation from a chain of observations of camera ``c`` (its column;
        ``initiator``): prior from the first, measurement from the last; re-identification
        against dropped trackers first (DTM)."""
        cfg, book = self.cfg, self.book
        gallery = Gallery(cfg.gallery_size, cfg.gallery_every,
                          [o.descriptor for o in observations if o.descriptor is not None])
        gallery.mark(k)
        born = k
        first, last = observations[0], observations[-1]
        tid = self.manager.reidentify(gallery, book.old.candidates(), k, last.z[:2], book.last)
        if tid is not None:
            old_gallery = book.old.take(tid)
            old_gallery.extend(gallery)
            gallery = old_gallery
            born = book.born.get(tid, k)
            self.stats.reidentified += 1
        else:
            tid = book.new_id()
            self.stats.births += 1
        book.born[tid] = born
        i = state.insert(tid, gallery, x_bar=quantize(birth_state(first.z)), P=self.P_birth,
                         born=born, since=k, heard=k, has_origin=True,
                         origin=np.asarray(last.z[:2], float))
        u, U = dkf.information(last.z, last.R)
        state.add_information(np.array([i]), c, u[None], U[None], np.array([last.raw]))

    # -- what a frame's messages bring --------------------------------------------------------
    def announced(self, state: NodeState, msgs: Sequence[FrameMessage]) -> None:
        """The neighbours' merge announcements (those the trust role let through), applied in
        message order."""
        for m in msgs:
            for mg in m.merges:
                self.merge(state, mg.loser, mg.winner, mg.winner_born)

    def adopt(self, state: NodeState, k: int, heard) -> None:
        """Every tracker the messages name that this node does not hold (paper III-C, case 1),
        at most ``max_adoptions_per_frame`` per sender a frame (the rest wait for the next),
        then, event-triggered, the appearance of a first entry that came late
        (``inbound.Heard``)."""
        inbox = heard.inbox
        adopted: Counter[int] = Counter()  # per sender, this frame
        for tid in inbox.ids():
            if tid in state:
                continue
            sender = inbox.first_sender(tid)
            if adopted[sender] >= self.cfg.max_adoptions_per_frame:
                self.rejected["adoption_rate"] += 1  # it waits for the next frame
                continue
            told = k if heard.told is None else heard.told.get(tid, k)
            adopted[sender] += self._adopt(state, k, tid, inbox.infos(tid), told)
        for tid, app in sorted(heard.late_appearance.items()):
            tid = self.book.resolve(tid)
            if tid not in state:
                continue
            i = state.row(tid)
            if state.heard_appearance[i]:
                continue
            self._descriptors(app, state.galleries[i])
            state.heard_appearance[i] = True

    def _adopt(self, state: NodeState, k: int, tid: TrackerId, infos: list[TrackerInfo],
               heard: int) -> bool:
        """A tracker heard of from neighbours but not held here; ``heard``: the frame of the
        oldest message that told of it (``k`` unless it came late). Whether it was adopted."""
        cfg, book = self.cfg, self.book
        ell = min(t.ell for t in infos)
        if ell > cfg.kappa or not self.manager.may_adopt(tid, book.dropped):
            return False
        if cfg.scope_hops and ell >= cfg.scope_hops:
            # Beyond this node's scope: not held. Its appearance, sent once with the first entry
            # of a sender, is kept with the dropped trackers' galleries, so that a later
            # adoption (the target came closer) has it. (Without this, scope 2 on corridor-4
            # adopted 11 trackers without appearance, whose co-motion merges joined different
            # people, and the middle nodes started 42-48 trackers instead of 6-7.)
            if self.manager.keeps_galleries and tid not in book.old:
                g = self._with_descriptors(infos, self._gallery())
                if len(g):
                    book.note_born(tid, infos[0].born)  # its rank, should it be re-found here
                    book.retire(tid, g, True)
            return False
        src = infos[0]  # messages are sorted by sender: deterministic choice
        gallery = self._gallery()
        if tid in book.old:
            gallery = book.old.take(tid)
            self.stats.reactivated += 1
        else:
            self.stats.adopted += 1
        gallery = self._with_descriptors(infos, gallery)
        born = book.note_born(tid, src.born)
        x_bar = np.array(src.x_bar, float)
        state.insert(tid, gallery, x_bar=x_bar, P=self.P_birth, born=born, since=k,
                     heard=min(heard, k), informed=False,
                     heard_appearance=any(t.appearance is not None for t in infos),
                     ell_sent=ell, x_bar_sent=x_bar)
        return True

    def _with_descriptors(self, infos: list[TrackerInfo], gallery: Gallery) -> Gallery:
        """``gallery`` with the descriptors the neighbours' entries carry."""
        for t in infos:
            if t.appearance is not None:
                self._descriptors(t.appearance, gallery)
        return gallery

    def _descriptors(self, appearance: np.ndarray, gallery: Gallery) -> None:
        for d in appearance:
            d = self.descriptor(d)
            if d is not None:
                gallery.add(d)

    # -- eq. 8 ----------------------------------------------------------------------------------
    def count(self, state: NodeState, k: int, entries: Entries,
              lagless: dict[TrackerId, int] | None = None,
              news: set[TrackerId] | frozenset[TrackerId] = frozenset()) -> None:
        """``ell`` (eq. 8) of every tracker from this node's counter and the neighbours', and
        ``coast``, the frames in a row it grew. With late messages (event-triggered operation)
        a neighbour's ``ell`` ages by its link's lag (``NeighbourMemory``), which is right for
        the drop (eq. 8) but is no news that nobody sees the target: ``coast`` counts only
        growth beyond the lag (``lagless``: per tracker the neighbours' smallest ``ell`` aged by
        their silences alone), and counts all of it: over a late link news comes in bursts
        (three frames of growth at once) and in gaps (no message: no news, ``coast`` holds;
        ``news`` names the trackers whose senders were heard). Before, a target only a
        neighbour saw stopped being reported whenever the lag jittered up: with every message
        1-4 frames late terrace-gt's ground misses went from 460 to 1096."""
        if not len(state):
            return
        ells = np.asarray(self.manager.ells(state.ell_sent.tolist(), entries.rows, entries.ell),
                          np.int64)
        seen_before = state.ell - state.lag
        if lagless is None:  # synchronous: every neighbour's news of frame k is here
            coast = np.where(ells > seen_before, state.coast + 1, 0)
        else:
            own = state.ell_sent
            seen = np.array([self.manager.ell(int(own[i]), [lagless[t]] if t in lagless else [])
                             for i, t in enumerate(state.ids)], np.int64)
            state.lag = ells - seen
            fresh = (own == 0) | np.array([t in news for t in state.ids], bool)
            coast = np.where(seen > seen_before, state.coast + seen - seen_before,
                             np.where(fresh, 0, state.coast))
        state.ell, state.coast = ells, coast
        state.held = state.held + ((coast == 0) & (k > state.since))

    # -- merges ---------------------------------------------------------------------------------
    def merge(self, state: NodeState, loser: TrackerId, winner: TrackerId,
              winner_born: int | None = None) -> None:
        """Apply ``loser -> winner`` here and announce it (so it propagates hop by hop)."""
        book = self.book
        pair = book.alias(loser, winner, winner_born)
        if pair is None:
            return
        loser, winner = pair
        old = book.old
        if loser in state and winner in state:
            gone = state.delete(loser)
            self._absorb(state, state.row(winner), gone)
            self.stats.merged += 1
        elif loser in state:  # only the loser is held here: it takes the winner's id and rank
            i = state.rename(loser, winner)
            state.born[i] = book.born.get(winner, state.born[i])
            state.announced[i] = False  # neighbours may not know the winner's appearance
            if winner in old:
                state.galleries[i].extend(old.take(winner))
        elif loser in old:  # a dropped tracker's gallery follows its id
            hearsay = loser in old.hearsay
            g = old.take(loser)
            if winner in state:
                state.galleries[state.row(winner)].extend(g)
            elif winner in old:
                old.extend(winner, g)
            else:
                old.put(winner, g, reid=not hearsay)
        self.manager.forget(loser)

    @staticmethod
    def _absorb(state: NodeState, w: int, o: dict) -> None:
        """Merge the row values ``o`` (the same target under another id, just deleted) into
        row ``w``: the more certain estimate, both cameras' measurement information, the union
        of galleries, the smaller ``ell``."""
        if np.trace(o["P"]) < np.trace(state.P[w]):
            state.x_bar[w], state.P[w] = o["x_bar"], o["P"]
            state.x_bar_sent[w] = o["x_bar_sent"]
            if o["estimated"]:
                state.x_hat[w], state.M[w] = o["x_hat"], o["M"]
                state.estimated[w] = True
        if o["seen"].any() and not state.seen[w].any():
            state.u[w], state.U[w] = o["u"], o["U"]
        state.seen[w] |= o["seen"]
        state.galleries[w].extend(o["gallery"])
        if o["ell"] < state.ell[w]:
            state.lag[w] = o["lag"]
        state.ell[w] = min(state.ell[w], o["ell"])
        state.coast[w] = min(state.coast[w], o["coast"])
        state.ell_sent[w] = min(state.ell_sent[w], o["ell_sent"])
        state.since[w] = min(state.since[w], o["since"])
        state.heard[w] = min(state.heard[w], o["heard"])
        state.heard_appearance[w] |= o["heard_appearance"]
        state.held[w] = max(state.held[w], o["held"])
        # negative evidence: the node's cameras missed the target only as long as they missed
        # both (a duplicate that took the measurements leaves its twin's count climbing, and a
        # merge must neither hide the person nor end a run of misses nobody made)
        state.unseen[w] = min(state.unseen[w], o["unseen"])
        # per camera, what the later measurement taught its view: size, place, the foot point
        newer = o["view_k"] > state.view_k[w]
        state.view_k[w] = np.where(newer, o["view_k"], state.view_k[w])
        for name in ("view_size", "view_off", "view_at"):
            col = getattr(state, name)
            col[w] = np.where(newer[:, None], o[name], col[w])

    # -- the manager's frame ----------------------------------------------------------------------
    def views(self, state: NodeState, k: int, measured) -> list[MergeView]:
        """What the global association needs of every tracker (in id order)."""
        none: frozenset[int] = frozenset()
        cams = self.cameras
        if len(cams) == 1:  # one frozenset for every tracker its camera saw
            one = frozenset(cams)
            by = [one if s else none for s in state.seen[:, 0].tolist()]
        else:
            by = [frozenset(c for c, s in zip(cams, row) if s) for row in state.seen.tolist()]
        xy = state.x_hat[:, :2].copy()  # the views' own: a later merge changes the table
        born, since, heard = state.born.tolist(), state.since.tolist(), state.heard.tolist()
        mine, g = self.mine, state.galleries
        return [MergeView(t, xy[i], g[i], since[i] == k, by[i], born[i], measured.get(t, none),
                          born[i] == k and t[0] in mine, since[i], heard[i])
                for i, t in enumerate(state.ids)]

    def manage(self, state: NodeState, k: int, measured) -> None:
        """The manager's frame after the update: merges of duplicates (global association),
        drops (eq. 8's ``kappa``, the regional scope), the heir of a dropped id, and
        re-appearances by motion; then the identity book forgets what no longer matters."""
        views = self.views(state, k, measured)
        for loser, winner in self.manager.merges(views):
            self.merge(state, loser, winner)
        for tid in list(state.ids):
            if tid not in state:
                continue  # merged into a tracker dropped before it (heir)
            i = state.row(tid)
            if state.ell[i] > self.cfg.kappa:
                heir = self._heir(state, k, views, tid)
                self.drop(state, k, tid)
                if heir is not None:  # it takes the dropped id back (manager.heir)
                    self.merge(state, heir, tid)
                    self.stats.stitched += 1
            elif not self.in_scope(state, i):
                self.drop(state, k, tid)
                self.stats.out_of_scope += 1
        self._reappear(state, k)
        self.book.forget(set(state.ids))

    def in_scope(self, state: NodeState, i: int) -> bool:
        """Whether this node keeps row ``i``: within ``scope_hops`` hops (always without scope).
        By eq. 8 a node h >= 1 hops from the nearest camera that sees a target holds
        ``ell = h - 1``, and while nobody sees it every node's ``ell`` grows by one a frame,
        counted in ``coast``; so ``ell - coast`` is how far, in hops minus one, the node is
        from the cameras that saw the target last, whether it is seen now or not."""
        return not self.cfg.scope_hops or state.ell[i] - state.coast[i] < self.cfg.scope_hops

    def _heir(self, state: NodeState, k: int, views: list[MergeView], tid: TrackerId
              ) -> TrackerId | None:
        """The tracker that took over the target of ``tid``, which is being dropped
        (``manager.heir``); only for a tracker the network kept alive (``confirmed``)."""
        i = state.row(tid)
        if not state.confirmed[i] or not state.estimated[i]:
            return None
        held = [v for v in views if v.id in state]
        lost = next((v for v in held if v.id == tid), None)
        return None if lost is None else self.manager.heir(lost, int(state.ell[i]), held, k)

    def young(self, state: NodeState, i: int) -> Young:
        return Young(state.ids[i], int(state.born[i]), state.x_hat[i], state.galleries[i],
                     state.origin[i] if state.has_origin[i] else None)

    def gone(self) -> list[Gone]:
        """The dropped trackers that may re-appear (``reappear.Gone``)."""
        old = self.book.old
        return gone_trackers(old.candidates(), old.last, old.motion)

    def _reappear(self, state: NodeState, k: int) -> None:
        """Trackers this node's cameras created ``reappear_age`` frames ago that go on where a
        dropped tracker was heading take its id, by a merge announced like any other
        (``manager.reappearances``); only the creator decides, so one decision per tracker."""
        rows = np.flatnonzero(state.has_origin & (k - state.born == self.cfg.reappear_age)
                              & state.estimated)
        if not len(rows):
            return
        young = [self.young(state, i) for i in rows.tolist()]
        for new, old in self.manager.reappearances(young, self.gone(), k):
            self.merge(state, new, old)
            self.stats.reappeared += 1

    def drop(self, state: NodeState, k: int, tid: TrackerId) -> None:
        """Drop ``tid`` (eq. 8: its ``ell`` passed ``kappa``) and retire it to the identity book.
        A tracker the network never kept alive after it appeared here (``confirmed``: one
        message's plausible hearsay, such as a phantom flood's) is kept for a later adoption
        of its id but not for re-identification: a person appearing later where it went must
        not take its id (the zombie probe's flood gave a phantom the id of a person born 54
        frames after it was dropped, on every node)."""
        confirmed = bool(state.confirmed[state.row(tid)])
        o = state.delete(tid)
        self.manager.forget(tid)
        self.stats.dropped += 1
        x = o["x_hat"] if o["estimated"] else None
        self.book.retire(tid, o["gallery"], self.manager.keeps_galleries, k,
                         None if x is None else x[:2], reid=confirmed, x=x, seen=k - int(o["ell"]))
