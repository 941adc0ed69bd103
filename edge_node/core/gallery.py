"""The bounded appearance gallery of a tracker and the appearance score of eq. 7."""
from __future__ import annotations

from collections import deque
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
    frames (paper III-B: "saving a new patch every N frames, and discarding the oldest one")."""

    def __init__(self, capacity: int = 20, every: int = 20,
                 descriptors: Iterable[np.ndarray] = ()):
        self.capacity = capacity
        self.every = every
        self._items: deque[np.ndarray] = deque(maxlen=capacity)
        self._matrix: np.ndarray | None = None  # cache of the stacked descriptors
        self._last_frame: int | None = None
        for d in descriptors:
            self._items.append(_unit(d))

    def __len__(self) -> int:
        return len(self._items)

    def offer(self, descriptor: np.ndarray | None, frame: int, admit: float | None = None) -> bool:
        """Store ``descriptor`` if ``every`` frames have passed since the last one stored and
        (when ``admit`` is given) it is within ``admit`` of the gallery: a descriptor from a
        wrong association must not teach the gallery another person's look."""
        if descriptor is None:
            return False
        if self._last_frame is not None and frame - self._last_frame < self.every:
            return False
        if admit is not None and self._items and self.distance(descriptor) > admit:
            return False
        self.add(descriptor, frame)
        return True

    def add(self, descriptor: np.ndarray, frame: int | None = None) -> None:
        self._items.append(_unit(descriptor))
        self._matrix = None
        if frame is not None:
            self._last_frame = frame

    def mark(self, frame: int) -> None:
        """Start the ``every``-frame clock at ``frame`` (descriptors added at a tracker's birth)."""
        self._last_frame = frame

    def extend(self, other: "Gallery") -> None:
        for d in other._items:
            self._items.append(d)
        self._matrix = None

    def matrix(self) -> np.ndarray:
        if not self._items:
            return np.zeros((0, 0))
        if self._matrix is None:
            self._matrix = np.stack(self._items)
        return self._matrix

    def newest(self, n: int) -> np.ndarray:
        """The ``n`` most recent descriptors, shape ``(<=n, D)``."""
        items = list(self._items)[-n:]
        return np.stack(items) if items else np.zeros((0, 0))

    def distance(self, query: np.ndarray) -> float:
        """Eq. 7: ``s_a = min_a (1 - cos(query, a))`` over the gallery; ``nan`` if empty."""
        if not self._items:
            return float("nan")
        return float(1.0 - np.max(self.matrix() @ _unit(query)))

    def distances(self, queries: np.ndarray) -> np.ndarray:
        """Eq. 7 for each row of ``queries`` ``(n, D)``; ``nan`` where the gallery is empty."""
        queries = np.atleast_2d(queries)
        if not self._items or queries.size == 0:
            return np.full(len(queries), np.nan)
        Q = queries / np.maximum(np.linalg.norm(queries, axis=1, keepdims=True), 1e-12)
        return 1.0 - (Q @ self.matrix().T).max(axis=1)

    def distance_to(self, other: "Gallery") -> float:
        """Minimum cosine distance between any two descriptors of two galleries (re-id score)."""
        if not self._items or not other._items:
            return float("nan")
        return float(1.0 - np.max(self.matrix() @ other.matrix().T))

    def copy(self) -> "Gallery":
        g = Gallery(self.capacity, self.every, self._items)
        g._last_frame = self._last_frame
        return g
