"""Re-identification quality of appearance descriptors: cross-camera rank-1 and mAP.

The standard protocol of person re-id benchmarks (Market-1501, DukeMTMC): every descriptor is a
query in turn; its gallery is every descriptor taken by *another* camera (same-camera
descriptors are left out, so a query cannot be matched by a near-copy of itself), ranked by
cosine distance, nearest first.

``rank-1``  the fraction of queries whose nearest gallery descriptor shows the same person;
``mAP``     the mean over queries of the average precision of the ranked gallery (the mean,
            over the gallery's descriptors of the query's person, of the precision at each
            one's rank).

Queries whose person has no descriptor in another camera are left out (they cannot be
re-identified); ties in distance keep the gallery's order (a stable sort). Both figures depend
on the gallery: the more people in it, the harder it is, so a quality is stated together with
its number of people (:func:`scenario_reid` and ``appearance.measure_quality`` report it).

:func:`cross_camera_reid` measures any descriptors with their person and camera labels;
:func:`scenario_reid` the descriptors of a scenario's detections, labelled by the scenario's
``detection_truth`` (false positives left out).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim_cluster.scenarios.data import ScenarioData

_BLOCK = 256  # queries ranked at a time (a block x gallery distance matrix)


@dataclass(frozen=True)
class ReidScore:
    """Cross-camera rank-1 and mAP of ``queries`` queries over ``people`` people."""

    rank1: float
    mean_ap: float
    queries: int
    people: int

    def to_dict(self) -> dict:
        return asdict(self)


def cross_camera_reid(descriptors: np.ndarray, person: np.ndarray,
                      camera: np.ndarray) -> ReidScore:
    """Rank-1 and mAP of ``descriptors`` (``(n, dim)``) labelled by ``person`` and ``camera``
    (``(n,)`` each): queries from one camera against the gallery of every other camera."""
    x = np.asarray(descriptors, dtype=np.float64)
    pid = np.asarray(person).reshape(-1)
    cam = np.asarray(camera).reshape(-1)
    if x.ndim != 2 or len(x) != len(pid) or len(x) != len(cam):
        raise ValueError(f"descriptors {x.shape}, person {pid.shape} and camera {cam.shape} "
                         "must have one row each per descriptor")
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norm == 0) or not np.all(np.isfinite(x)):
        raise ValueError("descriptors must be finite and non-zero")
    x = x / norm
    hits1: list[np.ndarray] = []
    aps: list[np.ndarray] = []
    for s in range(0, len(x), _BLOCK):
        q = slice(s, min(s + _BLOCK, len(x)))
        dist = 1.0 - x[q] @ x.T
        other = cam[None, :] != cam[q, None]  # the gallery of each query
        dist[~other] = np.inf  # same-camera descriptors rank last and are not counted
        order = np.argsort(dist, axis=1, kind="stable")
        rel = (pid[order] == pid[q, None]) & np.take_along_axis(other, order, axis=1)
        n_rel = rel.sum(axis=1)
        ok = n_rel > 0  # queries that have their person in another camera
        if not np.any(ok):
            continue
        rel, n_rel = rel[ok], n_rel[ok]
        hits1.append(rel[:, 0])
        precision = np.cumsum(rel, axis=1) / np.arange(1, rel.shape[1] + 1)
        aps.append((precision * rel).sum(axis=1) / n_rel)
    if not hits1:
        return ReidScore(rank1=float("nan"), mean_ap=float("nan"), queries=0,
                         people=int(len(np.unique(pid))))
    h, a = np.concatenate(hits1), np.concatenate(aps)
    return ReidScore(rank1=float(h.mean()), mean_ap=float(a.mean()), queries=int(len(h)),
                     people=int(len(np.unique(pid))))


def scenario_reid(data: ScenarioData, per_view: int = 2) -> ReidScore:
    """Rank-1 and mAP of a scenario's own descriptors: ``per_view`` detections of each
    (person, camera), evenly spread over the frames that camera detected the person in (false
    positives and detections without a descriptor left out). ``people`` counts everyone with a
    descriptor; queries only those seen by two cameras or more."""
    if per_view < 1:
        raise ValueError(f"per_view must be >= 1, got {per_view}")
    if not data.detection_truth:
        raise ValueError(f"scenario {data.name} has no detection truth: nothing to measure")
    seen: dict[tuple[int, int], list[np.ndarray]] = {}
    for k in range(data.frames):
        for c, dets in enumerate(data.detections[k]):
            truth = data.detection_truth[k][c]
            for d, p in zip(dets, truth):
                if p >= 0 and d.descriptor is not None:
                    seen.setdefault((int(p), c), []).append(d.descriptor)
    desc, pid, cam = [], [], []
    for (p, c), ds in sorted(seen.items()):
        for i in np.unique(np.linspace(0, len(ds) - 1, per_view).round().astype(int)):
            desc.append(np.asarray(ds[i], dtype=np.float64))
            pid.append(p)
            cam.append(c)
    if not desc:
        raise ValueError(f"scenario {data.name} has no descriptors: nothing to measure")
    return cross_camera_reid(np.stack(desc), np.array(pid), np.array(cam))
