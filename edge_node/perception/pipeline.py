"""Frame -> detections with descriptors, and the runtime source that feeds a node from frames.

:class:`Perception` runs a detector and (optionally) a re-id extractor on one image and returns the
tracker core's :class:`~edge_node.core.types.Detection` objects; it keeps per-stage timings.
:class:`FrameDetections` is what ``edge_node run`` calls for frame ``k`` when ``[source]`` is a
video, an image folder, the EPFL layout or a live camera: it reads frames in order and runs the
perception on each (a frame the node skips is read and dropped, so frame ``k`` is always the
source's ``k``-th frame).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from edge_node.core.types import Detection
from edge_node.perception import PerceptionError
from edge_node.perception.detectors import DETECTORS, Detector
from edge_node.perception.frames import FrameSource, open_frames
from edge_node.perception.reid import REID, ReidExtractor
from edge_node.perception.settings import PerceptionSettings

log = logging.getLogger("edge_node.perception")
UNBOUNDED_FRAMES = 2**31 - 1  # a live camera runs until stopped (or [runtime] frames)


@dataclass
class PerceptionStats:
    frames: int = 0
    boxes: int = 0
    read_s: float = 0.0
    detect_s: float = 0.0
    reid_s: float = 0.0

    def per_frame_ms(self) -> dict:
        n = max(self.frames, 1)
        return {"frames": self.frames, "boxes_per_frame": self.boxes / n,
                "read_ms": 1e3 * self.read_s / n, "detect_ms": 1e3 * self.detect_s / n,
                "reid_ms": 1e3 * self.reid_s / n}


class Perception:
    """``detector`` (+ ``reid``) on one image -> ``[Detection]``; boxes shorter than
    ``min_height_px`` are dropped before re-id.

    ``foot_offset_m`` (needs ``camera``): a box's bottom edge is the person's lowest pixel, the
    nearer foot, which lies closer to the camera than the centre of the body the tracker
    estimates (half a step when walking towards the camera, the foot's width when side-on). The
    bottom edge is raised by the pixels that move its ground point this far away from the camera
    (through the homography's Jacobian); the top stays.
    """

    def __init__(self, detector: Detector, reid: ReidExtractor | None = None,
                 min_height_px: float = 0.0, *, camera=None, units_per_metre: float = 1.0,
                 foot_offset_m: float = 0.0, occluded_overlap: float = 0.3):
        self.detector = detector
        self.reid = reid
        self.min_height_px = float(min_height_px)
        self.camera = camera
        self.foot_offset = float(foot_offset_m) * float(units_per_metre)
        self.occluded_overlap = float(occluded_overlap)
        self.stats = PerceptionStats()

    def _raise_feet(self, b: np.ndarray) -> np.ndarray:
        u, v = b[0] + b[2] / 2.0, b[1] + b[3]
        try:
            J = self.camera.ground_jacobian(np.array([u, v]))
        except (ValueError, np.linalg.LinAlgError):
            return b
        per_px = float(np.hypot(J[0, 1], J[1, 1]))  # ground units per pixel down the image
        if not np.isfinite(per_px) or per_px <= 0:
            return b
        dv = min(self.foot_offset / per_px, 0.25 * b[3])
        return np.array([b[0], b[1], b[2], b[3] - dv])

    def process(self, image: np.ndarray | None) -> list[Detection]:
        if image is None:
            return []
        t0 = time.perf_counter()
        found = [(b, s) for b, s in self.detector.detect(image) if b[3] >= self.min_height_px]
        if self.camera is not None and self.foot_offset > 0:
            found = [(self._raise_feet(np.asarray(b, float)), s) for b, s in found]
        t1 = time.perf_counter()
        boxes = np.array([b for b, _ in found], float).reshape(-1, 4)
        desc = None
        if self.reid is not None and len(boxes):
            keep = np.ones(len(boxes), bool)
            if self.occluded_overlap < 1 and not getattr(self.reid, "handles_overlap", False):
                keep = ~occluded(boxes, self.occluded_overlap)
            desc = np.full((len(boxes), self.reid.dim), np.nan, np.float32)
            if keep.any():
                desc[keep] = self.reid.extract(image, boxes[keep],
                                               getattr(self.detector, "mask", None))
        t2 = time.perf_counter()
        st = self.stats
        st.frames += 1
        st.boxes += len(found)
        st.detect_s += t1 - t0
        st.reid_s += t2 - t1
        out = []
        for i, (b, s) in enumerate(found):
            d = None
            if desc is not None and np.all(np.isfinite(desc[i])):
                d = desc[i]
            out.append(Detection(box=np.asarray(b, float), descriptor=d, score=float(s)))
        return out


def occluded(boxes: np.ndarray, overlap: float) -> np.ndarray:
    """Whether each box ``(n, 4)`` is partly hidden by a nearer one: more than ``overlap`` of
    its area lies inside a box whose bottom edge is lower in the image (people stand on the
    ground: lower feet are nearer). Such a box's pixels mix two people, so its appearance is
    not trusted (no descriptor: the tracker associates it by position alone)."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    n = len(b)
    out = np.zeros(n, bool)
    if n < 2:
        return out
    x0, y0 = b[:, 0], b[:, 1]
    x1, y1 = x0 + b[:, 2], y0 + b[:, 3]
    iw = np.clip(np.minimum(x1[:, None], x1[None]) - np.maximum(x0[:, None], x0[None]), 0, None)
    ih = np.clip(np.minimum(y1[:, None], y1[None]) - np.maximum(y0[:, None], y0[None]), 0, None)
    frac = iw * ih / np.maximum(b[:, 2] * b[:, 3], 1e-9)[:, None]  # [i, j]: part of i inside j
    nearer = y1[None, :] > y1[:, None]
    np.fill_diagonal(frac, 0.0)
    return np.any((frac > overlap) & nearer, axis=1)


@dataclass
class FrameDetections:
    """A node's source fed by frames: the attributes ``edge_node.runtime`` reads of a ``Source``
    (``camera``, ``frames``, ``fps``, ``units_per_metre``, ``description``) and ``source(k)``."""

    camera: object
    frames: int
    fps: float
    units_per_metre: float
    frames_in: FrameSource
    perception: Perception
    description: str = ""
    log_every: int = 250
    timestamps: list = field(default_factory=list)  # (index, timestamp) of the frames processed
    _next: int = 0
    _ended: bool = False

    def __call__(self, k: int) -> list[Detection]:
        st = self.perception.stats
        frame = None
        while not self._ended and self._next <= k:
            t0 = time.perf_counter()
            frame = self.frames_in.read()
            st.read_s += time.perf_counter() - t0
            if frame is None:
                self._ended = True
                log.info("perception: the source ended after %d frames (%s)", self._next,
                         self.summary())
                break
            self._next += 1
            if frame.index != k:
                frame = None  # a frame before k: skipped
        if frame is None:
            return []
        dets = self.perception.process(frame.image)
        if len(self.timestamps) < 100_000:
            self.timestamps.append((frame.index, frame.timestamp))
        if self.log_every and st.frames % self.log_every == 0:
            log.info("perception: %s", self.summary())
        return dets

    def summary(self) -> str:
        s = self.perception.stats.per_frame_ms()
        return (f"{s['frames']} frames, {s['boxes_per_frame']:.1f} boxes/frame; per frame: read "
                f"{s['read_ms']:.1f} ms, detect {s['detect_ms']:.1f} ms, re-id {s['reid_ms']:.1f} ms")

    def close(self) -> None:
        self.frames_in.close()


def build_perception(settings, *, camera=None, units_per_metre: float = 1.0) -> Perception:
    """A :class:`Perception` from ``PerceptionSettings`` (``edge_node.perception.settings``);
    the MOG2 detector gets the camera for its person-size geometry."""
    detector = DETECTORS.get(settings.detector).from_options(
        settings.of(settings.detector), camera=camera, units_per_metre=units_per_metre)
    kind = REID.get(settings.reid)
    reid = kind.from_options(settings.of(kind.table))
    return Perception(detector, reid, settings.min_height_px, camera=camera,
                      units_per_metre=units_per_metre, foot_offset_m=settings.foot_offset_m)


def open_frame_source(cfg) -> FrameDetections:
    """The runtime source of a ``NodeConfig`` whose ``[source]`` is a frame kind. Raises
    :class:`PerceptionError` for anything that cannot be opened or loaded (at start-up)."""
    s = cfg.source
    fps_hint = s.fps if s.fps is not None else (cfg.camera.fps if cfg.camera is not None else None)
    frames_in = open_frames(s.kind, path=s.path, camera=s.camera, sequence=s.sequence,
                            pattern=s.pattern, device=s.device, fps=fps_hint)
    try:
        if cfg.camera is not None:
            camera = cfg.camera.camera(cfg.node)
            upm = cfg.camera.units_per_metre or 1.0
        elif s.kind == "epfl":
            camera = frames_in.camera(cfg.node)
            if camera is None:
                raise PerceptionError(f"{s.path}: no homographies.json for the camera's "
                                      "calibration; give a [camera] table")
            upm = 30.0  # EPFL calibration units (about 30 per metre), as sim_cluster's EPFL scenarios
        else:  # pragma: no cover - the config requires [camera] for the other kinds
            raise PerceptionError(f"source kind {s.kind!r} needs a [camera] table (calibration)")
        W, H = frames_in.image_size
        cw, ch = camera.image_size
        if (W, H) != (cw, ch):
            log.warning("frames are %dx%d but the camera's calibration says %dx%d: boxes are in "
                        "frame pixels; check [camera] image_size / pixel_scale", W, H, cw, ch)
        settings = cfg.perception if cfg.perception is not None else PerceptionSettings()
        perception = build_perception(settings, camera=camera, units_per_metre=upm)
    except Exception:
        frames_in.close()
        raise
    n = frames_in.frames if frames_in.frames is not None else UNBOUNDED_FRAMES
    desc = (f"{frames_in.description} -> {perception.detector.name}"
            f" + {perception.reid.name if perception.reid else 'no re-id'}")
    return FrameDetections(camera, int(n), float(frames_in.fps), float(upm), frames_in,
                           perception, desc, log_every=settings.log_every)
