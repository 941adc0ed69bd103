"""``NodeState``: every tracker quantity a node holds, as the columns of one table.

Row ``i`` is one tracker; rows are kept in the order of the trackers' ids, so every role that
walks the trackers (the association's candidates, the message's entries, the merge search, the
tracks) sees them in one deterministic order without sorting. Each column is one NumPy array
(or, for the galleries, one list), so a role computes for all trackers at once and writes its
result into the column: no per-tracker objects in the hot path, no stacking and unstacking.

Lasting columns (a tracker's life on this node; paper notation where it has one):

* ``x_bar, P``: the prediction of the current frame and its covariance;
* ``x_hat, M``: the last estimate (eq. 4) and its covariance (``estimated``: there is one);
* ``ell`` (eq. 8), ``coast`` (frames in a row ``ell`` grew), ``lag`` (how much of ``ell`` is a
  late link's lag), ``held`` (frames the network kept it alive since it came, ``confirmed``);
* ``born`` (at the originating camera), ``since`` (on this node), ``heard`` (the frame of the
  news by which it came), ``informed`` (the last update had measurement information),
  ``announced`` (its appearance was sent), ``heard_appearance``, ``origin`` (where this node's
  camera measured it at birth, ``has_origin``);
* ``view_k, view_size``: per camera of the node, the last frame it measured the target and the
  box size it draws it at (``views``; ``view_k`` -1: never); ``view_off``: where it sees the
  target's foot point against the network's estimate, in its own ground frame (NaN: not learnt
  yet); ``view_at``: the foot point it measured at ``view_k``, until the frame's drawing compares
  it with the estimate (NaN: none, or the measurement did not locate the target);
* ``galleries``: each tracker's appearance gallery.

Frame columns (rebuilt by every ``prepare``: the paper's local information and the message):
``u, U`` (eq. 2, summed over the node's cameras), ``seen`` (which of the node's cameras
associated a measurement), ``raw`` (that measurement's row among the camera's boxes, -1
none), ``residual`` (whether it gives the registrar a residual: not a measurement taken from
outside the gate), ``cam_u, cam_U`` (each camera's own ``u, U``: the registrar's residuals on nodes of
several cameras), ``ell_sent`` and ``x_bar_sent`` (what the message says: eq. 8's counter and
``x_bar`` at the wire's precision).

Rows are inserted (a birth, an adoption) and deleted (a merge, a drop) explicitly; a rename (a
merge whose loser alone is held here) moves the row to its new id's place. ``TrackerRows`` is a
read-mostly mapping of id to row (``CameraNode.trackers``) for code outside the hot path.
"""
from __future__ import annotations

from bisect import bisect_left
from collections.abc import Iterator, Mapping

import numpy as np

from edge_node.core.gallery import Gallery
from edge_node.core.model import STATE_DIM
from protocol.messages import TrackerId

# frames in which the network must keep a tracker alive after it appeared on a node before it
# counts as a person (two, as a birth needs two observations): one message's phantom, or one
# stray detection associated to it, is hearsay (the zombie probe's flood)
CONFIRM_FRAMES = 2

_D = STATE_DIM


class NodeState:
    """The table of a node's trackers (module docstring). ``cameras``: how many cameras the
    node owns (the per-camera columns' width)."""

    #: lasting columns: name -> (shape after the row, dtype, value of a new row)
    LASTING = {
        "born": ((), np.int64, 0), "since": ((), np.int64, 0), "heard": ((), np.int64, 0),
        "ell": ((), np.int64, 0), "coast": ((), np.int64, 0), "lag": ((), np.int64, 0),
        "held": ((), np.int64, 0), "unseen": ((), np.int64, 0),
        "informed": ((), bool, True), "announced": ((), bool, False),
        "heard_appearance": ((), bool, True), "has_origin": ((), bool, False),
        "estimated": ((), bool, False),
        "origin": ((2,), float, 0.0),
        "x_bar": ((_D,), float, 0.0), "P": ((_D, _D), float, 0.0),
        "x_hat": ((_D,), float, 0.0), "M": ((_D, _D), float, 0.0),
    }
    #: frame columns, reset by ``begin_frame``
    FRAME = {
        "u": ((_D,), float, 0.0), "U": ((_D, _D), float, 0.0),
        "ell_sent": ((), np.int64, 0), "x_bar_sent": ((_D,), float, 0.0),
    }

    #: lasting per-camera columns (``(n, C, ...)``): name -> value of a new row
    PER_CAMERA = {"view_k": -1, "view_size": 0.0, "view_off": np.nan, "view_at": np.nan}

    def __init__(self, cameras: int = 1):
        self.C = int(cameras)
        self.ids: list[TrackerId] = []
        self.galleries: list[Gallery] = []
        self._index: dict[TrackerId, int] | None = {}
        for name, (shape, dtype, _) in {**self.LASTING, **self.FRAME}.items():
            setattr(self, name, np.zeros((0, *shape), dtype))
        C = self.C
        self.view_k = np.zeros((0, C), np.int64)
        self.view_size = np.zeros((0, C, 2))
        self.view_off = np.zeros((0, C, 2))
        self.view_at = np.zeros((0, C, 2))
        self.seen = np.zeros((0, C), bool)
        self.raw = np.zeros((0, C), np.int64)
        self.residual = np.zeros((0, C), bool)
        self.cam_u = np.zeros((0, C, _D))
        self.cam_U = np.zeros((0, C, _D, _D))

    # -- the table's shape --------------------------------------------------------------------
    def _columns(self) -> list[str]:
        cols = [*self.LASTING, *self.FRAME, *self.PER_CAMERA, "seen", "raw", "residual"]
        if self.C > 1:
            cols += ["cam_u", "cam_U"]
        return cols

    def __len__(self) -> int:
        return len(self.ids)

    def __contains__(self, tid: object) -> bool:
        return tid in self.index

    @property
    def index(self) -> dict[TrackerId, int]:
        """Row of each id (rebuilt after a change of the table)."""
        if self._index is None:
            self._index = {t: i for i, t in enumerate(self.ids)}
        return self._index

    def row(self, tid: TrackerId) -> int:
        return self.index[tid]

    @property
    def confirmed(self) -> np.ndarray:
        """Whether the network kept each tracker alive in ``CONFIRM_FRAMES`` frames after it
        appeared here: only such a tracker is re-identified when dropped."""
        return self.held >= CONFIRM_FRAMES

    # -- rows in and out ----------------------------------------------------------------------
    def insert(self, tid: TrackerId, gallery: Gallery, **values) -> int:
        """A new row for ``tid`` at its place in id order, every column at its new-row value
        but those given; returns the row. The frame's columns start empty (no information)."""
        if tid in self.index:
            raise KeyError(f"tracker {tid} is already held")
        at = bisect_left(self.ids, tid)
        self.ids.insert(at, tid)
        self.galleries.insert(at, gallery)
        self._index = None
        specs = {**self.LASTING, **self.FRAME}
        for name in self._columns():
            col = getattr(self, name)
            if name in values:
                new = np.asarray(values[name], col.dtype)
            elif name in specs:
                new = np.full(col.shape[1:], specs[name][2], col.dtype)
            else:  # the per-camera columns
                new = np.full(col.shape[1:], self.PER_CAMERA.get(name, -1 if name == "raw" else 0),
                              col.dtype)
            setattr(self, name, np.concatenate((col[:at], new[None], col[at:])))
        return at

    def delete(self, tid: TrackerId) -> dict:
        """Take ``tid``'s row out; returns its values (column name -> value, and
        ``gallery``)."""
        at = self.index[tid]
        out = {name: getattr(self, name)[at].copy() for name in self._columns()}
        out["gallery"] = self.galleries.pop(at)
        del self.ids[at]
        self._index = None
        for name in self._columns():
            setattr(self, name, np.delete(getattr(self, name), at, axis=0))
        return out

    def rename(self, old: TrackerId, new: TrackerId) -> int:
        """The row of ``old`` becomes ``new``'s, at ``new``'s place in id order; returns it."""
        values = self.delete(old)
        gallery = values.pop("gallery")
        return self.insert(new, gallery, **values)

    # -- the frame's columns ------------------------------------------------------------------
    def begin_frame(self) -> None:
        """No local information yet (eq. 2): the frame's columns to zero."""
        n, C = len(self), self.C
        self.u, self.U = np.zeros((n, _D)), np.zeros((n, _D, _D))
        self.seen = np.zeros((n, C), bool)
        self.raw = np.full((n, C), -1, np.int64)
        self.residual = np.zeros((n, C), bool)
        if C > 1:
            self.cam_u, self.cam_U = np.zeros((n, C, _D)), np.zeros((n, C, _D, _D))

    def add_information(self, rows: np.ndarray, c: int, u: np.ndarray, U: np.ndarray,
                        raws: np.ndarray, residual: bool = True) -> None:
        """Camera ``c`` (its place among the node's cameras) measured trackers ``rows`` with
        information ``u, U`` (eq. 2, one row each) from its boxes ``raws``: the node's cameras
        add up (eq. 3). ``rows`` are distinct. ``residual``: the measurements give the
        registrar residuals (not one taken from outside the gate)."""
        rows = np.asarray(rows, np.intp)
        first = ~self.seen.take(rows, axis=0).any(axis=1)
        if first.all():  # the first camera of the frame for every one (one camera: always)
            self.u[rows], self.U[rows] = u, U
        else:
            self.u[rows] = np.where(first[:, None], u, self.u.take(rows, axis=0) + u)
            self.U[rows] = np.where(first[:, None, None], U, self.U.take(rows, axis=0) + U)
        self.seen[rows, c] = True
        self.raw[rows, c] = raws
        self.residual[rows, c] = residual
        if self.C > 1:
            self.cam_u[rows, c], self.cam_U[rows, c] = u, U

    def seen_any(self) -> np.ndarray:
        """Whether any of the node's cameras associated a measurement with each tracker."""
        return self.seen.any(axis=1)

    def seen_by(self, i: int, cameras: list[int]) -> frozenset[int]:
        """The camera ids (``cameras``: the node's, in column order) that measured row ``i``."""
        return frozenset(c for c, s in zip(cameras, self.seen[i].tolist()) if s)


class TrackerRow:
    """One tracker of a ``NodeState`` by id, its columns as attributes (read and write): for
    tests, tools and code off the hot path. Invalid once the table changes shape."""

    __slots__ = ("_s", "_i")

    def __init__(self, state: NodeState, i: int):
        object.__setattr__(self, "_s", state)
        object.__setattr__(self, "_i", i)

    @property
    def id(self) -> TrackerId:
        return self._s.ids[self._i]

    @property
    def gallery(self) -> Gallery:
        return self._s.galleries[self._i]

    @property
    def confirmed(self) -> bool:
        return bool(self._s.held[self._i] >= CONFIRM_FRAMES)

    def __getattr__(self, name: str):
        col = getattr(self._s, name)
        v = col[self._i]
        if name in ("x_hat", "M") and not self._s.estimated[self._i]:
            return None
        if name == "origin" and not self._s.has_origin[self._i]:
            return None
        return v.item() if np.ndim(v) == 0 else v

    def __setattr__(self, name: str, value) -> None:
        getattr(self._s, name)[self._i] = value


class TrackerRows(Mapping):
    """A node's trackers by id (``CameraNode.trackers``): ``rows[tid]`` is a ``TrackerRow``;
    ``ids()`` and ``in_order()`` in id order."""

    def __init__(self, state: NodeState):
        self._s = state

    def __getitem__(self, tid: TrackerId) -> TrackerRow:
        return TrackerRow(self._s, self._s.index[tid])

    def __iter__(self) -> Iterator[TrackerId]:
        return iter(list(self._s.ids))

    def __len__(self) -> int:
        return len(self._s)

    def __contains__(self, tid: object) -> bool:
        return tid in self._s

    def ids(self) -> list[TrackerId]:
        return list(self._s.ids)

    def in_order(self) -> list[TrackerRow]:
        return [TrackerRow(self._s, i) for i in range(len(self._s))]
