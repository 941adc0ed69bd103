"""Ids kept along long walks: does a person who walks across many cameras keep one id on a node?

Definitions (the scale benchmark, ``sim_cluster bench --cameras``, reports them):

* A person's **walk** is the frames in which they are in the ground truth (``Frame.ids``: inside
  some camera's view), and the cameras they **cross** are those whose image ground truth
  (``Frame.boxes[c]``) lists them at least once.
* A **long walker** crosses at least ``min_cameras`` cameras (default 4).
* On one node, the person's frames are matched to the node's tracks by the ground evaluation
  (py-motmetrics, within the ground threshold: its MATCH and SWITCH events). The person's
  **dominant id** is the track id matched to them in the most frames.
* **id kept** (per node) = the long walkers' frames matched to their dominant id / their walk
  frames, summed over the long walkers (a walk-weighted fraction in [0, 1]; frames missed or
  matched to another id count against it). 1.0: every long walker carried one id from the
  first frame they were in view to the last.
* **ids per long walk** (per node) = the mean, over long walkers, of the distinct track ids
  matched to them (1.0 is ideal; unmatched walkers count 0).

:class:`WalkLog` collects the walks from a stream's frames (it holds one counter and one camera
set per person ever seen: what the evaluation needs, not the world); :func:`walk_ids` scores one
node's matches.
"""
from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable, Mapping

from sim_cluster.scenarios.data import Frame


class WalkLog:
    """Each person's walk length (frames in the ground truth) and the cameras they crossed."""

    def __init__(self) -> None:
        self.frames: Counter = Counter()
        self.cameras: dict[int, set[int]] = defaultdict(set)

    def observe(self, frame: Frame) -> None:
        """Count one frame."""
        for pid in frame.ids:
            self.frames[int(pid)] += 1
        for c, (ids, _) in enumerate(frame.boxes):
            for pid in ids:
                self.cameras[int(pid)].add(c)

    def long_walkers(self, min_cameras: int = 4) -> set[int]:
        """People who crossed at least ``min_cameras`` cameras' views."""
        return {p for p, cams in self.cameras.items() if len(cams) >= min_cameras}


def walk_ids(matches: Iterable[tuple[int, object]], walk_frames: Mapping[int, int],
             walkers: Iterable[int]) -> dict[str, float | int | None]:
    """One node's ``id_kept`` and ``ids_per_walk`` (module docstring) over ``walkers``.

    ``matches``: ``(person, track id)`` per matched frame (one pair per person and frame);
    ``walk_frames[person]``: frames of their walk. ``None`` where there is no long walker."""
    walkers = set(walkers)
    per: dict[int, Counter] = {p: Counter() for p in walkers}
    for person, tid in matches:
        if person in per:
            per[person][tid] += 1
    total = sum(walk_frames.get(p, 0) for p in walkers)
    if not walkers or total == 0:
        return {"walkers": len(walkers), "id_kept": None, "ids_per_walk": None}
    kept = sum(max(c.values(), default=0) for c in per.values())
    return {"walkers": len(walkers), "id_kept": kept / total,
            "ids_per_walk": sum(len(c) for c in per.values()) / len(walkers)}
