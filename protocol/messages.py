"""Message types exchanged between neighbouring cameras, one per node per frame.

Paper Section III-D: per active tracker the message carries ``(ID_i, x_bar_i, u_i, U_i, ell_i)``;
a tracker new to the sender additionally carries its appearance model (the descriptors of its
gallery, at most ``MAX_DESCRIPTORS``), which is the only time appearance crosses the network.
Merge announcements (``loser -> winner``) make all cameras converge on one id per target.

A message holds its trackers in one of two equal forms: a ``TrackerBlock`` (one array per
field, a row per tracker: what the codec reads and writes in one pass) or a tuple of
``TrackerInfo`` (one object per tracker: what code that loops over trackers reads). Each is
built from the other on first use and kept.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocol.checks import MAX_WIRE_INT, TrackerId, as_appearance, as_float_array, as_id, as_int, err

SCHEMA_VERSION = 3
STATE_DIM = 6  # x = (x, y, w, h, vx, vy)
MAX_DESCRIPTORS = 2
# the places of U's rows and columns 4-5 (velocity) in its flattened 6 x 6: eq. 2's H observes
# (x, y, w, h) only, so a camera's measurement information has nothing there
VELOCITY_PLACES = np.flatnonzero((np.arange(STATE_DIM)[:, None] >= 4)
                                 | (np.arange(STATE_DIM)[None, :] >= 4))

__all__ = ["MAX_DESCRIPTORS", "SCHEMA_VERSION", "STATE_DIM", "VELOCITY_PLACES", "FrameMessage", "Merge",
           "TrackerBlock", "TrackerId", "TrackerInfo"]

_N = STATE_DIM


@dataclass(frozen=True, eq=False)
class TrackerInfo:
    """One tracker's consensus data from one camera for one frame.

    x_bar: predicted state ``A x_hat(k-1)``, shape (6,).
    u, U:  information vector and matrix of the local measurement (eq. 2); zeros when the
           sender has no measurement of this target this frame. ``U`` is symmetric (6, 6).
    ell:   frames since the last association by any camera, as the sender knows it (eq. 8).
    appearance: ``(n, D)`` descriptors, only when the tracker is new to the sender.
    born:  the frame its originating camera created it. Every camera ranks trackers by
           ``(born, id)``, so when two trackers turn out to be one target, all keep the older.
    """

    id: TrackerId
    x_bar: np.ndarray
    u: np.ndarray
    U: np.ndarray
    ell: int
    appearance: np.ndarray | None = None
    born: int = 0

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TrackerInfo):
            return NotImplemented
        if self.id != other.id or self.ell != other.ell or self.born != other.born:
            return False
        if not (np.array_equal(self.x_bar, other.x_bar) and np.array_equal(self.u, other.u)
                and np.array_equal(self.U, other.U)):
            return False
        if (self.appearance is None) != (other.appearance is None):
            return False
        return self.appearance is None or np.array_equal(self.appearance, other.appearance)


def _frozen(a: Any, dtype: type, shape: tuple[int, ...], what: str) -> np.ndarray:
    """``a`` as a read-only array of ``dtype`` and ``shape`` (copied unless already read-only)."""
    if dtype is np.int64:
        try:
            arr = np.asarray(a)
        except Exception:  # noqa: BLE001 - ragged / unconvertible input
            raise err("malformed", f"{what} is not an integer array") from None
        if arr.dtype.kind not in "iu" and not (arr.size == 0 and arr.dtype.kind == "f"):
            raise err("malformed", f"{what} must be integers, got dtype {arr.dtype}")
        if arr.dtype == np.uint64 and arr.size and arr.max() > MAX_WIRE_INT:
            raise err("malformed", f"{what} out of range: {arr.max()}")
    else:
        arr = as_float_array(a, None, what, finite=False)
    if arr.shape != shape:
        raise err("malformed", f"{what} must have shape {shape}, got {arr.shape}")
    if arr.dtype != dtype or arr.flags.writeable:
        arr = arr.astype(dtype)
        arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class TrackerBlock:
    """A message's trackers as columns: row ``i`` is tracker ``(camera[i], counter[i])``.

    camera, counter, born, ell: int64 ``(n,)`` (see ``TrackerInfo``: id, birth frame, eq. 8's
    ``ell``); x_bar, u: float64 ``(n, 6)``; U: float64 ``(n, 6, 6)`` (eq. 2's ``u_i, U_i``, zero
    for a row without a measurement); appearance: ``(row, (m, D) descriptors)`` for the rows
    that carry one, rows increasing. All arrays are read-only (copied on construction unless
    they already are). Construction checks shapes and types only; the codec enforces the
    wire's value rules (finite numbers, non-negative ids, unique ids, limits).
    """

    camera: np.ndarray
    counter: np.ndarray
    born: np.ndarray
    ell: np.ndarray
    x_bar: np.ndarray
    u: np.ndarray
    U: np.ndarray
    appearance: tuple[tuple[int, np.ndarray], ...] = ()

    def __post_init__(self) -> None:
        try:
            n = len(self.camera)
        except TypeError:
            raise err("malformed", "camera must be a 1-D integer array") from None
        for name in ("camera", "counter", "born", "ell"):
            object.__setattr__(self, name, _frozen(getattr(self, name), np.int64, (n,), name))
        object.__setattr__(self, "x_bar", _frozen(self.x_bar, np.float64, (n, _N), "x_bar"))
        object.__setattr__(self, "u", _frozen(self.u, np.float64, (n, _N), "u"))
        object.__setattr__(self, "U", _frozen(self.U, np.float64, (n, _N, _N), "U"))
        apps = []
        last = -1
        for entry in self.appearance:
            if not isinstance(entry, tuple) or len(entry) != 2:
                raise err("malformed", "appearance entries must be (row, descriptors) pairs")
            row = as_int(entry[0], "appearance row")
            if not last < row < n:
                raise err("malformed", f"appearance row {row} out of order or beyond {n} rows")
            a = as_appearance(entry[1], f"appearance of row {row}")
            a.setflags(write=False)
            apps.append((row, a))
            last = row
        object.__setattr__(self, "appearance", tuple(apps))

    @classmethod
    def _trusted(cls, camera: np.ndarray, counter: np.ndarray, born: np.ndarray, ell: np.ndarray,
                 x_bar: np.ndarray, u: np.ndarray, U: np.ndarray,
                 appearance: tuple[tuple[int, np.ndarray], ...]) -> TrackerBlock:
        """A block of arrays that already hold every invariant (the codec's decoder, the core's
        own message): no checks."""
        b = object.__new__(cls)
        b.__dict__.update(camera=camera, counter=counter, born=born, ell=ell, x_bar=x_bar, u=u, U=U,
                          appearance=appearance)
        return b

    def measurement_factor(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """A decoded block's measurements in the form the decoder built ``u, U`` from (see
        ``protocol.codec``): which rows carry one (``(n,)`` bool, ``m`` set), their ``L (m, 4,
        4)``, lower-triangular with a positive diagonal, and ``v (m, 4)``, with ``U_zz = L L^T``
        and ``u_z = L v`` (so the measurement is ``z = L^-T v``); read-only. Such ``u, U`` hold
        the wire's form by construction: ``U`` exactly symmetric and zero outside ``(x, y, w,
        h)``, ``u = 0`` where ``U = 0``. ``None`` for a block taken from a decoded one or made
        any other way."""
        return self.__dict__.get("_factor")

    @classmethod
    def empty(cls) -> TrackerBlock:
        return _EMPTY

    @classmethod
    def from_infos(cls, infos: Sequence[TrackerInfo]) -> TrackerBlock:
        """The block of a sequence of ``TrackerInfo``; ``ProtocolError`` if it cannot be one
        (not ``TrackerInfo``, ids not ``(camera, counter)`` pairs of ints, wrong shapes, ...)."""
        if not isinstance(infos, (tuple, list)):
            raise err("malformed", "trackers must be a sequence")
        if not infos:
            return _EMPTY
        fast = _fast_columns(infos)
        if fast is None:
            fast = _checked_columns(infos)
        ints, x_bar, u, U = fast
        apps = []
        for i, t in enumerate(infos):
            if t.appearance is not None:
                a = as_appearance(t.appearance, f"appearance of {t.id}")
                a.setflags(write=False)
                apps.append((i, a))
        ints.setflags(write=False)
        for a in (x_bar, u, U):
            a.setflags(write=False)
        return cls._trusted(ints[0], ints[1], ints[2], ints[3], x_bar, u, U, tuple(apps))

    def __len__(self) -> int:
        return len(self.camera)

    def ids(self) -> list[TrackerId]:
        """The rows' ids ``(camera, counter)`` as Python ints, in row order (a new list; the
        block's columns are read-only, so the ids are made once: the screen and the inbox both
        read them, 15 k instructions for 20 rows)."""
        ids = self.__dict__.get("_ids")
        if ids is None:
            ids = self.__dict__["_ids"] = tuple(zip(self.camera.tolist(), self.counter.tolist()))
        return list(ids)

    def take(self, rows: Sequence[int] | np.ndarray) -> TrackerBlock:
        """The block of the given rows, in that order (increasing: appearance stays in order)."""
        rows = np.asarray(rows, np.intp)
        if len(rows) == len(self) and np.array_equal(rows, np.arange(len(self))):
            return self
        new_row = {r: i for i, r in enumerate(rows.tolist())}
        apps = tuple((new_row[r], a) for r, a in self.appearance if r in new_row)
        cols = [a[rows] for a in (self.camera, self.counter, self.born, self.ell, self.x_bar,
                                  self.u, self.U)]
        for a in cols:
            a.setflags(write=False)
        return TrackerBlock._trusted(*cols, tuple(sorted(apps, key=lambda e: e[0])))

    def info(self, i: int) -> TrackerInfo:
        """Row ``i`` as a ``TrackerInfo`` (sharing this block's read-only arrays)."""
        t = object.__new__(TrackerInfo)
        t.__dict__.update(id=(int(self.camera[i]), int(self.counter[i])), x_bar=self.x_bar[i],
                          u=self.u[i], U=self.U[i], ell=int(self.ell[i]),
                          appearance=dict(self.appearance).get(i), born=int(self.born[i]))
        return t

    def infos(self) -> tuple[TrackerInfo, ...]:
        """One ``TrackerInfo`` per row, sharing this block's (read-only) arrays."""
        apps = dict(self.appearance)
        new = object.__new__
        out = []
        for i, (c, k, b, e) in enumerate(zip(self.camera.tolist(), self.counter.tolist(),
                                            self.born.tolist(), self.ell.tolist())):
            t = new(TrackerInfo)
            t.__dict__.update(id=(c, k), x_bar=self.x_bar[i], u=self.u[i], U=self.U[i], ell=e,
                              appearance=apps.get(i), born=b)
            out.append(t)
        return tuple(out)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TrackerBlock):
            return NotImplemented
        if len(self) != len(other) or len(self.appearance) != len(other.appearance):
            return False
        if not all(np.array_equal(getattr(self, f), getattr(other, f))
                   for f in ("camera", "counter", "born", "ell", "x_bar", "u", "U")):
            return False
        return all(r == s and np.array_equal(a, b)
                   for (r, a), (s, b) in zip(self.appearance, other.appearance))

    __hash__ = None  # type: ignore[assignment]


def _fast_columns(infos: Sequence[Any]) -> tuple[np.ndarray, ...] | None:
    """Columns of well-formed ``TrackerInfo``s (plain int ids, real arrays of the right
    shapes) in a few array calls; ``None`` when anything is unusual (the checked path decides).
    Negative ints pass here: the codec's whole-block check refuses them."""
    n = len(infos)
    try:
        if set(map(type, infos)) != {TrackerInfo}:
            return None
        ids = [t.id for t in infos]
        if set(map(type, ids)) != {tuple} or set(map(len, ids)) != {2}:
            return None
        flat = [c for c, _ in ids] + [k for _, k in ids] + [t.born for t in infos] + [t.ell for t in infos]
        if set(map(type, flat)) != {int}:  # not bool, not numpy ints: the checked path
            return None
        ints = np.array(flat, dtype=np.int64).reshape(4, n)  # OverflowError beyond int64
        x_bar = np.array([t.x_bar for t in infos])
        u = np.array([t.u for t in infos])
        U = np.array([t.U for t in infos])
    except Exception:  # noqa: BLE001 - ragged arrays, odd objects: the checked path says what
        return None
    out: list[np.ndarray] = [ints]
    for a, shape in ((x_bar, (n, _N)), (u, (n, _N)), (U, (n, _N, _N))):
        if a.shape != shape or a.dtype.kind not in "fiu":
            return None
        out.append(a if a.dtype == np.float64 else a.astype(np.float64))
    return tuple(out)


def _checked_columns(infos: Sequence[Any]) -> tuple[np.ndarray, ...]:
    """Columns of ``infos``, checking each tracker and naming the first that is not well formed."""
    n = len(infos)
    ints = np.empty((4, n), np.int64)
    x_bar, u, U = np.empty((n, _N)), np.empty((n, _N)), np.empty((n, _N, _N))
    for i, t in enumerate(infos):
        if not isinstance(t, TrackerInfo):
            raise err("malformed", f"tracker must be a TrackerInfo, got {type(t).__name__}")
        tid = as_id(t.id, "tracker id")
        ints[:, i] = (*tid, as_int(t.born, f"born of {tid}"), as_int(t.ell, f"ell of {tid}"))
        x_bar[i] = as_float_array(t.x_bar, (_N,), f"x_bar of {tid}", finite=False)
        u[i] = as_float_array(t.u, (_N,), f"u of {tid}", finite=False)
        U[i] = as_float_array(t.U, (_N, _N), f"U of {tid}", finite=False)
    return ints, x_bar, u, U


def _empty_block() -> TrackerBlock:
    ints = np.zeros((4, 0), np.int64)
    arrays = (ints, np.zeros((0, _N)), np.zeros((0, _N)), np.zeros((0, _N, _N)))
    for a in arrays:
        a.setflags(write=False)
    return TrackerBlock._trusted(ints[0], ints[1], ints[2], ints[3], *arrays[1:], ())


_EMPTY = _empty_block()


@dataclass(frozen=True)
class Merge:
    """Announcement that ``loser`` and ``winner`` are the same target; everyone keeps ``winner``.

    ``winner_born`` is the winner's birth frame, so a camera that only held the loser renames
    it with the winner's rank ``(born, id)`` intact.
    """

    loser: TrackerId
    winner: TrackerId
    winner_born: int = 0


@dataclass(frozen=True, eq=False, init=False, repr=False)
class FrameMessage:
    """Everything one camera tells one neighbour about frame ``frame``.

    Give the trackers either as ``trackers`` (a tuple of ``TrackerInfo``) or as ``block`` (a
    ``TrackerBlock``, see ``from_block``); ``msg.trackers`` and ``msg.block`` both work on
    either, each built once on first use. Nothing is checked here: the codec is the trust
    boundary (``msg.block`` raises ``ProtocolError`` when the trackers cannot form one).
    ``dataclasses.replace(msg, trackers=...)`` and ``replace(msg, block=...)`` replace the
    trackers; a ``replace`` of other fields keeps both forms. Two messages are equal when their
    fields and their trackers, row by row, are.
    """

    network: str
    sender: int
    frame: int
    merges: tuple[Merge, ...]
    sent_at: float  # seconds since the epoch at send; 0.0 in simulation
    version: int
    _block: TrackerBlock | None = field(default=None, compare=False)  # either form, or both
    _infos: Sequence[TrackerInfo] | None = field(default=None, compare=False)

    def __init__(self, network: str, sender: int, frame: int,
                 trackers: Sequence[TrackerInfo] | None = None, merges: tuple[Merge, ...] = (),
                 sent_at: float = 0.0, version: int = SCHEMA_VERSION, *,
                 block: TrackerBlock | None = None, _block: TrackerBlock | None = None,
                 _infos: Sequence[TrackerInfo] | None = None) -> None:
        if trackers is not None and block is not None:
            raise TypeError("give trackers or block, not both")
        if trackers is not None or block is not None:  # (replace() passes _block/_infos too)
            # a tuple: a caller's list appended to later would leave a cached block stale
            _block, _infos = block, (tuple(trackers) if isinstance(trackers, list) else trackers)
        elif _block is None and _infos is None:
            _block = _EMPTY
        d = self.__dict__
        d.update(network=network, sender=sender, frame=frame, merges=merges, sent_at=sent_at,
                 version=version, _block=_block, _infos=_infos)

    @classmethod
    def from_block(cls, network: str, sender: int, frame: int, block: TrackerBlock,
                   merges: tuple[Merge, ...] = (), sent_at: float = 0.0) -> FrameMessage:
        """A message whose trackers are the rows of ``block`` (no per-tracker objects)."""
        if not isinstance(block, TrackerBlock):
            raise TypeError(f"block must be a TrackerBlock, got {type(block).__name__}")
        return cls(network, sender, frame, merges=merges, sent_at=sent_at, block=block)

    @property
    def trackers(self) -> Sequence[TrackerInfo]:
        """The trackers as ``TrackerInfo`` objects (a tuple, unless built from another sequence)."""
        if self._infos is None:
            self.__dict__["_infos"] = self._block.infos()  # type: ignore[union-attr]
        return self._infos  # type: ignore[return-value]

    @property
    def block(self) -> TrackerBlock:
        """The trackers as one ``TrackerBlock``; ``ProtocolError`` if they cannot form one."""
        if self._block is None:
            self.__dict__["_block"] = TrackerBlock.from_infos(self._infos)  # type: ignore[arg-type]
        return self._block

    def tracker(self, tid: TrackerId) -> TrackerInfo | None:
        for t in self.trackers:
            if t.id == tid:
                return t
        return None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FrameMessage):
            return NotImplemented
        if (self.network, self.sender, self.frame, self.merges, self.sent_at, self.version) != (
                other.network, other.sender, other.frame, other.merges, other.sent_at, other.version):
            return False
        if self._block is not None and other._block is not None:
            return self._block == other._block
        if self._infos is not None and other._infos is not None:
            return self._infos == other._infos
        return tuple(self.trackers) == tuple(other.trackers)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        try:
            n = len(self._block) if self._block is not None else len(self._infos)  # type: ignore[arg-type]
        except TypeError:
            n = "?"
        return (f"FrameMessage(network={self.network!r}, sender={self.sender!r}, frame={self.frame!r}, "
                f"trackers=<{n}>, merges={self.merges!r}, sent_at={self.sent_at!r}, "
                f"version={self.version!r})")
