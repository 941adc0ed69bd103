"""The re-identification store: what a node keeps of the trackers it dropped (paper III-C, "old
trackers"), so that a new tracker whose gallery matches one takes its id back (eq. 7 against
``epsilon``), or, without appearance, one born near where it was dropped.

Bounded twice, oldest dropped first out: at most ``max_count`` entries and at most
``max_bytes`` of descriptors. The galleries are kept as float16, trimmed to their rows: a
quarter of a live gallery's float64, and finer than a descriptor travels on the wire (int8 with
a scale, protocol/codec.py; many stored descriptors came that way). A full 20-descriptor
gallery of 512-d descriptors costs 20 kB instead of 80 kB (the preallocated float64 rows), so
200 of them fill 3.9 MiB, not 16 MB. A gallery taken back (:meth:`ReidStore.take`) is float64
again. Its cosine distances to a query differ from the float64 gallery's by float16 rounding,
at most 4e-5 on synthetic 512-d descriptors, and re-identification decides the same
(tests/test_components.py).

A :class:`collections.abc.Mapping` from id to the stored gallery; where each tracker was
dropped is :attr:`ReidStore.last`. Entries put with ``reid=False`` (hearsay: trackers the network
never kept alive, ``Tracker.confirmed``) keep their gallery for a later adoption of the same id
but are no re-identification candidates (:meth:`ReidStore.candidates`, what
``manager.reidentify`` reads).
Pure and deterministic.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator, Mapping

import numpy as np

from edge_node.core.gallery import Gallery
from protocol.messages import TrackerId

STORED = np.float16  # descriptors of dropped trackers (finer than the wire's int8)


class ReidStore(Mapping):
    """Dropped trackers' galleries (float16) and where they were dropped, within a count and
    a byte budget (module docstring)."""

    def __init__(self, max_count: int, max_bytes: int):
        self.max_count = int(max_count)
        self.max_bytes = int(max_bytes)
        self._g: OrderedDict[TrackerId, Gallery] = OrderedDict()  # oldest first
        self.last: dict[TrackerId, tuple[int, np.ndarray]] = {}  # frame and where dropped
        # the frame it was last seen and its whole state when dropped (reappear.py)
        self.motion: dict[TrackerId, tuple[int, np.ndarray]] = {}
        self.nbytes = 0  # descriptor bytes held
        self.hearsay: set[TrackerId] = set()  # kept, but not to be re-identified

    # -- Mapping ------------------------------------------------------------------------------
    def __getitem__(self, tid: TrackerId) -> Gallery:
        return self._g[tid]

    def __iter__(self) -> Iterator[TrackerId]:
        return iter(self._g)

    def __len__(self) -> int:
        return len(self._g)

    def __contains__(self, tid: object) -> bool:
        return tid in self._g

    def candidates(self) -> Mapping[TrackerId, Gallery]:
        """The stored trackers a new one may be re-identified as: all but the hearsay."""
        if not self.hearsay:
            return self
        return {t: g for t, g in self._g.items() if t not in self.hearsay}

    # -- changes ------------------------------------------------------------------------------
    def put(self, tid: TrackerId, gallery: Gallery, frame: int | None = None,
            xy: np.ndarray | None = None, reid: bool = True, x: np.ndarray | None = None,
            seen: int | None = None) -> None:
        """Keep ``gallery`` (a float16 copy) for ``tid``, newest, and where it was dropped
        (``frame``, ``xy``; its state ``x`` with the velocity it was going at, and the frame
        ``seen`` last) when known; then the oldest go until both bounds hold. ``reid``: whether it is a re-identification
        candidate (module docstring)."""
        self._discard(tid)
        if not reid:
            self.hearsay.add(tid)
        g = gallery.astype(STORED)
        self._g[tid] = g
        self.nbytes += g.nbytes
        if xy is not None:
            self.last[tid] = (int(frame or 0), np.asarray(xy, float).copy())
        if x is not None:
            self.motion[tid] = (int(frame or 0) if seen is None else int(seen),
                                np.asarray(x, float).copy())
        self._shrink()

    def take(self, tid: TrackerId) -> Gallery | None:
        """Remove ``tid`` (and where it was dropped); its gallery as float64, or ``None``."""
        g = self._discard(tid)
        return None if g is None else g.astype(np.float64)

    def _discard(self, tid: TrackerId) -> Gallery | None:
        """Remove ``tid`` and where it was dropped; its stored gallery, or ``None``."""
        self.last.pop(tid, None)
        self.motion.pop(tid, None)
        self.hearsay.discard(tid)
        g = self._g.pop(tid, None)
        if g is not None:
            self.nbytes -= g.nbytes
        return g

    def extend(self, tid: TrackerId, gallery: Gallery) -> None:
        """Add ``gallery``'s descriptors to the stored gallery of ``tid`` (two dropped
        trackers turned out to be one), keeping its place in the order."""
        g = self._g[tid]
        self.nbytes -= g.nbytes
        g.extend(gallery)
        self._g[tid] = g = g.astype(STORED)  # trimmed again
        self.nbytes += g.nbytes
        self._shrink()

    def _shrink(self) -> None:
        while self._g and (len(self._g) > self.max_count or self.nbytes > self.max_bytes):
            self._discard(next(iter(self._g)))
