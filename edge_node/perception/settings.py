"""The ``[perception]`` table of a camera config and the frame-source fields of ``[source]``
(read by :mod:`edge_node.runtime.config`; pure Python, imports neither OpenCV nor torch).

Schema (defaults in brackets)::

    [source]
    kind = "video"                  # "video" | "images" | "epfl" | "camera"
    path = "cam0.avi"               # video: the file; images / epfl: the folder
    # camera = 0                    # epfl: camera index c<i>                              [node]
    # sequence = "terrace1"         # epfl: the files' prefix (terrace1-c0.avi ...)
    # pattern = "*.png"             # images: a glob                      [every image extension]
    # device = 0                    # camera: OpenCV device index, or a stream URL           [0]
    # fps = 25.0                    # images / camera (a video has its own)         [[camera] fps]

    [perception]
    detector = "mog2"               # "mog2" | "hog" | "onnx" | "ssdlite"                 ["mog2"]
    reid = "histogram"              # "histogram" | "osnet_x1_0" | "osnet_x0_25" | ... | "none"
    min_height_px = 0               # drop boxes shorter than this                           [0]
    foot_offset_m = 0.2             # raise each box's bottom so its ground point moves this far
                                    # from the camera (the lowest pixel is the nearer foot) [0.2]
    log_every = 250                 # log perception timings every N frames (0 = only at the end)

    [perception.mog2]               # every key optional
    background = "empty.avi"        # a video (or image) of the empty scene to start from
    history = 500                   # MOG2 history (frames)
    var_threshold = 16.0            # MOG2 variance threshold
    learning_rate = -1.0            # -1: MOG2's automatic 1/history; else in [0, 1]
    min_area = 60                   # px, smallest foreground area kept as a person
    min_height = 12                 # px
    open_px = 3                     # morphological opening (noise) kernel, 0 = off
    close_px = 5                    # morphological closing (holes) kernel, 0 = off
    split = true                    # split blobs wider than one person (camera geometry)
    person_size_m = [0.5, 1.75]     # the person the geometry expects (width, height)

    [perception.hog]                # every key optional
    upscale = 2.0                   # people must be ~100 px tall for the 64x128 window
    win_stride = 8
    scale = 1.05
    hit_threshold = 0.0
    nms_threshold = 0.4

    [perception.onnx]
    model = "yolov8n.onnx"          # required for detector = "onnx"; checked at start-up
    input_size = [640, 640]         # network input width, height
    score_threshold = 0.5
    nms_threshold = 0.45
    class_id = 0                    # the person class (COCO: 0)
    layout = "auto"                 # "auto" | "yolov8" | "yolov5" | "xyxy"

    [perception.ssdlite]            # every key optional: the trained detector shipped here
    score_threshold = 0.3           # smallest score kept                                  [0.3]
    tiles = 1                       # 1: the whole frame; n: plus n x n overlapping tiles (small
                                    # people; n * n + 1 network passes)                      [1]
    tile_overlap = 0.2              # overlap of neighbouring tiles, fraction of a tile       [0.2]
    nms_threshold = 0.45            # IoU merging the boxes of the frame and its tiles       [0.45]
    backend = "auto"                # "opencv" (cv2.dnn) | "onnxruntime" | "auto": onnxruntime
                                    # where installed (vision extra), else opencv      ["auto"]
    threads = 1                     # the backend's threads                   [the backend's own]
    model = "other.onnx"            # another file with the same four outputs [the shipped one]

    [perception.osnet]
    weights = "osnet_x0_25_msmt17.pth"  # required for reid = "osnet_*": a torchreid checkpoint
    batch = 32                      # boxes per forward pass
    threads = 1                     # torch threads (default: torch's)

A frame source needs the camera's calibration: ``[camera]`` (homography, image size...), or for
``kind = "epfl"`` a ``homographies.json`` in the folder.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from edge_node.perception.detectors import DETECTOR_KINDS, ONNX_LAYOUTS, SSDLITE_BACKENDS
from edge_node.perception.frames import FRAME_KINDS
from edge_node.perception.reid import REID_KINDS


@dataclass(frozen=True)
class PerceptionSettings:
    detector: str = "mog2"
    reid: str = "histogram"
    min_height_px: float = 0.0
    log_every: int = 250
    foot_offset_m: float = 0.2
    mog2: dict = field(default_factory=dict)  # Mog2Detector keyword arguments
    hog: dict = field(default_factory=dict)  # HogDetector keyword arguments
    onnx: dict = field(default_factory=dict)  # OnnxDetector keyword arguments
    osnet: dict = field(default_factory=dict)  # OsnetReid: weights, batch, threads
    ssdlite: dict = field(default_factory=dict)  # SsdliteDetector keyword arguments

    def to_dict(self) -> dict:
        return {"detector": self.detector, "reid": self.reid, "min_height_px": self.min_height_px,
                "log_every": self.log_every, "foot_offset_m": self.foot_offset_m, "mog2": dict(self.mog2), "hog": dict(self.hog),
                "onnx": dict(self.onnx), "ssdlite": dict(self.ssdlite),
                "osnet": dict(self.osnet)}


def _file(t, key: str, base: Path, what: str, required: bool = False) -> str | None:
    p = t.path(key, base, None)
    if p is None:
        if required:
            raise t.error(key, f"is required ({what})")
        return None
    if not p.is_file():
        raise t.error(key, f"names a file that does not exist: {p} ({what})")
    return str(p)


def _pair(t, key: str, integer: bool) -> list | None:
    if not t.has(key):
        t.raw(key, None)
        return None
    v = t.raw(key)
    ok = isinstance(v, list) and len(v) == 2 and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0
        and (not integer or isinstance(x, int)) and math.isfinite(x) for x in v)
    if not ok:
        raise t.error(key, f"must be two positive {'integers' if integer else 'numbers'}, got {v!r}")
    return list(v)


def _drop_none(d: dict) -> dict:
    return {k: v for k, v in d.items() if v is not None}


def parse_perception(t, base: Path) -> PerceptionSettings:
    """``[perception]`` (an ``edge_node.settings.Table`` or ``None``) -> :class:`PerceptionSettings`."""
    if t is None:
        return PerceptionSettings()
    detector = t.string("detector", "mog2", choices=DETECTOR_KINDS)
    reid = t.string("reid", "histogram", choices=REID_KINDS)
    min_h = t.number("min_height_px", 0.0, lo=0)
    log_every = t.integer("log_every", 250, lo=0)
    foot_offset = t.number("foot_offset_m", None, lo=0, hi=1.0)

    m = t.optional_table("mog2")
    mog2: dict[str, Any] = {}
    if m is not None:
        mog2 = _drop_none({
            "background": _file(m, "background", base, "a video or image of the empty scene"),
            "history": m.integer("history", None, lo=1),
            "var_threshold": m.number("var_threshold", None, lo=0, lo_open=True),
            "learning_rate": m.number("learning_rate", None, lo=-1, hi=1),
            "min_area": m.integer("min_area", None, lo=1),
            "min_height": m.integer("min_height", None, lo=0),
            "open_px": m.integer("open_px", None, lo=0),
            "close_px": m.integer("close_px", None, lo=0),
            "split": m.boolean("split", None) if m.has("split") else None,
            "person_size_m": _pair(m, "person_size_m", integer=False),
        })
        m.finish()

    h = t.optional_table("hog")
    hog: dict[str, Any] = {}
    if h is not None:
        hog = _drop_none({
            "upscale": h.number("upscale", None, lo=0, lo_open=True),
            "win_stride": h.integer("win_stride", None, lo=1),
            "padding": h.integer("padding", None, lo=0),
            "scale": h.number("scale", None, lo=1, lo_open=True),
            "hit_threshold": h.number("hit_threshold", None),
            "nms_threshold": h.number("nms_threshold", None, lo=0, hi=1),
            "min_score": h.number("min_score", None),
        })
        h.finish()

    o = t.optional_table("onnx")
    onnx: dict[str, Any] = {}
    if o is not None:
        onnx = _drop_none({
            "model": _file(o, "model", base, "an ONNX person detector",
                           required=detector == "onnx"),
            "input_size": _pair(o, "input_size", integer=True),
            "score_threshold": o.number("score_threshold", None, lo=0, hi=1),
            "nms_threshold": o.number("nms_threshold", None, lo=0, hi=1),
            "class_id": o.integer("class_id", None, lo=0),
            "layout": o.string("layout", None, choices=ONNX_LAYOUTS),
        })
        o.finish()
    elif detector == "onnx":
        raise t.error("onnx", "is required for detector = \"onnx\" ([perception.onnx] model = "
                      "\"your-detector.onnx\")")

    d = t.optional_table("ssdlite")
    ssdlite: dict[str, Any] = {}
    if d is not None:
        ssdlite = _drop_none({
            "model": _file(d, "model", base, "an ONNX file with the shipped model's outputs"),
            "score_threshold": d.number("score_threshold", None, lo=0, hi=1),
            "nms_threshold": d.number("nms_threshold", None, lo=0, hi=1),
            "tiles": d.integer("tiles", None, lo=1, hi=4),
            "tile_overlap": d.number("tile_overlap", None, lo=0, hi=0.5),
            "backend": d.string("backend", None, choices=SSDLITE_BACKENDS),
            "threads": d.integer("threads", None, lo=1),
        })
        d.finish()

    s = t.optional_table("osnet")
    osnet: dict[str, Any] = {}
    if s is not None:
        osnet = _drop_none({
            "weights": _file(s, "weights", base, "a torchreid OSNet checkpoint",
                             required=reid.startswith("osnet_")),
            "batch": s.integer("batch", None, lo=1),
            "threads": s.integer("threads", None, lo=1),
        })
        s.finish()
    elif reid.startswith("osnet_"):
        raise t.error("osnet", f"is required for reid = {reid!r} ([perception.osnet] weights = "
                      "\"...pth\", a torchreid checkpoint; see docs/perception.md)")
    t.finish()
    return PerceptionSettings(detector, reid, float(min_h), int(log_every),
                              0.2 if foot_offset is None else float(foot_offset),
                              mog2, hog, onnx, osnet, ssdlite)


def parse_frame_source(t, kind: str, base: Path) -> dict:
    """The frame-source fields of ``[source]`` (``kind`` in ``FRAME_KINDS``) as keyword values
    for ``SourceSettings``; ``t.finish()`` is the caller's."""
    assert kind in FRAME_KINDS
    out: dict[str, Any] = {}
    if kind == "camera":
        dev = t.raw("device", 0)
        if isinstance(dev, bool) or not isinstance(dev, (int, str)) or (
                isinstance(dev, int) and dev < 0) or dev == "":
            raise t.error("device", f"must be a device index (>= 0) or a stream URL, got {dev!r}")
        out["device"] = dev
    else:
        p = t.path("path", base)
        if kind == "video" and not p.is_file():
            raise t.error("path", f"names a video file that does not exist: {p}")
        if kind in ("images", "epfl") and not p.is_dir():
            raise t.error("path", f"names a folder that does not exist: {p}")
        out["path"] = p
    if kind == "epfl":
        seq = t.string("sequence")
        if not seq:
            raise t.error("sequence", "must be a sequence name like terrace1")
        out["sequence"] = seq
    if kind == "images":
        out["pattern"] = t.string("pattern", None)
    out["fps"] = t.number("fps", None, lo=0, lo_open=True)
    return out
