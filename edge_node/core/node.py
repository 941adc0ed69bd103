"""``CameraNode``: one camera's complete tracker (paper Section III), pure and deterministic.

The node only composes roles, each with one job, after Stone Soup's tracker
(``stonesoup/tracker/simple.py``); every tracker quantity lives in one table
(``state.NodeState``). One cycle per frame ``k``, in the order of the paper's Fig. 1:

``prepare(k, detections) -> FrameMessage``
    ``predictor`` (every tracker to ``k``), per camera ``measurer`` (boxes to ``z, R``),
    ``associator`` (eqs. 5-7 and eq. 2's information), ``initiator`` and ``lifecycle.birth``
    (two observations make a tracker), ``views.saw`` (the sizes each camera draws), and
    ``outbound`` (the message: ``(ID, x_bar, u, U, ell)`` per tracker, appearance, merges).

``update(inbox) -> list[Track]``
    ``inbound`` (accept, bound, screen; event-triggered, the neighbour memory), ``lifecycle``
    (announced merges, adoptions), ``updater`` (eqs. 3-4), ``lifecycle.count`` (eq. 8),
    ``registrar`` (registration residuals), ``lifecycle.manage`` (merges, drops,
    re-identification) and ``reporter`` (the tracks and each camera's own boxes).

``assemble`` builds the paper's three configurations (Sec. IV-B); a test may pass its own
components. A node may own several cameras: the centralized baseline is a node that owns all
of them and has no neighbours. No I/O, no clock, no randomness: same inputs, same outputs.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial

import edge_node.core.registrar as registrar
from edge_node.core.association import LocalDataAssociation
from edge_node.core.associator import Associator
from edge_node.core.config import TrackerConfig
from edge_node.core.identity import IdentityBook
from edge_node.core.inbound import Inbound
from edge_node.core.initiator import Initiator
from edge_node.core.lifecycle import Lifecycle
from edge_node.core.manager import DistributedTrackerManager, IndependentTrackers
from edge_node.core.measurer import Measurer
from edge_node.core.memory import NeighbourMemory
from edge_node.core.outbound import Outbound
from edge_node.core.predictor import Predictor
from edge_node.core.registration import Registration
from edge_node.core.reidquality import ReidQuality
from edge_node.core.reporter import Reporter
from edge_node.core.screen import Screen
from edge_node.core.state import NodeState, TrackerRows
from edge_node.core.types import Detection, Track
from edge_node.core.updater import Updater
from edge_node.core.views import OwnViews, ViewSettings
from edge_node.geometry import Camera
from protocol.errors import DmttError
from protocol.messages import FrameMessage

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
    """What a node is assembled from (the replaceable parts)."""

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
        self.cfg = cfg = config or TrackerConfig()
        self.network = network
        parts = components or assemble(cfg)
        self.associate, self.manager, self.stats = parts.associate, parts.manager, NodeStats()
        self.state = NodeState(len(self.cameras))
        self.trackers = TrackerRows(self.state)  # by id, for code off the hot path
        self.registrations: dict[int, Registration] = (
            {c.id: parts.registration(c) for c in self.cameras} if parts.registration else {})
        self.own_views = (parts.views or partial(OwnViews, ViewSettings.of(cfg)))(
            self.cameras, self.registrations)
        self.book = IdentityBook(self.id, cfg, first_counter)
        self.memory = NeighbourMemory(cfg, network)
        self.screen = Screen(cfg, self.cameras, self.id)
        self.predictor = Predictor(cfg)
        self.measurer = Measurer(cfg, self.cameras, self.registrations,
                                 self.associate.descriptor, self.stats)
        self.associator = Associator(self.associate, cfg)
        self.initiators = {c.id: parts.initiator() for c in self.cameras}
        self.lifecycle = Lifecycle(self.manager, self.book, cfg, [c.id for c in self.cameras],
                                   self.associate.descriptor, self.stats, self.screen.rejected)
        self.outbound = Outbound(network, self.id, cfg.scope_hops, self.book)
        self.inbound = Inbound(self.neighbours, network, cfg.kappa, cfg.max_trackers_per_neighbour,
                               self.screen, self.stats, self.memory)
        self.updater = Updater(cfg, self.stats)
        self.reporter = Reporter(self.manager, self.lifecycle.young, self.lifecycle.gone,
                                 self.own_views, cfg)
        self._frame: int | None = None
        self._prepared = False
        self._raws: dict = {}  # per camera, this frame's box measurements

    def prepare(self, k: int,
                detections: Sequence[Detection] | Mapping[int, Sequence[Detection]]) -> FrameMessage:
        """Frame ``k``'s local half: prediction, association, births, the message."""
        if self._prepared:
            raise NodeStateError(f"node {self.id}: prepare({k}) called twice without update")
        if self._frame is not None and k <= self._frame:
            raise NodeStateError(f"node {self.id}: frame {k} does not follow frame {self._frame}")
        per_camera = self.measurer.split(self.id, detections)
        state, steps = self.state, 0 if self._frame is None else k - self._frame
        self.predictor(state, steps)
        state.begin_frame()
        self._frame, self._raws = k, {}
        for c, cam in enumerate(self.cameras):
            obs, raws = self.measurer(cam, per_camera.get(cam.id, ()))
            if raws is not None:
                self._raws[cam.id] = raws
            for chain in self.initiators[cam.id].step(k, self.associator(state, c, k, obs)):
                self.lifecycle.birth(state, k, c, chain)
        self.own_views.saw(state, k, self._raws)
        self.outbound.sent_values(state)
        self._prepared = True
        return self.outbound.message(state, k)

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
        state, k = self.state, self._frame
        msgs = self.inbound.take(inbox, k, stale_ok, self.book, state.__contains__)
        self.lifecycle.announced(state, msgs)
        heard = self.inbound.gather(msgs, k, stale_ok, self.book.aliases)
        self.lifecycle.adopt(state, k, heard)
        self.stats.rejected = dict(self.screen.rejected)
        entries = heard.inbox.entries(state.ids)
        self.updater(state, entries)
        self.lifecycle.count(state, k, entries, heard.lagless, heard.news)
        if self.registrations:
            registrar.learn(self.registrations, entries, state, [c.id for c in self.cameras],
                            self._raws)
        self.lifecycle.manage(state, k, heard.inbox.measured)
        self._prepared = False
        return self.tracks()

    def tracks(self) -> list[Track]:
        """The current estimates (after the last ``update``): the trackers it reports."""
        return self.reporter(self.state, self._frame)

    def covariances(self):
        """The predicted covariances ``P`` ``(n, 6, 6)`` of the last message's rows, in its
        order (the event trigger's prior; call between ``prepare`` and ``update``)."""
        return self.outbound.covariances()

    def resync_message(self, msg: FrameMessage) -> FrameMessage:
        """``msg`` with every tracker's appearance attached (``Outbound.resync``)."""
        return self.outbound.resync(msg, self.state)

    @property
    def next_counter(self) -> int:
        """The counter the next new tracker of this node will get (persist it across restarts)."""
        return self.book.counter

    @property
    def frame(self) -> int | None:
        return self._frame
