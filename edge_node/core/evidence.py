"""The co-motion evidence of a node's pairs of trackers (``manager.find_merges``), held as one
square table of the trackers' slots instead of a dictionary of pairs.

Every frame the manager updates the evidence of every pair a camera measured at once far apart
(``manager.far_apart``: with 20 trackers about 190 pairs, with 50 about 1,200) and decides
which pairs to keep; one Python step per pair was a fifth of a node-frame at 50 trackers.
Here a tracker id gets a slot (a row and the same column) while the table holds a pair of it,
and those frame-wide steps are a few array operations whatever the number of pairs.

It is also a ``MutableMapping`` from ``(a, b)`` (``a < b``, the manager's order) to nats, so
the rules that read a pair or two (``partner``, ``heir``, the nearby pairs of ``find_merges``)
and the tests read it like the dictionary it replaces. A pair is absent (NaN in the table) until
it is first written; reading an absent pair as 0.0 is the callers' ``get(key, 0.0)``. Memory is
bounded by the trackers the table holds pairs of: a slot is freed with its tracker's last pair
(``forget``, ``settle``).
"""
from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping, MutableMapping

import numpy as np

from protocol.messages import TrackerId

Key = tuple[TrackerId, TrackerId]


class PairEvidence(MutableMapping):
    """Nats per pair of trackers; see the module docstring."""

    def __init__(self, pairs: Mapping[Key, float] | None = None):
        self._slot: dict[TrackerId, int] = {}  # tracker id -> its row and column
        self._ids: list[TrackerId | None] = []  # slot -> tracker id (None: free)
        self._free: list[int] = []
        self.table = np.full((0, 0), np.nan)  # [slot a, slot b] = [slot b, slot a]: nats
        for key, e in (pairs or {}).items():
            self[key] = e

    # -- slots ------------------------------------------------------------------------------
    def slots(self, ids: list[TrackerId]) -> np.ndarray:
        """The slots of ``ids``, a slot given to each id that has none (the table grows by
        doubling when it is full)."""
        out = []
        for tid in ids:
            s = self._slot.get(tid)
            if s is None:
                s = self._take(tid)
            out.append(s)
        return np.array(out, np.intp)

    def holders(self) -> set[TrackerId]:
        """The trackers that have a slot."""
        return set(self._slot)

    def _take(self, tid: TrackerId) -> int:
        if not self._free:
            n = len(self._ids)
            grown = np.full((max(8, 2 * n),) * 2, np.nan)
            grown[:n, :n] = self.table
            self.table = grown
            self._free = list(range(len(grown) - 1, n - 1, -1))  # the lowest slot first
            self._ids.extend([None] * (len(grown) - n))
        s = self._free.pop()
        self._slot[tid] = s
        self._ids[s] = tid
        return s

    def _release(self, s: int) -> None:
        self.table[s, :] = np.nan
        self.table[:, s] = np.nan
        del self._slot[self._ids[s]]
        self._ids[s] = None
        self._free.append(s)

    def _pair(self, key: Key) -> tuple[int, int] | None:
        a, b = self._slot.get(key[0]), self._slot.get(key[1])
        return None if a is None or b is None or a == b else (a, b)

    # -- the mapping ------------------------------------------------------------------------
    def __getitem__(self, key: Key) -> float:
        at = self._pair(key)
        e = np.nan if at is None else self.table.item(at)
        if e != e:  # NaN: absent
            raise KeyError(key)
        return e

    def get(self, key: Key, default: float | None = None) -> float | None:
        at = self._pair(key)
        e = np.nan if at is None else self.table.item(at)
        return default if e != e else e

    def __setitem__(self, key: Key, e: float) -> None:
        a, b = self._slot.get(key[0]), self._slot.get(key[1])
        a = self._take(key[0]) if a is None else a
        b = self._take(key[1]) if b is None else b
        self.table[a, b] = self.table[b, a] = e

    def __delitem__(self, key: Key) -> None:
        self[key]  # KeyError when absent
        a, b = self._pair(key)
        self.table[a, b] = self.table[b, a] = np.nan

    def __iter__(self) -> Iterator[Key]:
        return iter([key for key, _ in self._present(~np.isnan(self.table))])

    def __len__(self) -> int:
        return int(np.count_nonzero(~np.isnan(self.table))) // 2

    def _present(self, where: np.ndarray) -> list[tuple[Key, float]]:
        """The pairs at the table's ``where`` (present ones only: NaN compares false), each
        once, ``(a, b)`` with ``a < b``."""
        s, t = np.nonzero(np.triu(where, 1))
        out = []
        for i, j, e in zip(s.tolist(), t.tolist(), self.table[s, t].tolist()):
            a, b = self._ids[i], self._ids[j]
            out.append(((a, b) if a < b else (b, a), e))
        return out

    # -- the frame-wide steps ---------------------------------------------------------------
    def positive(self) -> list[tuple[Key, float]]:
        """The pairs with evidence above 0 (for one target), in key order."""
        return sorted(self._present(self.table > 0.0))

    def settle(self, held: Collection[TrackerId], alive: Collection[Key]) -> None:
        """``find_merges``' end of frame: every pair but those ``alive`` (scored for a merge
        this frame) and those of two trackers ``held`` with evidence below 0 (seen as two
        people: remembered while both live) is forgotten, and the slots of trackers not held
        are freed."""
        gone = [tid for tid in self._slot if tid not in held]
        h = np.zeros(len(self._ids), bool)
        h[[s for tid, s in self._slot.items() if tid in held]] = True
        keep = (self.table < 0.0) & np.logical_and.outer(h, h)
        at = [p for p in map(self._pair, alive) if p is not None]
        if at:
            a, b = np.array(at, np.intp).T
            keep[a, b] = keep[b, a] = True
        self.table[~keep] = np.nan
        for tid in gone:
            self._release(self._slot[tid])

    def forget(self, tid: TrackerId) -> None:
        """``tid`` is gone: its pairs and its slot."""
        s = self._slot.get(tid)
        if s is not None:
            self._release(s)
