"""``CameraNode``: one camera's complete tracker (paper Section III), pure and deterministic.

The node only composes roles, each with one job, after Stone Soup's tracker
(``stonesoup/tracker/simple.py``); every tracker quantity lives in one table
(``state.NodeState``). One cycle per frame ``k``, in the order of the paper's Fig. 1:

``prepare(k, detections) -> FrameMessage``
    ``predictor`` (every tracker to ``k``), per camera ``measurer`` (boxes to ``z, R``),
    ``associator`` (eqs. 5-7 and eq. 2's information), ``initiator`` and ``lifecycle.birth``
    (two observations make a tracker), ``views.saw`` (what each camera measured), and
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

from collections.abc import Iterable, Mapping, Sequence

from edge_node.core.assembly import Components, assemble, roles
from edge_node.core.config import TrackerConfig
from edge_node.core.state import NodeState, TrackerRows
from edge_node.core.stats import NodeStats
from edge_node.core.types import Detection, Track
from edge_node.geometry import Camera
from protocol.errors import DmttError
from protocol.messages import FrameMessage

__all__ = ["CameraNode", "Components", "NodeStateError", "NodeStats", "assemble"]


class NodeStateError(DmttError, RuntimeError):
    """``prepare`` and ``update`` called out of order, or frames going backwards."""


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
        r = roles(cfg, parts, self.cameras, self.neighbours, network, self.id, first_counter,
                  self.stats)
        self.book, self.memory, self.screen, self.registrations = (r.book, r.memory, r.screen,
                                                                    r.registrations)
        self.predictor, self.measurer, self.associator = r.predictor, r.measurer, r.associator
        self.initiators, self.lifecycle, self.inbound = r.initiators, r.lifecycle, r.inbound
        self.trust = r.trust
        self.updater, self.registrar, self.outbound = r.updater, r.registrar, r.outbound
        self.reporter, self.own_views = r.reporter, r.views
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
                self.lifecycle.birth(state, k, c, chain.observations)
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
        msgs = self.trust(state, msgs, k, self.book.resolve)
        self.stats.trust = self.trust.summary()
        self.lifecycle.announced(state, msgs)
        heard = self.inbound.gather(msgs, k, stale_ok, self.book.aliases)
        self.lifecycle.adopt(state, k, heard)
        self.stats.rejected = dict(self.screen.rejected)
        entries = heard.inbox.entries(state.ids)
        self.updater(state, entries)
        self.lifecycle.count(state, k, entries, heard.lagless, heard.news)
        self.registrar(state, entries, self._raws)
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
