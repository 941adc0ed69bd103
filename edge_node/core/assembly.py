"""How a node is assembled: which part plays each role, each given its own slice of the
configuration (``config.Slice``), never the whole tree.

``Components`` are the replaceable parts, each a factory (or an instance) with a default from
``assemble(cfg)``: the paper's three configurations (Sec. IV-B) are three assemblies, and a test
passes fakes (``tests/fakes.py``). ``roles(...)`` builds a node's roles from them around the
node's own state (its identity book, neighbour memory, screen, registrations and counters).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

from edge_node.core.association import AssociationSettings, LocalDataAssociation
from edge_node.core.associator import Associator, AssociatorSettings
from edge_node.core.config import TrackerConfig
from edge_node.core.identity import IdentityBook, IdentitySettings
from edge_node.core.inbound import Inbound
from edge_node.core.initiator import Initiator, InitiatorSettings
from edge_node.core.lifecycle import Lifecycle, LifecycleSettings
from edge_node.core.manager import DistributedTrackerManager, IndependentTrackers, ManagerSettings
from edge_node.core.measurement import MeasurerSettings
from edge_node.core.measurer import Measurer
from edge_node.core.memory import MemorySettings, NeighbourMemory
from edge_node.core.model import MotionSettings
from edge_node.core.outbound import Outbound
from edge_node.core.predictor import Predictor
from edge_node.core.registrar import Registrar
from edge_node.core.registration import Registration, RegistrationSettings
from edge_node.core.reidquality import ReidQuality, ReidSettings
from edge_node.core.reporter import Reporter, ReporterSettings
from edge_node.core.screen import Screen, ScreenSettings
from edge_node.core.stats import NodeStats
from edge_node.core.trust import Trust, TrustSettings
from edge_node.core.updater import Updater, UpdaterSettings
from edge_node.core.views import OwnViews, ViewSettings
from edge_node.geometry import Camera

Manager = DistributedTrackerManager | IndependentTrackers


@dataclass(frozen=True)
class Components:
    """What a node is assembled from: the parts a user may replace (``assemble`` gives the
    configuration's). Factories take what the part needs of the node, nothing more."""

    associate: LocalDataAssociation  # the association itself (eqs. 5-7)
    manager: Manager  # the DTM's rules
    initiator: Callable[[], Initiator]  # one per camera
    registration: Callable[[Camera], Registration] | None = None  # one per camera, or none
    #: what each camera draws, from the node's cameras and registrations (``saw``, ``boxes``
    #: and ``unseen_limit``, the reporter's negative-evidence limit, 0: none; ``OwnViews``;
    #: with ``expected`` too, the trust role judges claims against it: "Refuted" in trust.py)
    views: Callable[[Sequence[Camera], Mapping[int, Registration]], Any] | None = None
    predictor: Any = None  # the motion model's prediction (``Predictor``)
    updater: Callable[[NodeStats], Any] | None = None  # eqs. 3-4, given the node's counters


def assemble(cfg: TrackerConfig) -> Components:
    """The paper's configurations (Sec. IV-B): ``dkf`` (geometry only, no manager), ``dkf+lda``
    (appearance in the association), ``dkf+lda+dtm`` (with the distributed tracker manager);
    each with or without online registration of the cameras (``cfg.registration``)."""
    appearance = cfg.use_appearance
    # the node's measured re-id, one for its association and its manager (reidquality)
    quality = ReidQuality(ReidSettings.of(cfg)) if appearance and cfg.reid_learn else None
    manager = ManagerSettings.of(cfg)
    registration = RegistrationSettings.of(cfg)
    initiator = InitiatorSettings.of(cfg)
    return Components(
        associate=LocalDataAssociation(AssociationSettings.of(cfg), appearance, quality),
        manager=(DistributedTrackerManager(manager, quality) if cfg.use_manager
                 else IndependentTrackers(manager)),
        initiator=lambda: Initiator(initiator, appearance),
        registration=(lambda camera: Registration(camera, registration)) if cfg.registration else None,
        views=partial(OwnViews, ViewSettings.of(cfg)),
        predictor=Predictor(MotionSettings.of(cfg)),
        updater=partial(Updater, UpdaterSettings.of(cfg)))


@dataclass
class Roles:
    """A node's roles, in the order of a frame (paper Fig. 1), and the node-owned state they
    share (identity book, neighbour memory, screen, registrations)."""

    predictor: Any
    measurer: Measurer
    associator: Associator
    initiators: dict[int, Initiator]
    lifecycle: Lifecycle
    inbound: Inbound
    trust: Trust
    updater: Any
    registrar: Registrar
    outbound: Outbound
    reporter: Reporter
    views: Any
    book: IdentityBook
    memory: NeighbourMemory
    screen: Screen
    registrations: dict[int, Registration]


def roles(cfg: TrackerConfig, parts: Components, cameras: Sequence[Camera],
          neighbours: Sequence[int], network: str, node_id: int, first_counter: int,
          stats: NodeStats) -> Roles:
    """A node's roles from ``parts`` (``Components``; missing ones from ``assemble(cfg)``),
    each given its slice of ``cfg``."""
    default = assemble(cfg)
    pick = lambda name: getattr(parts, name) or getattr(default, name)  # noqa: E731
    ids = [c.id for c in cameras]
    registrations = {c.id: parts.registration(c) for c in cameras} if parts.registration else {}
    views = pick("views")(cameras, registrations)
    book = IdentityBook(node_id, IdentitySettings.of(cfg), first_counter)
    memory = NeighbourMemory(MemorySettings.of(cfg), network)
    screen = Screen(ScreenSettings.of(cfg), list(cameras), node_id)
    manager, lda = parts.manager, parts.associate
    lifecycle = Lifecycle(manager, book, LifecycleSettings.of(cfg), ids, lda.descriptor, stats,
                          screen.rejected)
    return Roles(
        predictor=pick("predictor"),
        measurer=Measurer(MeasurerSettings.of(cfg), cameras, registrations, lda.descriptor, stats),
        associator=Associator(lda, AssociatorSettings.of(cfg)),
        initiators={c.id: parts.initiator() for c in cameras},
        lifecycle=lifecycle,
        inbound=Inbound(neighbours, network, cfg.kappa, cfg.max_trackers_per_neighbour, screen,
                        stats, memory),
        trust=Trust(TrustSettings.of(cfg), neighbours, screen.rejected, views),
        updater=pick("updater")(stats),
        registrar=Registrar(registrations, ids),
        outbound=Outbound(network, node_id, cfg.scope_hops, book),
        reporter=Reporter(manager, lifecycle.young, lifecycle.gone, views, ReporterSettings.of(cfg)),
        views=views, book=book, memory=memory, screen=screen, registrations=registrations)


__all__ = ["Components", "Roles", "assemble", "roles"]
