"""Regional ground evaluation: each node scored only on the ground its neighbourhood sees.

With regional scope (``TrackerConfig.scope_hops``) a node keeps only the targets near its
cameras, and even without it a node of a large network holds far people only through
consensus; scoring every node against everybody in the network then counts far people as its
misses. The regional score is MOT evaluation with an area of interest per node:

* **Region of node i**: the ground seen by the cameras of its inclusive neighbourhood (camera
  ``i`` and its 1-hop neighbours in the network's graph).
* **A camera sees a ground point** ``(x, y)`` when the point, at height 0, projects in front
  of the camera (positive depth, :meth:`Camera.in_front`) and inside its image
  (``0 <= u <= W``, ``0 <= v <= H``): the foot of a person standing there is in the picture.
  This is the same test for a true person (their ground position ``Frame.xy``) and a reported
  track (its ground point ``x[:2]``), both in the cameras' ground units.
* Truth people outside node i's region and tracks outside it are dropped before matching:
  neither a miss nor a false positive. Inside, matching is the ground evaluation's
  (py-motmetrics, within the threshold), so a person inside the region whose track drifted
  just outside it counts as a miss.

:class:`RegionalGround` is :class:`~sim_cluster.evaluation.online.OnlineGround` with that
filter, and it counts each person's frames inside each node's region (the regional walks of
:mod:`sim_cluster.evaluation.walks`).
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from edge_node.geometry import Camera
from sim_cluster.evaluation.metrics import EvaluationError
from sim_cluster.evaluation.online import OnlineGround
from sim_cluster.scenarios.data import Frame


def sees(camera: Camera, xy: np.ndarray) -> np.ndarray:
    """Whether ``camera`` sees each ground point of ``xy`` ``(n, 2)`` (module docstring)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if not len(xy):
        return np.zeros(0, bool)
    W, H = camera.image_size
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = camera.to_image(xy)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= W) & (uv[:, 1] >= 0) & (uv[:, 1] <= H)
    return inside & camera.in_front(xy)


class Regions:
    """Each node's region: the union of what its inclusive neighbourhood's cameras see."""

    def __init__(self, cameras: Sequence[Camera], neighbours: Mapping[int, Iterable[int]]):
        self.cameras = {c.id: c for c in cameras}
        self.members: dict[int, tuple[int, ...]] = {}
        for node, nbrs in neighbours.items():
            members = tuple(sorted({int(node), *(int(j) for j in nbrs)}))
            missing = [c for c in members if c not in self.cameras]
            if missing:
                raise EvaluationError(f"node {node}'s region names cameras {missing} that the "
                                      f"scenario does not have")
            self.members[int(node)] = members

    def contains(self, node: int, xy: np.ndarray,
                 seen: Mapping[int, np.ndarray] | None = None) -> np.ndarray:
        """Whether each point of ``xy`` lies in ``node``'s region; ``seen[c]``, when given, is
        :func:`sees` of camera ``c`` on these very points (computed once for many nodes)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        if node not in self.members:
            raise EvaluationError(f"node {node} has no region (not in the neighbour graph)")
        mask = np.zeros(len(xy), bool)
        for c in self.members[node]:
            mask |= seen[c] if seen is not None else sees(self.cameras[c], xy)
        return mask


class RegionalGround(OnlineGround):
    """:class:`OnlineGround` scoring each node inside its region only (module docstring)."""

    def __init__(self, regions: Regions, units_per_metre: float = 1.0, threshold_m: float = 1.0):
        super().__init__(units_per_metre, threshold_m)
        self.regions = regions
        self.walk_frames: dict[int, Counter] = {}
        self._truth_key: tuple[int, int] | None = None
        self._truth_seen: dict[int, np.ndarray] = {}

    def _seen(self, k: int, truth: Frame) -> dict[int, np.ndarray]:
        """Every camera's :func:`sees` on frame ``k``'s true positions, once per frame."""
        key = (k, id(truth))
        if key != self._truth_key:
            xy = np.asarray(truth.xy, float).reshape(-1, 2)
            self._truth_seen = {c: sees(cam, xy) for c, cam in self.regions.cameras.items()}
            self._truth_key = key
        return self._truth_seen

    def add(self, node: int, k: int, tracks: Iterable, truth: Frame) -> None:
        """Node ``node``'s tracks of frame ``k`` in its region, against the people in it."""
        keep = self.regions.contains(node, np.asarray(truth.xy).reshape(-1, 2),
                                     self._seen(k, truth))
        ids = np.asarray(truth.ids).ravel()[keep]
        counter = self.walk_frames.setdefault(node, Counter())
        for pid in ids:
            counter[int(pid)] += 1
        tracks = list(tracks)
        hxy = np.array([np.asarray(t.x)[:2] for t in tracks], float).reshape(-1, 2)
        inside = self.regions.contains(node, hxy)
        region_truth = Frame(detections=[], detection_truth=[], ids=ids,
                             xy=np.asarray(truth.xy).reshape(-1, 2)[keep],
                             wh=np.zeros((len(ids), 2)), boxes=[])
        super().add(node, k, [t for t, i in zip(tracks, inside) if i], region_truth)
