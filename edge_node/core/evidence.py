"""The co-motion evidence of a node's pairs of trackers (``manager.find_merges``), held as one
square table of the trackers' slots instead of a dictionary of pairs.

Every frame the manager updates the evidence of every pair a camera measured at once far apart
(``manager.far_apart``: with 20 trackers about 190 pairs, with 50 about 1,200) and decides
which pairs to keep. Here a tracker id gets a slot (a row and the same column), and those
frame-wide steps (:meth:`PairEvidence.seen_apart`, :meth:`~PairEvidence.settle`,
:meth:`~PairEvidence.positive`) are a few array operations whatever the number of pairs.

It is also a ``MutableMapping`` from ``(a, b)`` (``a < b``, the manager's order; ``(b, a)``
names the same pair) to nats, so the rules that read a pair or two (``partner``, ``heir``, the
nearby pairs of ``find_merges``) and the tests read it like the dictionary it replaces. A pair
is absent (NaN in the table) until it is first written; reading an absent pair as 0.0 is the
callers' ``get(key, 0.0)``.

Memory is bounded by the trackers the node holds: a tracker's slot is freed when it is gone
(``forget``) or, at the end of a frame, no longer held (``settle``), which also halves the
table while it is at most a quarter full, so a node that once held many trackers does not keep
a table (and its per-frame cost) of that size.
"""
from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping, MutableMapping, Sequence

import numpy as np

from protocol.messages import TrackerId

Key = tuple[TrackerId, TrackerId]
_LEAST = 8  # slots of the smallest table


class PairEvidence(MutableMapping):
    """Nats per pair of trackers; see the module docstring."""

    def __init__(self, pairs: Mapping[Key, float] | None = None):
        self._slot: dict[TrackerId, int] = {}  # tracker id -> its row and column
        self._ids: list[TrackerId | None] = []  # slot -> tracker id (None: free)
        self._free: list[int] = []
        self._table = np.full((0, 0), np.nan)  # [slot a, slot b] = [slot b, slot a]: nats
        for key, e in (pairs or {}).items():
            self[key] = e

    # -- slots ------------------------------------------------------------------------------
    def slots(self, ids: list[TrackerId]) -> np.ndarray:
        """The slots of ``ids``, a slot given to each id that has none (the table grows by
        doubling when it is full)."""
        return np.array([self._slot_of(tid) for tid in ids], np.intp)

    def _slot_of(self, tid: TrackerId) -> int:
        s = self._slot.get(tid)
        return self._take(tid) if s is None else s

    def size(self) -> int:
        """Slots of the table (held and free)."""
        return len(self._ids)

    def holders(self) -> set[TrackerId]:
        """The trackers that have a slot."""
        return set(self._slot)

    def _take(self, tid: TrackerId) -> int:
        if not self._free:
            self._resize(max(_LEAST, 2 * len(self._ids)))
        s = self._free.pop()
        self._slot[tid] = s
        self._ids[s] = tid
        return s

    def _resize(self, size: int) -> None:
        """A table of ``size`` slots holding the same pairs: the held slots keep their order,
        packed first; the rest are free, the lowest taken first."""
        held = sorted(self._slot.values())
        table = np.full((size, size), np.nan)
        table[:len(held), :len(held)] = self._table[np.ix_(held, held)]
        self._table = table
        self._ids = [self._ids[s] for s in held] + [None] * (size - len(held))
        self._slot = {tid: s for s, tid in enumerate(self._ids[:len(held)])}
        self._free = list(range(size - 1, len(held) - 1, -1))

    def _release(self, s: int) -> None:
        self._table[s, :] = np.nan
        self._table[:, s] = np.nan
        del self._slot[self._ids[s]]
        self._ids[s] = None
        self._free.append(s)

    def _pair(self, key: Key) -> tuple[int, int] | None:
        a, b = self._slot.get(key[0]), self._slot.get(key[1])
        return None if a is None or b is None or a == b else (a, b)

    # -- the mapping ------------------------------------------------------------------------
    def apart(self, pairs: Sequence[Key]) -> np.ndarray:
        """Which of ``pairs`` (either order) hold evidence below zero: two people (a camera
        measured both at once, or they moved apart), ``(len(pairs),)`` bool; an absent pair
        is not."""
        get = self._slot.get
        at = np.array([(get(a, -1), get(b, -1)) for a, b in pairs], np.intp).reshape(-1, 2)
        held = (at >= 0).all(axis=1) & (at[:, 0] != at[:, 1])
        out = np.zeros(len(pairs), bool)
        if held.any():  # (the table is symmetric; NaN, absent, is not below zero)
            out[held] = self._table[at[held, 0], at[held, 1]] < 0.0
        return out

    def get(self, key: Key, default: float | None = None) -> float | None:
        at = self._pair(key)
        e = np.nan if at is None else self._table.item(at)
        return default if e != e else e  # NaN: absent

    def __getitem__(self, key: Key) -> float:
        e = self.get(key)
        if e is None:
            raise KeyError(key)
        return e

    def __setitem__(self, key: Key, e: float) -> None:
        if key[0] == key[1]:
            raise KeyError(f"a pair of one tracker with itself: {key}")
        a, b = self._slot_of(key[0]), self._slot_of(key[1])  # (growing keeps the slots)
        self._table[a, b] = self._table[b, a] = e

    def __delitem__(self, key: Key) -> None:
        at = self._pair(key)
        if at is None or np.isnan(self._table[at]):
            raise KeyError(key)
        self._table[at] = self._table[at[::-1]] = np.nan

    def __iter__(self) -> Iterator[Key]:
        return iter([key for key, _ in self._present(~np.isnan(self._table))])

    def __len__(self) -> int:
        return int(np.count_nonzero(~np.isnan(self._table))) // 2

    def __repr__(self) -> str:
        return f"PairEvidence({dict(self.items())!r})"

    def _present(self, where: np.ndarray) -> list[tuple[Key, float]]:
        """The pairs at the table's ``where`` (present ones only: NaN compares false), each
        once, ``(a, b)`` with ``a < b``."""
        s, t = np.nonzero(np.triu(where, 1))
        out = []
        for i, j, e in zip(s.tolist(), t.tolist(), self._table[s, t].tolist()):
            a, b = self._ids[i], self._ids[j]
            out.append(((a, b) if a < b else (b, a), e))
        return out

    # -- the frame-wide steps ---------------------------------------------------------------
    def seen_apart(self, ids: list[TrackerId], i: np.ndarray, j: np.ndarray, nats: np.ndarray,
                   floor: float) -> None:
        """Pairs ``(ids[i], ids[j])`` a camera saw as two people (``manager.far_apart``): what
        spoke for one target dropped (an absent pair counts as 0), ``nats`` (negative) added,
        at least ``floor``."""
        slot = self.slots(ids)
        a, b = slot.take(i), slot.take(j)
        table = self._table  # (after the slots: taking one may grow it)
        old = table[a, b]
        e = np.minimum(np.where(np.isnan(old), 0.0, old), 0.0) + nats
        table[a, b] = table[b, a] = np.maximum(e, floor)

    def positive(self) -> list[tuple[Key, float]]:
        """The pairs with evidence above 0 (for one target), in key order."""
        return sorted(self._present(self._table > 0.0))

    def settle(self, held: Collection[TrackerId], alive: Collection[Key]) -> None:
        """``find_merges``' end of frame: every pair but those ``alive`` (scored for a merge
        this frame) and those of two trackers ``held`` with evidence below 0 (seen as two
        people: remembered while both live) is forgotten; the slots of trackers not held are
        freed, and the table halved while at most a quarter of it is used."""
        gone = [tid for tid in self._slot if tid not in held]
        h = np.zeros(len(self._ids), bool)
        h[[s for tid, s in self._slot.items() if tid in held]] = True
        keep = (self._table < 0.0) & np.logical_and.outer(h, h)
        at = [p for p in map(self._pair, alive) if p is not None]
        if at:
            a, b = np.array(at, np.intp).T
            keep[a, b] = keep[b, a] = True
        self._table[~keep] = np.nan
        for tid in gone:
            self._release(self._slot[tid])
        size = len(self._ids)
        if size > _LEAST and 4 * len(self._slot) <= size:
            self._resize(size // 2)

    def forget(self, tid: TrackerId) -> None:
        """``tid`` is gone: its pairs and its slot."""
        s = self._slot.get(tid)
        if s is not None:
            self._release(s)
