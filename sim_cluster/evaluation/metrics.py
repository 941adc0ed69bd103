"""Tracking metrics of a run through py-motmetrics: per camera in the image plane, per node on the ground.

Two views, both computed with ``motmetrics.MOTAccumulator`` and ``motmetrics.metrics``:

``image`` (the paper's protocol, Section IV): node ``c``'s tracks in node ``c``'s own camera as
    boxes: a track's own-view box ``Track.boxes[c]`` when the node reports boxes (its estimate
    through the camera's own registration, at the camera's own box size; tracks the camera has not
    seen recently have none and are not in its view), else the projection of the state's cylinder
    ``x[:4]`` (``Camera.cylinder_to_box``; tracks read back from files without boxes). Boxes in
    front of the camera and overlapping the image are kept and clipped to it (ground-truth boxes
    are clipped to the image too), and matched to that camera's ground-truth boxes at IoU >= 0.5. MOTP is the
    mean IoU of the matches (a fraction, higher is better). The result per camera and the median
    over cameras are reported.
``ground``: each node's whole track set against every person in the monitored area, matched by
    ground distance within a threshold (default 1 m, converted with ``units_per_metre``). MOTP is
    reported as ``motp_m``: the mean distance in metres of the matches.

IoU is computed here: ``mm.distances.iou_matrix`` calls ``np.asfarray``, removed in numpy 2.
Ground distances are handed to motmetrics squared (its assignment minimises the sum of squared
distances, like ``norm2squared_matrix``); ``motp_m`` is then the mean of their square roots, read
from the accumulator's events rather than motmetrics' ``motp`` (a mean squared distance).

A centralised tracker is evaluated in the image view by giving its one track set to every node:
``{c: central for c in range(num_cameras)}``.

The result is JSON-able: plain ``int``/``float``, ``None`` where a ratio is undefined (no objects).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Protocol, Union

import numpy as np

from edge_node.geometry import Camera
from protocol.errors import DmttError
from sim_cluster.scenarios.data import ScenarioData

try:  # motmetrics is a declared dependency; fail with a clear message if the env lacks it.
    import motmetrics as mm
except ImportError as exc:  # pragma: no cover - environment problem
    raise ImportError("sim_cluster.evaluation needs py-motmetrics (pip install motmetrics)") from exc


class EvaluationError(DmttError, ValueError):
    """Tracks or ground truth that cannot be evaluated (bad node index, malformed state)."""


class TrackLike(Protocol):
    """Anything with a tracker id and a state ``x = (x, y, w, h, vx, vy)``; e.g. ``core.types.Track``."""

    id: Any
    x: np.ndarray


TrackEntry = Union[TrackLike, tuple[Any, np.ndarray]]
"""One track at one frame: a ``Track`` (``.id``, ``.x``) or a pair ``(track_id, x)``."""

NodeTracks = Union[Sequence[Iterable[TrackEntry]], Mapping[int, Iterable[TrackEntry]]]
"""One node's tracks, frame by frame: a list indexed by frame, or a mapping frame -> tracks."""

RunTracks = Union[Mapping[Any, NodeTracks], Sequence[NodeTracks]]
"""A run's tracks: ``tracks[node][frame] -> tracks``; a mapping by node index or a list."""

#: Identity counts (standard MOT definitions, computed by py-motmetrics except the last two):
#: ``num_fragmentations`` (a person's tracked frames interrupted by a missed one),
#: ``mostly_tracked`` / ``partially_tracked`` / ``mostly_lost`` (people matched in >= 80 %,
#: 20-80 %, < 20 % of the frames they are present), ``num_track_ids`` (distinct track ids the
#: node reported in the evaluated frames) and ``ids_per_person`` (distinct track ids matched to
#: a person, averaged over the people matched at least once: 1.0 when each kept one id).
IDENTITY_METRICS = ("num_fragmentations", "mostly_tracked", "partially_tracked", "mostly_lost",
                    "num_track_ids", "ids_per_person")
COMMON_METRICS = ("mota", "idf1", "idp", "idr", "num_switches", "num_false_positives",
                  "num_misses", "num_matches", "num_objects", "num_predictions",
                  "num_unique_objects", "num_frames") + IDENTITY_METRICS
IMAGE_METRICS = COMMON_METRICS[:1] + ("motp",) + COMMON_METRICS[1:]
GROUND_METRICS = COMMON_METRICS[:1] + ("motp_m",) + COMMON_METRICS[1:]

_MM_METRICS = ["mota", "motp", "idf1", "idp", "idr", "num_switches", "num_false_positives",
               "num_misses", "num_matches", "num_objects", "num_predictions",
               "num_unique_objects", "num_frames", "num_fragmentations", "mostly_tracked",
               "partially_tracked", "mostly_lost", "pred_frequencies"]
_MM_METRICS.remove("num_fragmentations")  # counted by fragmentations(): the same, faster
_COUNTS = {"num_switches", "num_false_positives", "num_misses", "num_matches", "num_objects",
           "num_predictions", "num_unique_objects", "num_frames", "num_fragmentations",
           "mostly_tracked", "partially_tracked", "mostly_lost", "num_track_ids"}


# -- distances ------------------------------------------------------------------------------------
def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of boxes ``a (n, 4)`` against ``b (m, 4)``, both ``(x, y, w, h)``; ``(n, m)``."""
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    b = np.asarray(b, dtype=float).reshape(-1, 4)
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    ax0, ay0 = a[:, 0:1], a[:, 1:2]
    ax1, ay1 = ax0 + a[:, 2:3], ay0 + a[:, 3:4]
    bx0, by0 = b[:, 0], b[:, 1]
    bx1, by1 = bx0 + b[:, 2], by0 + b[:, 3]
    iw = np.clip(np.minimum(ax1, bx1) - np.maximum(ax0, bx0), 0.0, None)
    ih = np.clip(np.minimum(ay1, by1) - np.maximum(ay0, by0), 0.0, None)
    inter = iw * ih
    union = (a[:, 2] * a[:, 3])[:, None] + (b[:, 2] * b[:, 3])[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = np.where(union > 0, inter / union, 0.0)
    return iou


def iou_distances(gt: np.ndarray, hyp: np.ndarray, min_iou: float = 0.5) -> np.ndarray:
    """motmetrics distances ``1 - IoU`` (``(n_gt, n_hyp)``), ``nan`` where IoU < ``min_iou``."""
    d = 1.0 - iou_matrix(gt, hyp)
    d[d > 1.0 - min_iou + 1e-12] = np.nan
    return d


def ground_distances(gt_xy: np.ndarray, hyp_xy: np.ndarray, units_per_metre: float,
                     threshold_m: float) -> np.ndarray:
    """Squared ground distances in metres^2 (``(n_gt, n_hyp)``), ``nan`` beyond ``threshold_m``."""
    g = np.asarray(gt_xy, dtype=float).reshape(-1, 2)
    h = np.asarray(hyp_xy, dtype=float).reshape(-1, 2)
    d2 = ((g[:, None, :] - h[None, :, :]) ** 2).sum(axis=2) / (units_per_metre ** 2)
    d2[~(d2 <= threshold_m ** 2)] = np.nan
    return d2


# -- input normalisation --------------------------------------------------------------------------
NO_BOXES = None  # an entry that carries no own-view boxes: project its cylinder


def _entry(t: TrackEntry) -> tuple[Any, np.ndarray, Mapping[int, np.ndarray] | None]:
    boxes = getattr(t, "boxes", NO_BOXES)
    if hasattr(t, "id") and hasattr(t, "x"):
        tid, x = t.id, t.x
    else:
        try:
            if len(t) == 3:  # already normalised: (id, x, boxes)
                tid, x, boxes = t  # type: ignore[misc]
            else:
                tid, x = t  # type: ignore[misc]
        except (TypeError, ValueError) as exc:
            raise EvaluationError(f"track entry {t!r} is neither a Track nor a (id, x) pair") from exc
    x = np.asarray(x, dtype=float).ravel()
    if x.shape[0] < 4:
        raise EvaluationError(f"track {tid!r}: state must hold at least (x, y, w, h), got {x.shape}")
    return tid, x, boxes


class _IdMap:
    """Tracker ids (``(camera, counter)`` tuples) to small ints: motmetrics 1.4.0 casts object and
    hypothesis ids to float when it builds its event table, so strings or tuples fail there."""

    def __init__(self) -> None:
        self._ids: dict[Any, int] = {}

    def __call__(self, tid: Any) -> int:
        key = tuple(tid) if isinstance(tid, (list, np.ndarray)) else tid
        return self._ids.setdefault(key, len(self._ids))


def _frames_of(node_tracks: NodeTracks) -> dict[int, list[tuple[Any, np.ndarray]]]:
    items = node_tracks.items() if isinstance(node_tracks, Mapping) else enumerate(node_tracks)
    return {int(k): [_entry(t) for t in (ts or ())] for k, ts in items}


def _nodes_of(tracks: RunTracks) -> dict[int, dict[int, list[tuple[Any, np.ndarray]]]]:
    items = tracks.items() if isinstance(tracks, Mapping) else enumerate(tracks)
    out: dict[int, dict[int, list[tuple[Any, np.ndarray]]]] = {}
    for node, nt in items:
        try:
            out[int(node)] = _frames_of(nt)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, EvaluationError):
                raise
            raise EvaluationError(f"node {node!r}: tracks must be indexed by int frames") from exc
    return out


def _num_frames(nodes: Mapping[int, Mapping[int, Any]], scenario: ScenarioData,
                frames: int | None) -> int:
    total = len(scenario.truth.ids)
    if frames is not None:
        if frames > total:
            raise EvaluationError(f"frames={frames} exceeds the ground truth's {total} frames")
        return frames
    seen = [max(f.keys()) + 1 for f in nodes.values() if f]
    return min(max(seen, default=total), total)


# -- per-view accumulators --------------------------------------------------------------------------
def project_boxes(camera: Camera, cyl: np.ndarray) -> np.ndarray:
    """``Camera.cylinder_to_box`` for many cylinders ``(n, >=4)`` -> ``(n, 4)`` boxes.

    Vectorised for homography-only cameras (the same formula as ``cylinder_to_box``: the foot
    point through ``G^-1``, the width from the ground Jacobian's first column, the height from the
    cylinder's aspect); per cylinder through ``cylinder_to_box`` when the camera has ``P``.
    """
    c = np.atleast_2d(np.asarray(cyl, dtype=float))
    if c.size == 0:
        return np.zeros((0, 4))
    if camera.P is not None:
        return np.array([camera.cylinder_to_box(r[:4]) for r in c])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        foot = camera.to_image(c[:, :2])
        s = camera.pixel_scale
        G = camera.G
        q = np.hstack([foot * s, np.ones((len(c), 1))]) @ G.T
        w = q[:, 2:3]
        col0 = (G[:2, 0][None, :] * w - q[:, :2] * G[2, 0]) / (w * w) * s
        px_per_unit = 1.0 / np.maximum(np.linalg.norm(col0, axis=1), 1e-12)
        bw = c[:, 2] * px_per_unit
        bh = bw * c[:, 3] / np.maximum(c[:, 2], 1e-9)
    return np.stack([foot[:, 0] - bw / 2.0, foot[:, 1] - bh, bw, bh], axis=1)


def in_front(camera: Camera, xy: np.ndarray) -> np.ndarray:
    """``Camera.in_front``, robust to the sign of a homography-only camera's ``G``.

    A homography is defined up to scale, sign included; ``Camera.in_front`` (without ``P``) takes
    a positive third coordinate of ``G^-1 [x, y, 1]`` as "in front", which is backwards for
    calibrations published with the other sign (EPFL Terrace c0, Campus c0 and c1). The sign is
    taken here from the ground point seen at the image's bottom centre, which is in front.
    """
    front = camera.in_front(xy)
    if camera.P is None:
        W, H = camera.image_size
        ref = camera.to_ground(np.array([[W / 2.0, H - 1.0]]))
        if np.all(np.isfinite(ref)) and not camera.in_front(ref)[0]:
            front = ~front
    return front


def visible_boxes(camera: Camera, cyl: np.ndarray, clip: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Boxes of cylinders ``(n, >=4)`` in ``camera`` and whether each is usable: finite, in front
    of the camera, with positive size and overlapping the image. With ``clip`` the boxes are
    clipped to the image, like the annotated ground-truth boxes. Returns ``(boxes, ok)``."""
    c = np.asarray(cyl, dtype=float)
    c = c.reshape(-1, c.shape[-1]) if c.size else np.zeros((0, 4))
    ok = np.all(np.isfinite(c[:, :4]), axis=1)
    boxes = np.full((len(c), 4), np.nan)
    if not ok.any():
        return boxes, ok
    idx = np.flatnonzero(ok)
    front = in_front(camera, c[idx, :2])
    ok[idx[~front]] = False
    idx = idx[front]
    boxes[idx] = project_boxes(camera, c[idx])
    boxes, usable = own_boxes(camera, boxes, clip)
    ok &= usable
    boxes[~ok] = np.nan
    return boxes, ok


def visible_box(camera: Camera, x: np.ndarray, clip: bool = True) -> np.ndarray | None:
    """The box of cylinder ``x[:4]`` in ``camera`` if usable (see :func:`visible_boxes`), else None."""
    b, ok = visible_boxes(camera, np.asarray(x, dtype=float)[None, :4], clip)
    return b[0] if ok[0] else None


def own_boxes(camera: Camera, boxes: np.ndarray, clip: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Own-view boxes ``(n, 4)``: usable when finite, positive and overlapping the image;
    clipped to it with ``clip``. Returns ``(boxes, ok)`` like :func:`visible_boxes`."""
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    W, H = camera.image_size
    with np.errstate(invalid="ignore"):
        x0, y0, x1, y1 = b[:, 0], b[:, 1], b[:, 0] + b[:, 2], b[:, 1] + b[:, 3]
        ok = np.all(np.isfinite(b), axis=1) & (b[:, 2] > 0) & (b[:, 3] > 0)
        ok &= (x1 > 0) & (y1 > 0) & (x0 < W) & (y0 < H)
    if clip:
        x0, y0 = np.maximum(x0, 0.0), np.maximum(y0, 0.0)
        x1, y1 = np.minimum(x1, float(W)), np.minimum(y1, float(H))
        b = np.stack([x0, y0, x1 - x0, y1 - y0], axis=1)
    b = b.copy()
    b[~ok] = np.nan
    return b, ok


def image_accumulator(frames: Mapping[int, list[tuple[Any, np.ndarray, Any]]],
                      scenario: ScenarioData, camera_index: int, num_frames: int,
                      iou_threshold: float = 0.5, clip: bool = True,
                      start: int = 0) -> mm.MOTAccumulator:
    """Events of one node's tracks against its camera's ground-truth boxes, frames
    ``start..num_frames-1``."""
    camera = scenario.cameras[camera_index]
    gt_cam = scenario.truth.boxes[camera_index]
    acc = mm.MOTAccumulator(auto_id=False)
    hid = _IdMap()
    rows, own = [], []
    for k in range(start, num_frames):
        for tid, x, bx in frames.get(k, ()):
            if bx is NO_BOXES:
                rows.append((k, tid, x[:4]))
            elif camera.id in bx or camera_index in bx:
                own.append((k, tid, bx.get(camera.id, bx.get(camera_index))))
    boxes, ok = visible_boxes(camera, np.array([r[2] for r in rows]).reshape(-1, 4), clip)
    if own:
        ob, ook = own_boxes(camera, np.array([r[2] for r in own]), clip)
        rows += own
        boxes, ok = np.vstack([boxes, ob]), np.concatenate([ok, ook])
    per_frame: list[list[int]] = [[] for _ in range(num_frames)]
    for r, (k, _, _) in enumerate(rows):
        if ok[r]:
            per_frame[k].append(r)
    for k in range(start, num_frames):
        gt_ids, gt_boxes = gt_cam[k] if k < len(gt_cam) else (np.zeros(0, int), np.zeros((0, 4)))
        sel = per_frame[k]
        d = iou_distances(np.asarray(gt_boxes).reshape(-1, 4), boxes[sel].reshape(-1, 4),
                          iou_threshold)
        acc.update([int(i) for i in np.asarray(gt_ids).ravel()], [hid(rows[r][1]) for r in sel],
                   d, frameid=k)
    return acc


def ground_accumulator(frames: Mapping[int, list[tuple[Any, np.ndarray]]], scenario: ScenarioData,
                       num_frames: int, threshold_m: float = 1.0,
                       start: int = 0) -> mm.MOTAccumulator:
    """Events of one node's tracks against everyone in the monitored area, on the ground,
    frames ``start..num_frames-1``."""
    truth = scenario.truth
    acc = mm.MOTAccumulator(auto_id=False)
    hid = _IdMap()
    for k in range(start, num_frames):
        ts = frames.get(k, ())
        hids = [hid(tid) for tid, _, _ in ts]
        hxy = np.array([x[:2] for _, x, _ in ts]).reshape(-1, 2)
        d2 = ground_distances(truth.xy[k], hxy, scenario.units_per_metre, threshold_m)
        acc.update([int(i) for i in np.asarray(truth.ids[k]).ravel()], hids, d2, frameid=k)
    return acc


# -- summaries ----------------------------------------------------------------------------------------
def _jsonable(name: str, v: Any) -> int | float | None:
    if v is None:
        return None
    v = float(v)
    if not np.isfinite(v):
        return None
    return int(round(v)) if name in _COUNTS else v


def _matched_d(acc: mm.MOTAccumulator) -> np.ndarray:
    ev = acc.mot_events
    if len(ev) == 0:
        return np.zeros(0)
    m = ev[ev.Type.isin(["MATCH", "SWITCH"])]
    return m["D"].to_numpy(dtype=float)


def fragmentations(acc: mm.MOTAccumulator) -> int:
    """py-motmetrics' ``num_fragmentations``, vectorised: per person, the frames it is present
    in order, and every change from tracked (MATCH or SWITCH) to missed that a later tracked
    frame follows (between its first and last tracked frame). motmetrics loops over people with a
    filter of every event each (about 1 ms per person per node: a 64-camera sweep with 400
    people would spend a minute on it); a test checks both agree."""
    ev = acc.mot_events
    if len(ev) == 0:
        return 0
    ev = ev[ev.Type.isin(["MATCH", "SWITCH", "MISS"]) & ev.OId.notna()]
    if len(ev) == 0:
        return 0
    frame = ev.index.get_level_values("FrameId").to_numpy()
    oid = ev.OId.to_numpy(dtype=float)
    order = np.lexsort((frame, oid))
    oid, miss = oid[order], (ev.Type.to_numpy() == "MISS")[order]
    same = np.concatenate([[False], oid[1:] == oid[:-1]])
    starts = same & miss & ~np.roll(miss, 1)  # tracked -> missed within one person
    # a tracked frame of the same person after it: the last tracked row's position per person
    pos = np.arange(len(oid))
    tracked_pos = np.where(~miss, pos, -1)
    change = np.flatnonzero(~same)  # first row of each person
    last = np.maximum.reduceat(tracked_pos, change)
    last_tracked = np.repeat(last, np.diff(np.append(change, len(oid))))
    return int(np.count_nonzero(starts & (pos < last_tracked)))


def _ids_per_person(acc: mm.MOTAccumulator) -> float | None:
    """Distinct track ids matched (MATCH or SWITCH) to each person, averaged over the people
    matched at least once; None when nobody was."""
    ev = acc.mot_events
    if len(ev) == 0:
        return None
    m = ev[ev.Type.isin(["MATCH", "SWITCH"])]
    if len(m) == 0:
        return None
    return float(m.groupby("OId")["HId"].nunique().mean())


def summarize(acc: mm.MOTAccumulator, view: str) -> dict[str, int | float | None]:
    """The metrics of one accumulator as a JSON-able dict (``view`` is ``"image"`` or ``"ground"``)."""
    if view not in ("image", "ground"):
        raise EvaluationError(f"unknown view {view!r} (image or ground)")
    raw = dict(mm.metrics.create().compute(acc, metrics=_MM_METRICS, return_dataframe=False))
    raw["num_track_ids"] = len(raw.pop("pred_frequencies"))  # frames per hypothesis id
    raw["num_fragmentations"] = fragmentations(acc)
    raw["ids_per_person"] = _ids_per_person(acc)
    d = _matched_d(acc)
    out = {n: _jsonable(n, raw[n]) for n in COMMON_METRICS}
    if out["num_objects"] == 0:  # ratios over no objects are undefined (motmetrics gives nan/inf;
        # IDF1 is 0 there when the node reported tracks: no ground truth is not a score of 0)
        for n in ("mota", "idr", "idf1", "ids_per_person"):
            out[n] = None
    if view == "image":
        out["motp"] = float(np.mean(1.0 - d)) if len(d) else None
        order = IMAGE_METRICS
    else:
        out["motp_m"] = float(np.mean(np.sqrt(d))) if len(d) else None
        order = GROUND_METRICS
    return {n: out[n] for n in order}


def median_over(per_node: Mapping[str, Mapping[str, int | float | None]],
                names: Sequence[str]) -> dict[str, float | None]:
    """Median of every metric over nodes, ignoring nodes where it is undefined (None)."""
    med: dict[str, float | None] = {}
    for n in names:
        vals = [v[n] for v in per_node.values() if v.get(n) is not None]
        med[n] = float(np.median(vals)) if vals else None
    return med


# -- entry points -------------------------------------------------------------------------------------
def evaluate_image(tracks: RunTracks, scenario: ScenarioData, iou_threshold: float = 0.5,
                   frames: int | None = None, clip: bool = True, start: int = 0) -> dict[str, Any]:
    """Image-plane metrics: ``{"median": {...}, "per_node": {"0": {...}, ...}}``."""
    nodes = _nodes_of(tracks)
    n = _num_frames(nodes, scenario, frames)
    per: dict[str, dict[str, Any]] = {}
    for node in sorted(nodes):
        if not 0 <= node < scenario.num_cameras:
            raise EvaluationError(f"node {node} has no camera (scenario has {scenario.num_cameras})")
        acc = image_accumulator(nodes[node], scenario, node, n, iou_threshold, clip, start)
        per[str(node)] = summarize(acc, "image")
    return {"median": median_over(per, IMAGE_METRICS), "per_node": per}


def evaluate_ground(tracks: RunTracks, scenario: ScenarioData, threshold_m: float = 1.0,
                    frames: int | None = None, start: int = 0) -> dict[str, Any]:
    """Ground-plane metrics: ``{"median": {...}, "per_node": {"0": {...}, ...}}``."""
    if threshold_m <= 0 or scenario.units_per_metre <= 0:
        raise EvaluationError("threshold_m and the scenario's units_per_metre must be positive")
    nodes = _nodes_of(tracks)
    n = _num_frames(nodes, scenario, frames)
    per = {str(node): summarize(ground_accumulator(nodes[node], scenario, n, threshold_m, start),
                                "ground")
           for node in sorted(nodes)}
    return {"median": median_over(per, GROUND_METRICS), "per_node": per}


def evaluate(tracks: RunTracks, scenario: ScenarioData, *, iou_threshold: float = 0.5,
             ground_threshold_m: float = 1.0, frames: int | None = None,
             views: Sequence[str] = ("image", "ground"), start: int = 0) -> dict[str, Any]:
    """Both views of a run, JSON-able.

    ``{"image": {"median": {...}, "per_node": {"0": {...}}}, "ground": {...},
    "ground_threshold_m": 1.0, "iou_threshold": 0.5, "frames": n}``. ``frames`` defaults to the
    longest node's track list (capped by the ground truth); frames a node has no entry for count
    as frames without tracks. ``start``: evaluate frames ``start..frames-1`` only.
    """
    unknown = set(views) - {"image", "ground"}
    if unknown:
        raise EvaluationError(f"unknown view(s) {sorted(unknown)} (image, ground)")
    nodes = _nodes_of(tracks)
    n = _num_frames(nodes, scenario, frames)
    out: dict[str, Any] = {}
    if "image" in views:
        out["image"] = evaluate_image(nodes, scenario, iou_threshold, n, start=start)
    if "ground" in views:
        out["ground"] = evaluate_ground(nodes, scenario, ground_threshold_m, n, start=start)
    out["ground_threshold_m"] = float(ground_threshold_m)
    out["iou_threshold"] = float(iou_threshold)
    out["frames"] = n
    return out
