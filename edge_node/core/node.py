"""``CameraNode``: one camera's complete tracker (paper Section III), pure and deterministic.

One cycle per frame ``k`` (paper Fig. 1), each step a call to a component with one job:

``prepare(k, detections) -> FrameMessage``
    predict every tracker to ``k``; per camera: measurements ``z, R`` from the boxes, LDA
    between them and the trackers (eqs. 5-7, ``LocalDataAssociation``), local information
    ``u, U`` (eq. 2), local initialisation of new trackers (``Initiator``); the message
    ``(ID, x_bar, u, U, ell)`` per tracker, appearance for trackers new to this sender, and
    merge announcements (``IdentityBook``).

``update(inbox) -> list[Track]``
    merge announcements; adoption of neighbours' trackers; the DKF consensus update (eqs. 3-4,
    ``dkf``); the tracker manager (``DistributedTrackerManager``): ``ell`` (eq. 8), global
    association and merges, drops, re-identification. In event-triggered operation the
    neighbours' latest entries come from a ``NeighbourMemory``.

The paper's three configurations (Sec. IV-B) are three assemblies of these components
(``assemble``); a test may pass its own. A node may own several cameras: the centralized
baseline is a node that owns all of them and has no neighbours. No I/O, no clock, no
randomness: same inputs, same outputs.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

import edge_node.core.dkf as dkf
import edge_node.core.manager as manager
import edge_node.core.registrar as registrar
from edge_node.core.association import Candidates, LocalDataAssociation, Observation, Observations
from edge_node.core.config import TrackerConfig
from edge_node.core.entries import Entries, Inbox
from edge_node.core.gallery import Gallery
from edge_node.core.identity import IdentityBook
from edge_node.core.inbound import Inbound
from edge_node.core.initiator import Initiator, Pending
from edge_node.core.manager import DistributedTrackerManager, IndependentTrackers, MergeView
from edge_node.core.measurement import BoxMeasurements, box_measurements, fixed_R, uncorrected_many
from edge_node.core.memory import NeighbourMemory
from edge_node.core.model import STATE_DIM, birth_covariance, birth_state, process_noise, quantize, transition
from edge_node.core.reappear import Gone, Young, gone_trackers
from edge_node.core.registration import Registration
from edge_node.core.reidquality import ReidQuality
from edge_node.core.screen import Screen
from edge_node.core.stacks import RowStack, stacked
from edge_node.core.tracker import LocalInfo, Tracker, TrackerTable
from edge_node.core.types import Detection, Track
from edge_node.core.views import OwnViews, ViewSettings
from edge_node.geometry import Camera
from protocol.errors import DmttError
from protocol.messages import MAX_DESCRIPTORS, FrameMessage, TrackerBlock, TrackerId, TrackerInfo

Manager = DistributedTrackerManager | IndependentTrackers


class NodeStateError(DmttError, RuntimeError):
    """``prepare`` and ``update`` called out of order, or frames going backwards."""


@dataclass
class NodeStats:
    births: int = 0
    reidentified: int = 0
    adopted: int = 0
    reactivated: int = 0
    merged: int = 0
    stitched: int = 0  # dropped trackers whose id a younger tracker took (manager.heir: heir_pending or stitch)
    reappeared: int = 0  # new trackers that took a dropped one's id by its course (reappear.py)
    dropped: int = 0
    out_of_scope: int = 0  # trackers let go because the target is beyond scope_hops (regional scope)
    ignored_messages: int = 0  # other network, not a neighbour, future or too old a frame
    duplicate_messages: int = 0  # a sender's frame already taken
    bad_detections: int = 0  # boxes with NaN, inf or a non-positive size: not measured
    numerical: int = 0  # tracker corrections that failed numerically (kept the prediction)
    rejected: dict[str, int] = field(default_factory=dict)  # neighbours' entries, by reason

    def add(self, other: "NodeStats") -> "NodeStats":
        """The sum of two lives of a node (before and after a restart)."""
        out = NodeStats(**{f: getattr(self, f) + getattr(other, f)
                           for f in vars(self) if f != "rejected"})
        out.rejected = dict(Counter(self.rejected) + Counter(other.rejected))
        return out


@dataclass(frozen=True)
class Components:
    """What a node is assembled from."""

    associate: LocalDataAssociation
    manager: Manager
    initiator: Callable[[], Initiator]  # one per camera
    registration: Callable[[Camera], Registration] | None = None  # one per camera, or none
    #: what each camera draws (``views.OwnViews``), from the node's cameras and registrations;
    #: ``None``: the configuration's ``view_*`` rules
    views: Callable[[Sequence[Camera], Mapping[int, Registration]], OwnViews] | None = None


def assemble(cfg: TrackerConfig) -> Components:
    """The paper's configurations (Sec. IV-B): ``dkf`` (geometry only, no manager), ``dkf+lda``
    (appearance in the association), ``dkf+lda+dtm`` (with the distributed tracker manager);
    each with or without online registration of the cameras (``cfg.registration``)."""
    appearance = cfg.use_appearance
    # the node's measured re-id, one for its association and its manager (reidquality)
    quality = ReidQuality(cfg) if appearance and cfg.reid_learn else None
    return Components(
        associate=LocalDataAssociation(cfg, appearance, quality),
        manager=(DistributedTrackerManager(cfg, quality) if cfg.use_manager
                 else IndependentTrackers(cfg)),
        initiator=lambda: Initiator(cfg, appearance),
        registration=(lambda camera: Registration(camera, cfg)) if cfg.registration else None)


class CameraNode:
    """The per-camera tracker: ``prepare`` then ``update`` once per frame."""

    def __init__(self, cameras: Camera | Sequence[Camera], neighbours: Iterable[int] = (),
                 config: TrackerConfig | None = None, network: str = "dmtt",
                 node_id: int | None = None, first_counter: int = 0,
                 components: Components | None = None):
        self.cameras: list[Camera] = [cameras] if isinstance(cameras, Camera) else list(cameras)
        if not self.cameras:
            raise ValueError("a node needs at least one camera")
        self.id = self.cameras[0].id if node_id is None else int(node_id)
        self.neighbours = tuple(sorted(set(int(n) for n in neighbours) - {self.id}))
        self.cfg = config or TrackerConfig()
        self.network = network
        parts = components or assemble(self.cfg)
        self.associate = parts.associate
        self.manager = parts.manager
        self.initiators = {c.id: parts.initiator() for c in self.cameras}
        self.registrations: dict[int, Registration] = (
            {c.id: parts.registration(c) for c in self.cameras} if parts.registration else {})
        self.own_views = (parts.views or partial(OwnViews, ViewSettings.of(self.cfg)))(
            self.cameras, self.registrations)
        self.book = IdentityBook(self.id, self.cfg, first_counter)
        self.memory = NeighbourMemory(self.cfg, network)
        self.screen = Screen(self.cfg, self.cameras, self.id)
        self.A = transition(self.cfg.dt)
        self.Q = process_noise(self.cfg)
        self.P_birth = birth_covariance(self.cfg)
        self.trackers = TrackerTable()  # by id, the sorted order kept
        self.stats = NodeStats()
        self.inbound = Inbound(self.neighbours, network, self.cfg.kappa,
                               self.cfg.max_trackers_per_neighbour, self.screen, self.stats)
        self._frame: int | None = None
        self._prepared = False
        self._message_rows: list[Tracker] = []
        self._raws: dict[int, BoxMeasurements] = {}  # per camera, this frame's box measurements
        # the trackers' x_bar, P, x_bar_sent ("sent"), x_hat, M as rows of one stack each (stacks)
        self._rows: dict[str, RowStack] = {}

    # ------------------------------------------------------------------------------------
    # prepare: prediction, LDA, local information, local initialisation, the message
    # ------------------------------------------------------------------------------------
    def prepare(self, k: int,
                detections: Sequence[Detection] | Mapping[int, Sequence[Detection]]) -> FrameMessage:
        self._begin(k)
        per_camera = self._split(detections)
        for cam in self.cameras:
            obs = self._observe(cam, self._usable(per_camera.get(cam.id, ())))
            unassigned = self._associate(k, cam.id, obs)
            for chain in self.initiators[cam.id].step(k, unassigned):
                self._birth(k, cam.id, chain)
        trs = self.trackers.in_order()
        if trs:  # all at once
            self._rows["sent"] = RowStack(quantize(stacked([tr.x_bar for tr in trs], self._rows.get("x_bar"))))
            for tr, x in zip(trs, self._rows["sent"].rows):
                tr.local.ell_sent = manager.ell_sent(bool(tr.local.seen_by), tr.ell)
                tr.local.x_bar_sent = x
        self._prepared = True
        return self._message(k)

    def _begin(self, k: int) -> None:
        """Check the frame order; predict every tracker from its last estimate to frame ``k``
        (through any frames this node skipped); clear the frame's local information."""
        if self._prepared:
            raise NodeStateError(f"node {self.id}: prepare({k}) called twice without update")
        if self._frame is not None and k <= self._frame:
            raise NodeStateError(f"node {self.id}: frame {k} does not follow frame {self._frame}")
        steps = 0 if self._frame is None else k - self._frame
        trs = self.trackers.in_order()
        if steps and trs:
            x_bar, P = dkf.predict(stacked([t.x_hat for t in trs], self._rows.get("x_hat")),
                                   stacked([t.M for t in trs], self._rows.get("M")), self.A, self.Q)
            for _ in range(steps - 1):
                x_bar, P = dkf.predict(x_bar, P, self.A, self.Q)
            self._rows["x_bar"], self._rows["P"] = RowStack(x_bar), RowStack(P)
            for tr, x, P_i in zip(trs, self._rows["x_bar"].rows, self._rows["P"].rows):
                tr.x_bar, tr.P = x, P_i
        # this frame's local information (eq. 2), none yet: zero rows of one stack each
        self._rows["u"] = RowStack(np.zeros((len(trs), STATE_DIM)))
        self._rows["U"] = RowStack(np.zeros((len(trs), STATE_DIM, STATE_DIM)))
        for tr, u, U in zip(trs, self._rows["u"].rows, self._rows["U"].rows):
            tr.local = LocalInfo(u, U)
        self._raws.clear()
        self._frame = k

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

    def _usable(self, dets: Sequence[Detection]) -> tuple[list[Detection], np.ndarray]:
        """Detections with a finite box of positive size and their boxes ``(n, 4)`` (others are
        counted, not measured)."""
        if not dets:
            return [], np.zeros((0, 4))
        try:  # every box four numbers (the common case): one call
            B = np.array([d.box for d in dets], float)
        except (ValueError, TypeError):
            B = None
        if B is None or B.shape != (len(dets), 4):  # box by box: a wrong shape is not usable
            boxes = [np.asarray(d.box, float) for d in dets]
            B = np.array([b if b.shape == (4,) else np.full(4, np.nan) for b in boxes])
        with np.errstate(invalid="ignore"):
            good = np.isfinite(B).all(axis=1) & (B[:, 2] > 0) & (B[:, 3] > 0)
        bad = len(B) - int(np.count_nonzero(good))
        if not bad:
            return list(dets), B
        self.stats.bad_detections += bad
        return [d for d, g in zip(dets, good) if g], B[good]

    def _observe(self, cam: Camera, usable: tuple[list[Detection], np.ndarray]) -> Observations:
        """One camera's usable detections and their boxes as measurements ``z, R``
        (registration-corrected when the node registers its cameras), all at once. The box
        measurements stay in ``self._raws`` for the frame (registration residuals, box sizes);
        an observation names its row there (``raw``)."""
        dets, boxes = usable
        if not dets:
            return Observations(np.zeros((0, 4)), np.zeros((0, 4, 4)), [])
        raws = self._raws[cam.id] = box_measurements(cam, boxes, self.cfg)
        descs = [self.associate.descriptor(d.descriptor) for d in dets]
        reg = self.registrations.get(cam.id)
        if reg is None:
            z, R = uncorrected_many(raws, self.cfg)
        else:
            z, R = reg.corrects(raws)
            if self.cfg.fixed_R is not None:
                R = np.broadcast_to(fixed_R(self.cfg), R.shape).copy()
        return Observations(z, R, descs)  # an observation's raw: its row in raws

    def _associate(self, k: int, cam_id: int, obs: Observations) -> list[Observation]:
        """LDA of one camera's measurements; each pair adds its information (eq. 2) and may
        teach the gallery. Returns the unassigned measurements."""
        ids, trs = self.trackers.ids(), self.trackers.in_order()
        P = stacked([tr.P for tr in trs], self._rows.get("P"))
        if self.cfg.naive_bound and trs:
            P = self._gate_covariances(trs, P)
        cands = Candidates(stacked([tr.x_bar for tr in trs], self._rows.get("x_bar")), P,
                           [tr.gallery for tr in trs])
        assigned = set()
        pairs = self.associate(cands, obs)
        if pairs:
            rows, js = [i for i, _ in pairs], [j for _, j in pairs]
            js_at = np.array(js, np.intp)  # (rows by take: see stacks)
            u, U = dkf.informations(obs.z.take(js_at, axis=0), obs.R.take(js_at, axis=0))
            u0, U0 = self._rows.get("u"), self._rows.get("U")
            if (u0 is not None and u0.stack([tr.local.u for tr in trs]) is u0.base
                    and U0.stack([tr.local.U for tr in trs]) is U0.base
                    and not any(trs[i].local.seen_by for i in rows)):
                # every tracker's u, U is still its zero row of the frame's stacks and no camera
                # has added to the paired ones: eq. 2's values go into their rows at once
                rows_at = np.array(rows, np.intp)
                u0.base[rows_at], U0.base[rows_at] = u, U
                for i, j in pairs:
                    trs[i].local.added(cam_id, j)
            else:
                for n, (i, j) in enumerate(pairs):
                    trs[i].local.add(cam_id, u[n], U[n], j)
            for i, j in pairs:
                trs[i].gallery.offer(obs.descriptors[j], k, self.cfg.gallery_admit)
                assigned.add(j)
            self.own_views.saw([trs[i] for i in rows], cam_id, k, self._raws[cam_id].size[js])
        for i, j in self.associate.recover(cands, obs, pairs):
            # outside the gate: R grown until the innovation sits on it; no registration residual
            tr = self.trackers[ids[i]]
            tr.local.add(cam_id, *dkf.information(obs[j].z, self._on_gate(tr, obs[j])))
            self.own_views.saw([tr], cam_id, k, self._raws[cam_id].size[[j]])
            assigned.add(j)
        return [obs[j] for j in range(len(obs)) if j not in assigned]

    def _gate_covariances(self, trs: list[Tracker], P: np.ndarray) -> np.ndarray:
        """The covariances the LDA gates with (eq. 5): ``P``, except for a tracker whose last
        update had no measurement information (``Tracker.informed``: neither this node's
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
        ell = np.fromiter((tr.ell for tr in trs), float, len(trs)) + 1.0
        naive = np.fromiter((not tr.informed for tr in trs), bool, len(trs)) & (ell <= cfg.kappa)
        if not naive.any():
            return P
        bound = cfg.m(cfg.calib_sigma) ** 2 + (ell * cfg.dt * cfg.m(cfg.birth_vel_sigma)) ** 2
        top = np.linalg.eigvalsh(P[:, :2, :2])[:, -1]
        scale = np.where(naive, np.minimum(bound / np.maximum(top, 1e-300), 1.0), 1.0)
        return P * scale[:, None, None]

    def _on_gate(self, tr: Tracker, o: Observation) -> np.ndarray:
        """``R`` of a measurement outside the LDA gate, scaled so that its Mahalanobis distance
        (eq. 5) equals the gate ``tau``: it counts, but only as much as the gate allows."""
        e = o.z[:2] - tr.x_bar[:2]
        V = tr.P[:2, :2] + o.R[:2, :2]
        d2 = float(e @ np.linalg.solve(V, e))
        R = o.R.copy()
        f = max(d2 / self.cfg.tau**2, 1.0)
        R[:2, :2] = (tr.P[:2, :2] + R[:2, :2]) * f - tr.P[:2, :2]
        return R

    def _birth(self, k: int, cam_id: int, chain: Pending) -> None:
        """Local initialisation from two observations: prior from the first, measurement from
        the last; re-identification against dropped trackers first (DTM)."""
        cfg = self.cfg
        gallery = Gallery(cfg.gallery_size, cfg.gallery_every,
                          [o.descriptor for o in chain.observations if o.descriptor is not None])
        gallery.mark(k)
        born = k
        first, last = chain.observations[0], chain.observations[-1]
        tid = self.manager.reidentify(gallery, self.book.old.candidates(), k, last.z[:2],
                                      self.book.last)
        if tid is not None:
            old_gallery = self.book.old.take(tid)
            old_gallery.extend(gallery)
            gallery = old_gallery
            born = self.book.born.get(tid, k)
            self.stats.reidentified += 1
        else:
            tid = self.book.new_id()
            self.stats.births += 1
        tr = Tracker(tid, quantize(birth_state(first.z)), self.P_birth.copy(), gallery,
                     born=born, since=k, heard=k)
        self.book.born[tid] = born
        tr.origin = np.asarray(last.z[:2], float).copy()
        tr.local.add(cam_id, *dkf.information(last.z, last.R), last.raw)
        self.own_views.saw([tr], cam_id, k, self._raws[cam_id].size[[last.raw]])
        self.trackers[tid] = tr

    def _message(self, k: int) -> FrameMessage:
        """This frame's message ``(ID, x_bar, u, U, ell)`` per tracker it sends (paper III-D),
        the appearance of the trackers new to this sender, and the merge announcements; built
        as one ``TrackerBlock`` (no per-tracker objects)."""
        trs = [tr for tr in self.trackers.in_order() if self._sends(tr)]
        self._message_rows = trs
        apps = []
        for row, tr in enumerate(trs):
            if not tr.announced and len(tr.gallery):
                apps.append((row, np.asarray(tr.gallery.newest(MAX_DESCRIPTORS), float)))  # a copy
                tr.announced = True
        if trs:
            # fresh arrays of the block's dtypes and shapes, made read-only: what the checked
            # constructor would copy them into (``encode`` checks the wire's value rules)
            ints = np.array([(tr.id[0], tr.id[1], tr.born, tr.local.ell_sent) for tr in trs], np.int64)
            cols = (*ints.T.copy(),  # camera, counter, born, ell: a contiguous row each
                    stacked([tr.local.x_bar_sent for tr in trs], self._rows.get("sent")).copy(),
                    stacked([tr.local.u for tr in trs], self._rows.get("u")).copy(),
                    stacked([tr.local.U for tr in trs], self._rows.get("U")).copy())
            for a in (*cols, *(d for _, d in apps)):
                a.setflags(write=False)
            block = TrackerBlock._trusted(*cols, tuple(apps))
        else:
            block = TrackerBlock.empty()
        return FrameMessage.from_block(self.network, self.id, k, block, self.book.announcements())

    def covariances(self) -> np.ndarray:
        """The predicted covariances ``P`` ``(n, 6, 6)`` of the last message's rows, in its
        order (the event trigger's prior; call between ``prepare`` and ``update``)."""
        if not self._message_rows:
            return np.zeros((0, 6, 6))
        return stacked([tr.P for tr in self._message_rows], self._rows.get("P")).copy()

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
        Event-triggered operation (``stale_ok=True``) also takes late, repeated and reordered
        messages up to ``kappa`` frames old and uses every neighbour's newest entry per tracker
        brought to ``k`` (``NeighbourMemory``). Messages from other networks, non-neighbours
        and future frames are ignored (counted in ``stats.ignored_messages``); a second message
        of a sender for a frame already taken is ignored (``stats.duplicate_messages``), as the
        Zenoh transport does. What the messages say is checked for meaning first (``Screen``:
        entries and merges that fail are dropped, counted in ``stats.rejected`` by reason).
        Whatever a neighbour sends, the frame is finished for every tracker.
        """
        if not self._prepared:
            raise NodeStateError(f"node {self.id}: update() without prepare()")
        k = self._frame
        msgs = self.inbound.take(inbox, k, stale_ok, self.book, self.trackers.__contains__)
        for m in msgs:
            for mg in m.merges:
                self._merge(mg.loser, mg.winner, mg.winner_born)
        if stale_ok:
            self.memory.remember(msgs)
            msgs = self.memory.at(k)
        inbox = Inbox(msgs, self.book.aliases, self.memory.observed if stale_ok else frozenset())
        adopted: Counter[int] = Counter()  # per sender, this frame
        for tid in inbox.ids():
            if tid not in self.trackers:
                sender = inbox.first_sender(tid)
                if adopted[sender] >= self.cfg.max_adoptions_per_frame:
                    self.screen.rejected["adoption_rate"] += 1  # it waits for the next frame
                    continue
                adopted[sender] += self._adopt(k, tid, inbox.infos(tid),
                                               self.memory.told.get(tid, k) if stale_ok else k)
        self.stats.rejected = dict(self.screen.rejected)
        if stale_ok:
            self._late_appearance()
        entries = inbox.entries(self.trackers.ids())
        measured = inbox.measured
        if stale_ok:
            self._correct(entries, self.memory.lagless_ell, self.memory.news)
        else:
            self._correct(entries)
        if self.registrations:
            registrar.learn(self.registrations, entries,
                            [self.trackers[t].local.per_camera for t in entries.ids], self._raws)
        mine = {c.id for c in self.cameras}
        none: frozenset[int] = frozenset()
        views = [MergeView(t.id, t.x_hat[:2], t.gallery, t.since == k, frozenset(t.local.seen_by),
                           t.born, measured.get(t.id, none), t.born == k and t.id[0] in mine,  # started
                           t.since, t.heard)
                 for t in self.trackers.in_order()]  # (in id order: the merge search sorts them)
        for loser, winner in self.manager.merges(views):
            self._merge(loser, winner)
        for tid in self.trackers.ids():
            if tid not in self.trackers:
                continue  # merged into a tracker dropped before it (heir)
            if self.trackers[tid].ell > self.cfg.kappa:
                heir = self._heir(k, views, self.trackers[tid])
                self._drop(tid)
                if heir is not None:  # it takes the dropped id back (manager.heir)
                    self._merge(heir, tid)
                    self.stats.stitched += 1
            elif not self._in_scope(self.trackers[tid]):
                self._drop(tid)
                self.stats.out_of_scope += 1
        self._reappear(k)
        self._prepared = False
        self.book.forget(set(self.trackers))
        return self.tracks()

    def _correct(self, entries: Entries, lagless: dict[TrackerId, int] | None = None,
                 news: set[TrackerId] | frozenset[TrackerId] = frozenset()) -> None:
        """Eqs. 3-4 for every tracker with its neighbours' entries, all at once, then ``ell``
        (eq. 8) and ``coast``, the frames in a row ``ell`` grew. With late messages
        (event-triggered operation) a neighbour's ``ell`` ages by its link's lag
        (``NeighbourMemory``), which is right for the drop (eq. 8) but is no news that nobody
        sees the target: ``coast`` counts only growth beyond the lag (``lagless``: per tracker
        the neighbours' smallest ``ell`` aged by their silences alone), and counts all of it:
        over a late link news comes in bursts (three frames of growth at once) and in gaps (no
        message: no news, ``coast`` holds; ``news`` names the trackers whose senders were
        heard). Before, a target only a neighbour saw stopped being reported whenever the lag
        jittered up: with every message 1-4 frames late terrace-gt's ground misses went from
        460 to 1096.

        Eq. 3 sums this node's information and each neighbour's (``y``, ``S``), in the order
        the entries arrive (sender order), and the consensus term's differences
        ``x_bar_j - x_bar`` use this node's prediction as the neighbours received it.
        The entries passed ``Screen`` (``U`` positive semi-definite, bounded), so with ``P``
        positive definite ``I + P S`` is invertible and nothing here can fail; should a
        correction fail numerically anyway, that tracker alone keeps its prediction for the
        frame (counted in ``stats.numerical``) and every other tracker is corrected as usual."""
        ids, rows = entries.ids, entries.rows
        if not ids:
            return
        trs = [self.trackers[t] for t in ids]
        x_bar = stacked([tr.x_bar for tr in trs], self._rows.get("x_bar"))
        P = stacked([tr.P for tr in trs], self._rows.get("P"))
        ref = stacked([tr.x_bar if tr.local.x_bar_sent is None else tr.local.x_bar_sent for tr in trs],
                      self._rows.get("sent"))
        # eq. 3's y and eq. 4's consensus sum in one table: (u | x_bar_j - x_bar_sent) per entry
        y_diff = entries.summed(np.concatenate((stacked([tr.local.u for tr in trs], self._rows.get("u")),
                                                np.zeros(x_bar.shape)), axis=1),
                                np.concatenate((entries.u, entries.x_bar - ref.take(rows, axis=0)), axis=1))
        y, diff = y_diff[:, :STATE_DIM], y_diff[:, STATE_DIM:]
        S = entries.summed(stacked([tr.local.U for tr in trs], self._rows.get("U")), entries.U)
        upm = self.cfg.units_per_metre
        deg = np.bincount(rows, minlength=len(ids))  # terms of each consensus sum (eq. 4)
        bound = self.cfg.consensus_bound
        try:
            x_hat, M = dkf.corrects(x_bar, P, y, S, diff, upm, degree=deg, bound=bound)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            x_hat, M = np.full_like(x_bar, np.nan), np.full_like(P, np.nan)
            for i in range(len(ids)):  # one at a time: a failure stays with its tracker
                try:
                    x_hat[i:i + 1], M[i:i + 1] = dkf.corrects(x_bar[i:i + 1], P[i:i + 1], y[i:i + 1],
                                                              S[i:i + 1], diff[i:i + 1], upm,
                                                              degree=deg[i:i + 1], bound=bound)
                except (np.linalg.LinAlgError, ValueError, FloatingPointError):
                    pass
        bad = ~(np.isfinite(x_hat).all(axis=1) & np.isfinite(M).all(axis=(1, 2)))
        if bad.any():
            self.stats.numerical += int(bad.sum())
            x_hat[bad], M[bad] = x_bar[bad], P[bad]
        self._rows["x_hat"], self._rows["M"] = RowStack(x_hat), RowStack(M)
        ells = self.manager.ells([tr.local.ell_sent for tr in trs], rows, entries.ell).tolist()  # eq. 8
        informed = S[:, :2, :2].any(axis=(1, 2)).tolist()
        k = self._frame
        for tr, ell, x_i, M_i, inf in zip(trs, ells, self._rows["x_hat"].rows, self._rows["M"].rows,
                                          informed):
            tr.x_hat, tr.M = x_i, M_i
            tr.informed = inf
            seen_before = tr.ell - tr.lag
            tr.ell = ell
            if lagless is None:  # synchronous: every neighbour's news of frame k is here
                tr.coast = tr.coast + 1 if tr.ell > seen_before else 0
            else:
                seen = self.manager.ell(tr.local.ell_sent, [lagless[tr.id]] if tr.id in lagless else [])
                tr.lag = tr.ell - seen
                if seen > seen_before:  # news arrives in bursts over a late link: count all of it
                    tr.coast += seen - seen_before
                elif tr.local.ell_sent == 0 or tr.id in news:  # seen, or news that did not age it
                    tr.coast = 0
            if tr.coast == 0 and k > tr.since:
                tr.held += 1

    def _adopt(self, k: int, tid: TrackerId, infos: list[TrackerInfo], heard: int | None = None) -> bool:
        """A tracker heard of from neighbours but not held here (paper III-C, case 1);
        ``heard``: the frame of the oldest message that told of it (``k`` unless it came late).
        Whether it was adopted."""
        ell = min(t.ell for t in infos)
        if ell > self.cfg.kappa or not self.manager.may_adopt(tid, self.book.dropped):
            return False
        if self.cfg.scope_hops and ell >= self.cfg.scope_hops:
            # Beyond this node's scope: not held. Its appearance, sent once with the first entry
            # of a sender, is kept with the dropped trackers' galleries, so that a later
            # adoption (the target came closer) has it. (Without this, scope 2 on corridor-4
            # adopted 11 trackers without appearance, whose co-motion merges joined different
            # people, and the middle nodes started 42-48 trackers instead of 6-7.)
            if self.manager.keeps_galleries and tid not in self.book.old:
                heard = self._gallery(infos, Gallery(self.cfg.gallery_size, self.cfg.gallery_every))
                if len(heard):
                    self.book.note_born(tid, infos[0].born)  # its rank, should it be re-found here
                    self.book.retire(tid, heard, True)
            return False
        src = infos[0]  # messages are sorted by sender: deterministic choice
        gallery = Gallery(self.cfg.gallery_size, self.cfg.gallery_every)
        if tid in self.book.old:
            gallery = self.book.old.take(tid)
            self.stats.reactivated += 1
        else:
            self.stats.adopted += 1
        gallery = self._gallery(infos, gallery)
        born = self.book.note_born(tid, src.born)
        tr = Tracker(tid, np.array(src.x_bar, float), self.P_birth.copy(), gallery, born=born,
                     since=k, heard=k if heard is None else min(heard, k),
                     heard_appearance=any(t.appearance is not None for t in infos), informed=False)
        tr.local.ell_sent = ell
        tr.local.x_bar_sent = tr.x_bar
        self.trackers[tid] = tr
        return True

    def _late_appearance(self) -> None:
        """Event-triggered: a neighbour's first entry of a tracker, which carries its
        appearance, came after a newer entry (``NeighbourMemory.late_appearance``): a tracker
        adopted here from entries without appearance takes it, as adoption would have."""
        for tid, app in sorted(self.memory.late_appearance.items()):
            tr = self.trackers.get(self.book.resolve(tid))
            if tr is None or tr.heard_appearance:
                continue
            self._descriptors(app, tr.gallery)
            tr.heard_appearance = True

    def _gallery(self, infos: list[TrackerInfo], gallery: Gallery) -> Gallery:
        """``gallery`` with the descriptors the neighbours' entries carry."""
        for t in infos:
            if t.appearance is not None:
                self._descriptors(t.appearance, gallery)
        return gallery

    def _descriptors(self, appearance: np.ndarray, gallery: Gallery) -> None:
        for d in appearance:
            d = self.associate.descriptor(d)
            if d is not None:
                gallery.add(d)

    def _merge(self, loser: TrackerId, winner: TrackerId, winner_born: int | None = None) -> None:
        """Apply ``loser -> winner`` here and announce it (so it propagates hop by hop)."""
        pair = self.book.alias(loser, winner, winner_born)
        if pair is None:
            return
        loser, winner = pair
        lt = self.trackers.pop(loser, None)
        wt = self.trackers.get(winner)
        old = self.book.old
        if lt is not None and wt is not None:
            wt.absorb(lt)
            self.stats.merged += 1
        elif lt is not None:  # only the loser is held here: it takes the winner's id and rank
            lt.id = winner
            lt.born = self.book.born.get(winner, lt.born)
            lt.announced = False  # neighbours may not know the winner's appearance
            if winner in old:
                lt.gallery.extend(old.take(winner))
            self.trackers[winner] = lt
        elif loser in old:  # a dropped tracker's gallery follows its id
            hearsay = loser in old.hearsay
            g = old.take(loser)
            if wt is not None:
                wt.gallery.extend(g)
            elif winner in old:
                old.extend(winner, g)
            else:
                old.put(winner, g, reid=not hearsay)
        self.manager.forget(loser)

    # ------------------------------------------------------------------------------------
    # regional scope (our addition; cfg.scope_hops, needs the DTM's ell consensus)
    # ------------------------------------------------------------------------------------
    # By eq. 8 a node h >= 1 hops from the nearest camera that sees a target holds ell = h - 1,
    # and while nobody sees it every node's ell grows by one a frame, counted in ``coast``; so
    # ``ell - coast`` is how far, in hops minus one, the node is from the cameras that saw the
    # target last, whether it is seen now or not. With scope H a node keeps a tracker while
    # ell - coast < H (hops <= H) and sends it only while its receivers may keep it: the
    # cameras within H hops of a target hold it, the ones next to its cameras already hold it
    # when it walks into their view (the hand-over keeps the id), and the others never hear
    # of it. A node letting go keeps the gallery for re-identification like any drop (DTM).
    def _in_scope(self, tr: Tracker) -> bool:
        """Whether this node keeps ``tr``: within ``scope_hops`` hops (always without scope)."""
        return not self.cfg.scope_hops or tr.ell - tr.coast < self.cfg.scope_hops

    def _sends(self, tr: Tracker) -> bool:
        """Whether this frame's message carries ``tr``: a receiver one hop farther keeps it."""
        return not self.cfg.scope_hops or tr.local.ell_sent - tr.coast < self.cfg.scope_hops

    def _heir(self, k: int, views: list[MergeView], tr: Tracker) -> TrackerId | None:
        """The tracker that took over the target of ``tr``, which is being dropped
        (``manager.heir``); only for a tracker the network kept alive (``confirmed``)."""
        if not tr.confirmed or tr.x_hat is None:
            return None
        held = [v for v in views if v.id in self.trackers]
        lost = next((v for v in held if v.id == tr.id), None)
        return None if lost is None else self.manager.heir(lost, tr.ell, held, k)

    def _young(self, tr: Tracker) -> Young:
        return Young(tr.id, tr.born, tr.x_hat, tr.gallery, tr.origin)

    def _gone(self) -> list[Gone]:
        """The dropped trackers that may re-appear (``reappear.Gone``)."""
        old = self.book.old
        return gone_trackers(old.candidates(), old.last, old.motion)

    def _reappear(self, k: int) -> None:
        """Trackers this node's cameras created ``reappear_age`` frames ago that go on where a
        dropped tracker was heading take its id, by a merge announced like any other
        (``manager.reappearances``); only the creator decides, so one decision per tracker."""
        age = self.cfg.reappear_age
        young = [self._young(t) for t in self.trackers.in_order()
                 if t.origin is not None and k - t.born == age and t.x_hat is not None]  # created here
        if not young:
            return
        for new, old in self.manager.reappearances(young, self._gone(), k):
            self._merge(new, old)
            self.stats.reappeared += 1

    def _drop(self, tid: TrackerId) -> None:
        """Drop ``tid`` (eq. 8: its ``ell`` passed ``kappa``) and retire it to the identity book.
        A tracker the network never kept alive after it appeared here (``confirmed``: one
        message's plausible hearsay, such as a phantom flood's) is kept for a later adoption
        of its id but not for re-identification: a person appearing later where it went must
        not take its id (the zombie probe's flood gave a phantom the id of a person born 54
        frames after it was dropped, on every node)."""
        tr = self.trackers.pop(tid)
        self.manager.forget(tid)
        self.stats.dropped += 1
        self.book.retire(tid, tr.gallery, self.manager.keeps_galleries, self._frame,
                         None if tr.x_hat is None else tr.x_hat[:2], reid=tr.confirmed,
                         x=tr.x_hat, seen=self._frame - tr.ell)

    # ------------------------------------------------------------------------------------
    @property
    def next_counter(self) -> int:
        """The counter the next new tracker of this node will get (persist it across restarts)."""
        return self.book.counter

    @property
    def frame(self) -> int | None:
        return self._frame

    def tracks(self) -> list[Track]:
        """The current estimates (after the last ``update``): the trackers it reports."""
        held = self.trackers.in_order()
        shown = [t for t in held if t.x_hat is not None and self._reported(t)]
        alias: dict[TrackerId, TrackerId] = {}
        if self.cfg.hide_pending and len(shown) > 1:
            ids = {t.id for t in shown}
            new = self._frame - self.cfg.comotion_frames
            pend = self.manager.pending({t.id: t.born for t in held})
            hidden = {young for young, old in pend
                      if old in ids and self.trackers[young].since >= new}
            if self.cfg.pending_alias:
                for young, old in pend:
                    if old not in ids and young in ids and young not in alias and old not in alias.values():
                        alias[young] = old
            shown = [t for t in shown if t.id not in hidden]
        elif self.cfg.pending_alias and shown:
            ids = {t.id for t in shown}
            for young, old in self.manager.pending({t.id: t.born for t in held}):
                if old not in ids and young in ids and young not in alias and old not in alias.values():
                    alias[young] = old
        fresh = [t for t in shown
                 if self._frame - t.born < self.cfg.reappear_age + self.cfg.reappear_hide]
        if fresh:  # not yet told whether they are a dropped tracker re-appearing (reappear.py)
            gone = self._gone()
            waiting = {t.id for t in fresh
                       if self.manager.awaiting(self._young(t), gone, self._frame)}
            shown = [t for t in shown if t.id not in waiting]
        if not shown:
            return []
        x_hat = stacked([t.x_hat for t in shown], self._rows.get("x_hat"))
        boxes = self.own_views.boxes(shown, self._frame, x_hat)
        x_hat = x_hat.copy()  # the tracks' own
        M = stacked([t.M for t in shown], self._rows.get("M")).copy()
        return [Track._built(alias.get(t.id, t.id), self._frame, x, M_i, bool(t.local.seen_by), t.ell, b)
                for t, x, M_i, b in zip(shown, x_hat, M, boxes)]

    def _reported(self, tr: Tracker) -> bool:
        """A tracker is reported (returned by ``update``, written, drawn, evaluated) unless it
        has coasted more than ``report_coast`` frames: its ``ell`` grew that many frames in a
        row, so no camera of the network has seen the target since. It is still predicted,
        fused, merged and kept for re-association until ``ell`` exceeds ``kappa`` (eq. 8); only
        the estimate nobody observes, which drifts away at constant velocity, is not shown.
        The test is on the *growth* of ``ell``, not its value: a node ``h`` hops from the
        cameras that see a target holds ``ell = h - 1`` while they see it."""
        return tr.coast <= self.cfg.report_coast
