"""``CameraNode``: one camera's complete tracker (paper Section III), pure and deterministic.

One cycle per frame ``k`` (paper Fig. 1):

``prepare(k, detections) -> FrameMessage``
    predict every tracker; LDA between the frame's measurements and the trackers (eqs. 5-7);
    local information ``u_i, U_i`` (eq. 2); local initialisation of new trackers; the message
    ``(ID, x_bar, u, U, ell)`` per active tracker, appearance for trackers new to this sender,
    and merge announcements.

``update(inbox) -> list[Track]``
    merge announcements; adoption of neighbours' trackers; the DKF consensus update (eqs. 3-4);
    the DTM: global association / merge, ``ell`` consensus (eq. 9) and drop, re-identification.

A node may own several cameras (``cameras``): the centralized baseline is a node that owns all
of them and has no neighbours. No I/O, no clock, no randomness: same inputs, same outputs.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from edge_node.core import dkf, manager
from edge_node.core.association import Candidate, Observation, associate
from edge_node.core.config import TrackerConfig
from edge_node.core.gallery import Gallery
from edge_node.core.initiator import Initiator, Pending
from edge_node.core.measurement import measure
from edge_node.core.model import birth_covariance, birth_state, process_noise, quantize, transition
from edge_node.core.types import Detection, Track
from edge_node.geometry import Camera
from protocol.messages import MAX_DESCRIPTORS, FrameMessage, Merge, TrackerId, TrackerInfo


class NodeStateError(RuntimeError):
    """``prepare`` and ``update`` called out of order, or frames going backwards."""


@dataclass
class Tracker:
    """A tracker as one node holds it."""

    id: TrackerId
    x_bar: np.ndarray  # prediction for the current frame
    P: np.ndarray  # its covariance
    gallery: Gallery
    ell: int = 0  # eq. 9 after the last update
    coast: int = 0  # consecutive frames ell grew: nobody in the network saw the target
    born: int = 0  # frame its originating camera created it (same on every node)
    since: int = 0  # frame it appeared on this node
    announced: bool = False  # appearance already sent by this node
    # per-frame working values
    u: np.ndarray = field(default_factory=lambda: np.zeros(6))
    U: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    ell_sent: int = 0
    x_bar_sent: np.ndarray | None = None
    seen_by: set[int] = field(default_factory=set)
    x_hat: np.ndarray | None = None
    M: np.ndarray | None = None

    def certainty(self) -> float:
        return float(np.trace(self.P))


@dataclass
class NodeStats:
    births: int = 0
    reidentified: int = 0
    adopted: int = 0
    reactivated: int = 0
    merged: int = 0
    dropped: int = 0
    ignored_messages: int = 0


class CameraNode:
    """The per-camera tracker: ``prepare`` then ``update`` once per frame."""

    def __init__(self, cameras: Camera | Sequence[Camera], neighbours: Iterable[int] = (),
                 config: TrackerConfig | None = None, network: str = "dmtt",
                 node_id: int | None = None, first_counter: int = 0):
        self.cameras: list[Camera] = [cameras] if isinstance(cameras, Camera) else list(cameras)
        if not self.cameras:
            raise ValueError("a node needs at least one camera")
        self.id = self.cameras[0].id if node_id is None else int(node_id)
        self.neighbours = tuple(sorted(set(int(n) for n in neighbours) - {self.id}))
        self.cfg = config or TrackerConfig()
        self.network = network
        self.A = transition(self.cfg.dt)
        self.Q = process_noise(self.cfg)
        self.P_birth = birth_covariance(self.cfg)
        self.trackers: dict[TrackerId, Tracker] = {}
        self.old: OrderedDict[TrackerId, Gallery] = OrderedDict()  # dropped, for re-id (DTM)
        self.dropped: OrderedDict[TrackerId, None] = OrderedDict()  # dropped ids (no DTM)
        self.aliases: dict[TrackerId, TrackerId] = {}
        self._born: dict[TrackerId, int] = {}  # birth frame of every id this node has heard of
        # event-triggered input: neighbour -> tracker -> (frame, entry, u/U already fused)
        self._memory: dict[int, dict[TrackerId, tuple[int, TrackerInfo, bool]]] = {}
        self._announce: dict[tuple[TrackerId, TrackerId], int] = {}
        self._streaks: dict[tuple[TrackerId, TrackerId], int] = {}
        self._initiators = {c.id: Initiator(self.cfg) for c in self.cameras}
        self._counter = int(first_counter)  # a restarted process continues, never reuses
        self._frame: int | None = None
        self._prepared = False
        self.stats = NodeStats()

    # ------------------------------------------------------------------------------------
    # prepare: prediction, LDA, local information, local initialisation, the message
    # ------------------------------------------------------------------------------------
    def prepare(self, k: int,
                detections: Sequence[Detection] | Mapping[int, Sequence[Detection]]) -> FrameMessage:
        if self._prepared:
            raise NodeStateError(f"node {self.id}: prepare({k}) called twice without update")
        if self._frame is not None and k <= self._frame:
            raise NodeStateError(f"node {self.id}: frame {k} does not follow frame {self._frame}")
        gap = 0 if self._frame is None else k - self._frame - 1
        for tr in self.trackers.values():
            for _ in range(gap):  # frames this node skipped: predict through them
                tr.x_bar, tr.P = dkf.predict(tr.x_bar, tr.P, self.A, self.Q)
            tr.u, tr.U = dkf.no_information()
            tr.seen_by = set()
        per_camera = self._split(detections)

        for cam in self.cameras:
            obs = [self._observe(cam, d) for d in per_camera.get(cam.id, ())]
            ids = sorted(self.trackers)
            cands = [Candidate(self.trackers[t].x_bar, self.trackers[t].P,
                               self.trackers[t].gallery) for t in ids]
            pairs = associate(cands, obs, self.cfg)
            assigned = set()
            for i, j in pairs:
                tr = self.trackers[ids[i]]
                u, U = dkf.information(obs[j].z, obs[j].R)
                tr.u, tr.U = tr.u + u, tr.U + U  # several cameras of one node add up (eq. 3)
                tr.seen_by.add(cam.id)
                tr.gallery.offer(obs[j].descriptor, k, self.cfg.gallery_admit)
                assigned.add(j)
            unassigned = [o for j, o in enumerate(obs) if j not in assigned]
            for chain in self._initiators[cam.id].step(k, unassigned):
                self._birth(k, cam.id, chain)

        for tr in self.trackers.values():
            tr.ell_sent = manager.ell_sent(bool(tr.seen_by), tr.ell)
            tr.x_bar_sent = quantize(tr.x_bar)
        self._frame = k
        self._prepared = True
        return self._message(k)

    def _split(self, detections) -> dict[int, Sequence[Detection]]:
        if isinstance(detections, Mapping):
            unknown = set(detections) - {c.id for c in self.cameras}
            if unknown:
                raise ValueError(f"node {self.id}: detections for unknown camera(s) {sorted(unknown)}")
            return dict(detections)
        if len(self.cameras) != 1:
            raise ValueError(f"node {self.id} owns {len(self.cameras)} cameras: "
                             "pass detections as {camera_id: [...]}")
        return {self.cameras[0].id: detections}

    def _observe(self, cam: Camera, det: Detection) -> Observation:
        z, R = measure(cam, det.box, self.cfg)
        desc = det.descriptor if self.cfg.use_appearance else None
        return Observation(z, R, None if desc is None else np.asarray(desc, float))

    def _birth(self, k: int, cam_id: int, chain: Pending) -> None:
        """Local initialisation from two observations: prior from the first, measurement from
        the last; re-identification against old trackers first (DTM)."""
        cfg = self.cfg
        gallery = Gallery(cfg.gallery_size, cfg.gallery_every,
                          [o.descriptor for o in chain.observations if o.descriptor is not None])
        gallery.mark(k)
        tid: TrackerId | None = None
        born = k
        if cfg.use_manager and self.old and len(gallery):
            tid = manager.reidentify(gallery, self.old, cfg)
            if tid is not None:
                old_gallery = self.old.pop(tid)
                old_gallery.extend(gallery)
                gallery = old_gallery
                born = self._born.get(tid, k)
                self.stats.reidentified += 1
        if tid is None:
            tid = (self.id, self._counter)
            self._counter += 1
            self.stats.births += 1
        first, last = chain.observations[0], chain.observations[-1]
        tr = Tracker(tid, quantize(birth_state(first.z)), self.P_birth.copy(), gallery,
                     born=born, since=k)
        self._born[tid] = born
        tr.u, tr.U = dkf.information(last.z, last.R)
        tr.seen_by = {cam_id}
        self.trackers[tid] = tr

    def _message(self, k: int) -> FrameMessage:
        infos = []
        for tid in sorted(self.trackers):
            tr = self.trackers[tid]
            app = None
            if not tr.announced and len(tr.gallery):
                app = tr.gallery.newest(MAX_DESCRIPTORS)
                tr.announced = True
            infos.append(TrackerInfo(tid, tr.x_bar_sent, tr.u.copy(), tr.U.copy(), tr.ell_sent, app,
                                     tr.born))
        merges = tuple(Merge(l, w, self._born.get(w, 0)) for (l, w) in sorted(self._announce))
        self._announce = {key: n - 1 for key, n in self._announce.items() if n > 1}
        return FrameMessage(self.network, self.id, k, tuple(infos), merges)

    def resync_message(self, msg: FrameMessage) -> FrameMessage:
        """``msg`` with every tracker's appearance attached: what this node sends a neighbour that
        came back with an empty state (restart) or joined late, so that it adopts the network's
        trackers with their galleries and keeps their ids."""
        infos = []
        for t in msg.trackers:
            tr = self.trackers.get(t.id)
            if t.appearance is None and tr is not None and len(tr.gallery):
                t = replace(t, appearance=tr.gallery.newest(MAX_DESCRIPTORS))
            infos.append(t)
        return replace(msg, trackers=tuple(infos))

    # ------------------------------------------------------------------------------------
    # update: merges, adoption, DKF consensus, DTM
    # ------------------------------------------------------------------------------------
    def update(self, inbox: Iterable[FrameMessage], stale_ok: bool = False) -> list[Track]:
        """Consensus update of frame ``k`` with the neighbours' messages.

        Synchronous operation (``stale_ok=False``) uses only messages of frame ``k``.

        Event-triggered operation (``stale_ok=True``): neighbours send a tracker only when they
        have something new about it (``trigger.EventTrigger``), and messages may come late, twice
        or out of order. The node remembers each neighbour's newest entry per tracker; every
        frame it uses those entries brought to frame ``k``: ``x_bar`` predicted forward, ``ell``
        aged by the frames since, and ``u, U`` only once and only within ``staleness_frames``
        (older measurement information would pull the estimate to where the target was).
        Entries older than ``kappa`` frames are forgotten (a neighbour that died or dropped the
        tracker). Messages from other networks, non-neighbours and future frames are ignored.
        """
        if not self._prepared:
            raise NodeStateError(f"node {self.id}: update() without prepare()")
        k = self._frame
        msgs: list[FrameMessage] = []
        for m in inbox:
            ok = (m.sender in self.neighbours and m.network == self.network
                  and (m.frame == k or (stale_ok and k - self.cfg.kappa <= m.frame < k)))
            if not ok:
                self.stats.ignored_messages += 1
                continue
            msgs.append(m)
        msgs.sort(key=lambda m: (m.sender, m.frame))
        for m in msgs:
            for mg in m.merges:
                self._merge(mg.loser, mg.winner, mg.winner_born)
        if stale_ok:
            msgs = self._remembered(msgs, k)

        received: dict[TrackerId, list[TrackerInfo]] = {}
        for m in msgs:
            mine: dict[TrackerId, TrackerInfo] = {}
            for t in m.trackers:
                rid = manager.resolve(t.id, self.aliases)
                if rid not in mine or t.id == rid:
                    mine[rid] = t
            for rid, t in mine.items():
                received.setdefault(rid, []).append(t)

        for rid in sorted(received):
            if rid not in self.trackers:
                self._adopt(k, rid, received[rid])

        for tid in sorted(self.trackers):
            tr = self.trackers[tid]
            got = received.get(tid, [])
            y, S = dkf.fuse([(tr.u, tr.U)] + [(t.u, t.U) for t in got])
            tr.x_hat, tr.M = dkf.correct(tr.x_bar, tr.P, y, S, [t.x_bar for t in got],
                                         own_x_bar_sent=tr.x_bar_sent,
                                         units_per_metre=self.cfg.units_per_metre)
            ell_before = tr.ell
            if self.cfg.use_manager:
                tr.ell = manager.ell_consensus(tr.ell_sent, [t.ell for t in got])
            else:
                tr.ell = tr.ell_sent
            tr.coast = tr.coast + 1 if tr.ell > ell_before else 0

        if self.cfg.use_manager:
            views = [manager.MergeView(t.id, t.x_hat[:2], t.gallery, t.since == k,
                                       frozenset(t.seen_by), t.born)
                     for t in self.trackers.values()]
            for loser, winner in manager.find_merges(views, self._streaks, self.cfg):
                self._merge(loser, winner)

        for tid in sorted(self.trackers):
            if self.trackers[tid].ell > self.cfg.kappa:
                self._drop(tid)

        tracks = self.tracks()
        for tr in self.trackers.values():
            tr.x_bar, tr.P = dkf.predict(tr.x_hat, tr.M, self.A, self.Q)
        self._prepared = False
        self._forget()
        return tracks

    def _forget(self) -> None:
        """Bound the memory of a long-running node: the oldest merge aliases and the birth
        frames of ids no longer referenced go once the tables outgrow their limits."""
        limit = 10 * self.cfg.max_old_trackers
        while len(self.aliases) > limit:
            del self.aliases[next(iter(self.aliases))]
        if len(self._born) > 2 * limit:
            keep = set(self.trackers) | set(self.old) | set(self.aliases) \
                | set(self.aliases.values())
            self._born = {t: b for t, b in self._born.items() if t in keep}

    def _remembered(self, arrived: list[FrameMessage], k: int) -> list[FrameMessage]:
        """Event-triggered input: store what arrived, return every neighbour's newest entry per
        tracker brought to frame ``k`` (one message per neighbour)."""
        for m in arrived:
            mem = self._memory.setdefault(m.sender, {})
            for t in m.trackers:
                old = mem.get(t.id)
                if old is None or m.frame > old[0]:
                    mem[t.id] = (m.frame, t, False)
        out = []
        for sender in sorted(self._memory):
            mem = self._memory[sender]
            aged = []
            for tid in sorted(mem):
                frame, t, consumed = mem[tid]
                age = k - frame
                if age > self.cfg.kappa:
                    del mem[tid]
                    continue
                keep_info = not consumed and age <= self.cfg.staleness_frames
                mem[tid] = (frame, t, True)  # its u, U are fused at most once
                if age == 0 and keep_info:
                    aged.append(t)
                    continue
                A = transition(age * self.cfg.dt)
                aged.append(replace(t, x_bar=A @ t.x_bar, ell=t.ell + age,
                                    u=t.u if keep_info else np.zeros(6),
                                    U=t.U if keep_info else np.zeros((6, 6))))
            out.append(FrameMessage(self.network, sender, k, tuple(aged)))
        return out

    def _adopt(self, k: int, tid: TrackerId, infos: list[TrackerInfo]) -> None:
        """A tracker heard of from neighbours but not held here (paper III-C, case 1)."""
        ell = min(t.ell for t in infos)
        if ell > self.cfg.kappa:
            return
        if not self.cfg.use_manager and tid in self.dropped:
            return  # without the DTM a camera's drop decision is its own and final
        src = infos[0]  # messages are sorted by sender: deterministic choice
        gallery = Gallery(self.cfg.gallery_size, self.cfg.gallery_every)
        if tid in self.old:
            gallery = self.old.pop(tid)
            self.stats.reactivated += 1
        else:
            self.stats.adopted += 1
        for t in infos:
            if t.appearance is not None and self.cfg.use_appearance:
                for d in t.appearance:
                    gallery.add(d)
        born = self._born.setdefault(tid, src.born)
        tr = Tracker(tid, np.array(src.x_bar, float), self.P_birth.copy(), gallery, born=born,
                     since=k)
        tr.ell_sent = ell
        tr.x_bar_sent = tr.x_bar
        self.trackers[tid] = tr

    def rank(self, tid: TrackerId) -> tuple[int, TrackerId]:
        """Merge order ``(born, id)``: the older tracker survives, ties to the smaller id."""
        return (self._born.get(tid, 2**62), tid)

    def _merge(self, loser: TrackerId, winner: TrackerId, winner_born: int | None = None) -> None:
        """Apply ``loser -> winner`` here and announce it (so it propagates hop by hop)."""
        if winner_born is not None:
            self._born.setdefault(winner, winner_born)
        loser = manager.resolve(loser, self.aliases)
        winner = manager.resolve(winner, self.aliases)
        if loser == winner:
            return
        if self.rank(winner) > self.rank(loser):  # the older always survives, whoever announced
            loser, winner = winner, loser
        self.aliases[loser] = winner
        key = (loser, winner)
        if key not in self._announce:
            self._announce[key] = self.cfg.merge_announce_frames
        lt = self.trackers.pop(loser, None)
        wt = self.trackers.get(winner)
        if lt is not None and wt is not None:
            self._absorb(wt, lt)
            self.stats.merged += 1
        elif lt is not None:
            lt.id = winner
            lt.born = self._born.get(winner, lt.born)
            lt.announced = False  # neighbours may not know the winner's appearance
            if winner in self.old:
                lt.gallery.extend(self.old.pop(winner))
            self.trackers[winner] = lt
        elif loser in self.old:
            g = self.old.pop(loser)
            if wt is not None:
                wt.gallery.extend(g)
            elif winner in self.old:
                self.old[winner].extend(g)
            else:
                self.old[winner] = g
        for key in [key for key in self._streaks if loser in key]:
            del self._streaks[key]

    @staticmethod
    def _absorb(w: Tracker, l: Tracker) -> None:
        """Merge tracker ``l`` into ``w``: the more certain estimate, both cameras' measurement
        information, the union of galleries, the smaller ``ell``."""
        if l.certainty() < w.certainty():
            w.x_bar, w.P, w.x_bar_sent = l.x_bar, l.P, l.x_bar_sent
            if l.x_hat is not None:
                w.x_hat, w.M = l.x_hat, l.M
        if l.seen_by and not w.seen_by:
            w.u, w.U = l.u, l.U
        w.seen_by |= l.seen_by
        w.gallery.extend(l.gallery)
        w.ell = min(w.ell, l.ell)
        w.coast = min(w.coast, l.coast)
        w.ell_sent = min(w.ell_sent, l.ell_sent)
        w.since = min(w.since, l.since)

    def _drop(self, tid: TrackerId) -> None:
        tr = self.trackers.pop(tid)
        self.stats.dropped += 1
        if self.cfg.use_manager:
            self.old[tid] = tr.gallery
            while len(self.old) > self.cfg.max_old_trackers:
                self.old.popitem(last=False)
        else:
            self.dropped[tid] = None
            while len(self.dropped) > 10 * self.cfg.max_old_trackers:
                self.dropped.popitem(last=False)

    # ------------------------------------------------------------------------------------
    @property
    def next_counter(self) -> int:
        """The counter the next new tracker of this node will get (persist it across restarts)."""
        return self._counter

    @property
    def frame(self) -> int | None:
        return self._frame

    def tracks(self) -> list[Track]:
        """The current estimates (after the last ``update``): the trackers it reports."""
        return [Track(t.id, self._frame, t.x_hat.copy(), t.M.copy(), bool(t.seen_by), t.ell)
                for _, t in sorted(self.trackers.items())
                if t.x_hat is not None and self._reported(t)]

    def _reported(self, tr: Tracker) -> bool:
        """A tracker is reported (returned by ``update``, written, drawn, evaluated) unless it
        has coasted more than ``report_coast`` frames: its ``ell`` grew that many frames in a
        row, so no camera of the network has seen the target since. It is still predicted, fused, merged
        and kept for re-association until ``ell`` exceeds ``kappa`` (eq. 9); only the estimate
        nobody observes, which drifts away at constant velocity, is not shown. The test is on
        the *growth* of ``ell``, not its value: a node ``h`` hops from the cameras that see a
        target holds ``ell = h - 1`` while they see it."""
        return tr.coast <= self.cfg.report_coast
