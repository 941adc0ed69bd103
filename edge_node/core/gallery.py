"""The bounded appearance gallery of a tracker and the appearance score of eq. 7."""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def _unit(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64).ravel()
    n = np.linalg.norm(a)
    return a / n if n > 0 else a


def cosine_distance(a: np.ndarray, b: np.ndarray) -> float:
    """``1 - cos(a, b)``: the appearance distance of eq. 7 between two descriptors."""
    return float(1.0 - _unit(a) @ _unit(b))


class Gallery:
    """At most ``capacity`` descriptors, oldest dropped first; a new one at most every ``every``
    frames (paper III-B: "saving a new patch every N frames, and discarding the oldest one").

    The descriptors are the rows of one array, oldest first (``matrix()`` is a view of it): a
    gallery costs its descriptors once. A live tracker's gallery holds float64; the dropped
    trackers' galleries kept for re-identification (``reidstore.ReidStore``) are float16 copies
    trimmed to their rows (:meth:`astype`): finer than the wire's int8 (protocol/codec.py).
    """

    def __init__(self, capacity: int = 20, every: int = 20,
                 descriptors: Iterable[np.ndarray] = ()):
        self.capacity = capacity
        self.every = every
        self._a = np.zeros((0, 0))  # rows 0.._n-1: unit descriptors, oldest first
        self._n = 0
        self._last_frame: int | None = None
        self.version = 0  # changes whenever the descriptors do (what a cached distance checks)
        for d in descriptors:
            self._push(_unit(d))

    def __len__(self) -> int:
        return self._n

    def _push(self, u: np.ndarray) -> None:
        """Append one unit descriptor, dropping the oldest when full (rows grow by doubling)."""
        if self._n and u.size != self._a.shape[1]:
            raise ValueError(f"a descriptor of dimension {u.size} for a gallery of dimension "
                             f"{self._a.shape[1]}")
        self.version += 1
        if self._n == self.capacity:
            self._a[:-1] = self._a[1:]
            self._a[-1] = u
            return
        if self._n == len(self._a):
            grown = np.empty((min(self.capacity, max(4, 2 * self._n)), u.size),
                             self._a.dtype if self._n else np.float64)
            if self._n:
                grown[:self._n] = self._a[:self._n]
            self._a = grown
        self._a[self._n] = u
        self._n += 1

    def offer(self, descriptor: np.ndarray | None, frame: int, admit: float | None = None) -> bool:
        """Store ``descriptor`` if ``every`` frames have passed since the last one stored and
        (when ``admit`` is given) it is within ``admit`` of the gallery: a descriptor from a
        wrong association must not teach the gallery another person's look."""
        if descriptor is None:
            return False
        if self._last_frame is not None and frame - self._last_frame < self.every:
            return False
        if admit is not None and self._n and self.distance(descriptor) > admit:
            return False
        self.add(descriptor, frame)
        return True

    def add(self, descriptor: np.ndarray, frame: int | None = None) -> None:
        self._push(_unit(descriptor))
        if frame is not None:
            self._last_frame = frame

    def mark(self, frame: int) -> None:
        """Start the ``every``-frame clock at ``frame`` (descriptors added at a tracker's birth)."""
        self._last_frame = frame

    def extend(self, other: "Gallery") -> None:
        for d in other.matrix().copy():
            self._push(d)

    def matrix(self) -> np.ndarray:
        """The descriptors ``(n, D)``, oldest first (a view: read, do not keep)."""
        if not self._n:
            return np.zeros((0, 0))
        return self._a[:self._n]

    def newest(self, n: int) -> np.ndarray:
        """The ``n`` most recent descriptors, shape ``(<=n, D)`` (a copy)."""
        if not self._n or n <= 0:
            return np.zeros((0, 0))
        return self._a[max(0, self._n - n):self._n].copy()

    def distance(self, query: np.ndarray) -> float:
        """Eq. 7: ``s_a = min_a (1 - cos(query, a))`` over the gallery; ``nan`` if empty."""
        if not self._n:
            return float("nan")
        return float(1.0 - np.max(self.matrix() @ _unit(query)))

    def distances(self, queries: np.ndarray) -> np.ndarray:
        """Eq. 7 for each row of ``queries`` ``(n, D)``; ``nan`` where the gallery is empty."""
        queries = np.atleast_2d(queries)
        if not self._n or queries.size == 0:
            return np.full(len(queries), np.nan)
        units = queries / np.maximum(np.linalg.norm(queries, axis=1, keepdims=True), 1e-12)
        return 1.0 - self.similarities(units).max(axis=1)

    def similarities(self, units: np.ndarray) -> np.ndarray:
        """The cosines ``(n, len(self))`` of unit-length queries ``(n, D)`` with every stored
        descriptor (eq. 7 is one minus the largest of a row)."""
        return units @ self.matrix().T

    def distance_to(self, other: "Gallery") -> float:
        """Minimum cosine distance between any two descriptors of two galleries (re-id score)."""
        if not self._n or not other._n:
            return float("nan")
        return float(1.0 - np.max(self.matrix() @ other.matrix().T))

    def unlike(self, other: "Gallery", limit: float) -> bool:
        """Whether both galleries are known and farther apart than ``limit`` (two people)."""
        s_a = self.distance_to(other)
        return not np.isnan(s_a) and s_a > limit

    def copy(self) -> "Gallery":
        g = Gallery(self.capacity, self.every)
        g._a, g._n = self._a[:self._n].copy(), self._n
        g._last_frame = self._last_frame
        return g

    def astype(self, dtype: np.dtype | type) -> "Gallery":
        """A copy holding exactly its descriptors, as ``dtype`` (float16: what the re-id store
        keeps of a dropped tracker, a quarter of float64; float64: back to a live tracker)."""
        g = self.copy()
        if self._n:
            g._a = g._a.astype(dtype)
        return g

    @property
    def nbytes(self) -> int:
        """Bytes of the descriptor array (rows allocated, not only those used)."""
        return int(self._a.nbytes)
