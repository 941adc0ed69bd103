"""A tracker as one node holds it: lasting state, and this frame's local information.

Lasting state (``Tracker``): the prediction ``x_bar, P`` for the current frame, the last
estimate ``x_hat, M`` (eq. 4), the gallery, the drop counter ``ell`` (eq. 8), and who and when
(``born`` at the originating camera, ``since`` on this node).

This frame's working values (``LocalInfo``, rebuilt by every ``prepare``): the local
measurement information ``u, U`` (eq. 2), which of the node's cameras saw the target, and what
the node's message says about it (``ell`` and ``x_bar`` as sent, rounded to the wire).

A node holds its trackers in a ``TrackerTable``: a ``dict`` by id that keeps their sorted order
between changes (a frame visits them in id order eight times).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from edge_node.core.gallery import Gallery
from edge_node.core.model import STATE_DIM
from protocol.messages import TrackerId


# No measurement: one shared, read-only pair of zeros (``add`` builds new arrays; a fresh pair
# for every tracker and frame was 40 allocations a frame at 20 targets)
_NO_u = np.zeros(STATE_DIM)
_NO_U = np.zeros((STATE_DIM, STATE_DIM))
_NO_u.setflags(write=False)
_NO_U.setflags(write=False)
# frames in which the network must keep a tracker alive after it appeared on a node before it
# counts as a person (two, as a birth needs two observations): one message's phantom, or one
# stray detection associated to it, is hearsay (the zombie probe's flood)
CONFIRM_FRAMES = 2


class LocalInfo:
    """One tracker's part of this node's frame: filled by ``prepare``, used by ``update``. (A
    plain slotted class: one is built per tracker and frame, and a dataclass's default
    factories cost more than the fields.)"""

    __slots__ = ("u", "U", "seen_by", "ell_sent", "x_bar_sent", "per_camera")

    def __init__(self, u: np.ndarray = _NO_u, U: np.ndarray = _NO_U, seen_by: set[int] | None = None,
                 ell_sent: int = 0, x_bar_sent: np.ndarray | None = None,
                 per_camera: dict[int, tuple[np.ndarray, np.ndarray, object]] | None = None):
        self.u, self.U = u, U  # eq. 2, summed over this node's cameras
        self.seen_by = set() if seen_by is None else seen_by  # its cameras that associated it
        self.ell_sent = ell_sent  # eq. 8 as this node reports it
        self.x_bar_sent = x_bar_sent  # x_bar as the neighbours receive it (wire precision)
        # per camera of this node: its (u, U) and the row of its box measurement in the
        # frame's BoxMeasurements of that camera (registration residuals)
        self.per_camera = {} if per_camera is None else per_camera

    def add(self, camera: int, u: np.ndarray, U: np.ndarray, raw: object = None) -> None:
        """Several cameras of one node add up (eq. 3)."""
        if not self.seen_by:  # the first camera: nothing to add it to
            self.u, self.U = u, U
        else:
            self.u, self.U = self.u + u, self.U + U
        self.seen_by.add(camera)
        self.per_camera[camera] = (u, U, raw)

    def added(self, camera: int, raw: object = None) -> None:
        """``add`` of the first camera whose ``u, U`` were written into this tracker's own
        ``u, U`` (the rows of the node's stacks of the frame, all pairs at once)."""
        self.seen_by.add(camera)
        self.per_camera[camera] = (self.u, self.U, raw)


@dataclass
class Tracker:
    id: TrackerId
    x_bar: np.ndarray  # prediction for the current frame
    P: np.ndarray  # its covariance
    gallery: Gallery
    ell: int = 0  # eq. 8 after the last update
    coast: int = 0  # consecutive frames ell grew: nobody in the network saw the target
    lag: int = 0  # how much of ell is the neighbours' link lag (late messages; 0 in sync)
    born: int = 0  # frame its originating camera created it (same on every node)
    since: int = 0  # frame it appeared on this node
    # frame of the news by which it appeared here: ``since`` for a birth or an adoption from
    # messages on time; the frame of the oldest message that told of it when they came late
    heard: int = 0
    heard_appearance: bool = True  # adopted with the appearance a neighbour's entry carries
    # frames after it appeared here in which the network kept it alive (``ell`` held): with
    # CONFIRM_FRAMES of them it is a person, not one message's hearsay (``confirmed``)
    held: int = 0
    announced: bool = False  # appearance already sent by this node
    # where its own camera measured it at birth (on the node that created it; reappear.py)
    origin: np.ndarray | None = None
    # whether the last update (eq. 3) had measurement information on it, its own cameras' or
    # a neighbour's; False for a tracker adopted from neighbours until some arrives
    informed: bool = True
    x_hat: np.ndarray | None = None  # estimate of the last update (eq. 4)
    M: np.ndarray | None = None  # its covariance
    local: LocalInfo = field(default_factory=LocalInfo)
    # per camera of this node: (last frame it measured the target, its box size in ground units
    # along the image axes, smoothed): what that camera's own view draws
    views: dict[int, tuple[int, np.ndarray]] = field(default_factory=dict)

    @property
    def confirmed(self) -> bool:
        """Whether the network kept it alive in ``CONFIRM_FRAMES`` frames after it appeared on
        this node: only such a tracker is re-identified when dropped (``CameraNode._drop``)."""
        return self.held >= CONFIRM_FRAMES

    def certainty(self) -> float:
        return float(np.trace(self.P))

    def absorb(self, other: "Tracker") -> None:
        """Merge ``other`` (the same target under another id) into this tracker: the more
        certain estimate, both cameras' measurement information, the union of galleries, the
        smaller ``ell``."""
        if other.certainty() < self.certainty():
            self.x_bar, self.P = other.x_bar, other.P
            self.local.x_bar_sent = other.local.x_bar_sent
            if other.x_hat is not None:
                self.x_hat, self.M = other.x_hat, other.M
        if other.local.seen_by and not self.local.seen_by:
            self.local.u, self.local.U = other.local.u, other.local.U
        self.local.seen_by |= other.local.seen_by
        self.gallery.extend(other.gallery)
        if other.ell < self.ell:
            self.lag = other.lag
        self.ell = min(self.ell, other.ell)
        self.coast = min(self.coast, other.coast)
        self.local.ell_sent = min(self.local.ell_sent, other.local.ell_sent)
        self.since = min(self.since, other.since)
        self.heard = min(self.heard, other.heard)
        self.heard_appearance = self.heard_appearance or other.heard_appearance
        self.held = max(self.held, other.held)
        for cam, (k, size) in other.views.items():
            if cam not in self.views or self.views[cam][0] < k:
                self.views[cam] = (k, size)


class TrackerTable(dict):
    """A node's trackers by id (a ``dict``), with the ids' sorted order kept between changes.

    A frame visits the trackers in id order eight times (prediction, the sent states,
    association, message, the neighbours' entries, merge views, drops, tracks); sorting twenty
    ``(camera, counter)`` ids with their trackers cost about 50 k instructions each time. Every
    change of the table (an item set, popped or deleted) drops the kept order; ``ids`` and
    ``in_order`` return new lists."""

    __slots__ = ("_order",)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._order: tuple[list[TrackerId], list[Tracker]] | None = None

    def _sorted(self) -> tuple[list[TrackerId], list[Tracker]]:
        if self._order is None:
            ids = sorted(self)
            self._order = (ids, [self[t] for t in ids])
        return self._order

    def ids(self) -> list[TrackerId]:
        """The ids, sorted."""
        return list(self._sorted()[0])

    def in_order(self) -> list[Tracker]:
        """The trackers in the order of their ids."""
        return list(self._sorted()[1])

    # every way to change a dict drops the kept order
    def __setitem__(self, key, value):
        self._order = None
        super().__setitem__(key, value)

    def __delitem__(self, key):
        self._order = None
        super().__delitem__(key)

    def pop(self, *args):
        self._order = None
        return super().pop(*args)

    def popitem(self):
        self._order = None
        return super().popitem()

    def setdefault(self, key, default=None):
        self._order = None
        return super().setdefault(key, default)

    def update(self, *args, **kwargs):
        self._order = None
        super().update(*args, **kwargs)

    def clear(self):
        self._order = None
        super().clear()

    def __ior__(self, other):
        self._order = None
        return super().__ior__(other)
