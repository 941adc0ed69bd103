"""Ground metrics of a run computed frame by frame, beside the run (nothing of it is kept).

:class:`OnlineGround` feeds one py-motmetrics accumulator per node as the run's frames come
(``run_network(on_frame=...)`` over a stream), with the same distances and summary as
:func:`sim_cluster.evaluation.metrics.evaluate_ground` (a test checks they agree), so a large
network's run need not hold every node's tracks of every frame; and it gives each node's matches
(person, track id) for :mod:`sim_cluster.evaluation.walks`.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator

import motmetrics as mm
import numpy as np

from sim_cluster.evaluation.metrics import (GROUND_METRICS, EvaluationError, ground_distances,
                                            median_over, summarize)
from sim_cluster.scenarios.data import Frame


class OnlineGround:
    """Per-node ground accumulators, fed one frame at a time (module docstring)."""

    def __init__(self, units_per_metre: float = 1.0, threshold_m: float = 1.0):
        if threshold_m <= 0 or units_per_metre <= 0:
            raise EvaluationError("threshold_m and units_per_metre must be positive")
        self.units_per_metre, self.threshold_m = units_per_metre, threshold_m
        self._acc: dict[int, mm.MOTAccumulator] = {}
        self._hid: dict[int, dict] = {}

    def add(self, node: int, k: int, tracks: Iterable, truth: Frame) -> None:
        """Node ``node``'s tracks (``.id``, ``.x``) of frame ``k`` against ``truth``."""
        acc = self._acc.setdefault(node, mm.MOTAccumulator(auto_id=False))
        ids = self._hid.setdefault(node, {})
        tracks = list(tracks)
        hids = [ids.setdefault(t.id, len(ids)) for t in tracks]
        hxy = np.array([np.asarray(t.x)[:2] for t in tracks]).reshape(-1, 2)
        d2 = ground_distances(truth.xy, hxy, self.units_per_metre, self.threshold_m)
        acc.update([int(i) for i in np.asarray(truth.ids).ravel()], hids, d2, frameid=k)

    def summary(self) -> dict:
        """``{"median": {...}, "per_node": {"0": {...}, ...}}`` as ``evaluate_ground``."""
        per = {str(n): summarize(a, "ground") for n, a in sorted(self._acc.items())}
        return {"median": median_over(per, GROUND_METRICS), "per_node": per}

    def matches(self, node: int) -> Iterator[tuple[int, int]]:
        """``(person, track number)`` of every matched frame of ``node`` (MATCH and SWITCH)."""
        ev = self._acc[node].mot_events
        if len(ev) == 0:
            return iter(())
        m = ev[ev.Type.isin(["MATCH", "SWITCH"])]
        return zip(m["OId"].astype(int).tolist(), m["HId"].astype(int).tolist())

    @property
    def nodes(self) -> list[int]:
        return sorted(self._acc)
