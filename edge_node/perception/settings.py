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
    detector = "mog2"               # "mog2" | "hog" | "onnx" | "ssdlite" | a plug-in     ["mog2"]
    reid = "histogram"              # "histogram" | "osnet_x1_0" | "osnet_x0_25" | ... | "none"
                                    # (edge_node/plugins.py: DETECTORS, REID)
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

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from edge_node.perception.detectors import DETECTORS
from edge_node.perception.frames import FRAME_KINDS
from edge_node.perception.reid import REID


@dataclass(frozen=True)
class PerceptionSettings:
    """``[perception]`` as read: the detector and re-id kinds by name, and the options each
    ``[perception.<table>]`` table gave (``options["mog2"]``: ``Mog2Detector`` keyword
    arguments; ``options["osnet"]``: weights, batch, threads), tables the config has only."""

    detector: str = "mog2"
    reid: str = "histogram"
    min_height_px: float = 0.0
    log_every: int = 250
    foot_offset_m: float = 0.2
    options: dict[str, dict] = field(default_factory=dict)

    def of(self, table: str | None) -> dict:
        """The options table ``table`` gave (empty when the config has no such table)."""
        return dict(self.options.get(table, {})) if table else {}

    def to_dict(self) -> dict:
        return {"detector": self.detector, "reid": self.reid, "min_height_px": self.min_height_px,
                "log_every": self.log_every, "foot_offset_m": self.foot_offset_m,
                **{k: dict(v) for k, v in self.options.items()}}


def parse_perception(t, base: Path) -> PerceptionSettings:
    """``[perception]`` (an ``edge_node.settings.Table`` or ``None``) -> :class:`PerceptionSettings`.

    Each registered detector and re-id kind reads its own sub-table (:data:`DETECTORS`,
    :data:`REID`): the chosen kind's always (a required key is enforced), the others' when the
    config has them, so a typo in any of them is an error naming the key."""
    if t is None:
        return PerceptionSettings()
    detector = t.string("detector", "mog2", choices=DETECTORS.names())
    reid = t.string("reid", "histogram", choices=REID.names())
    min_h = t.number("min_height_px", 0.0, lo=0)
    log_every = t.integer("log_every", 250, lo=0)
    foot_offset = t.number("foot_offset_m", None, lo=0, hi=1.0)
    options: dict[str, dict] = {}
    for name in DETECTORS.names():
        if name == detector or t.has(name):
            options[name] = DETECTORS.get(name).options(t, base, selected=name == detector)
    chosen = REID.get(reid).table
    for name in REID.names():
        kind = REID.get(name)
        table = kind.table
        if table is None or table in options or not (table == chosen or t.has(table)):
            continue
        owner = REID.get(reid) if table == chosen else kind
        options[table] = owner.options(t, base, selected=table == chosen)
    t.declare(*DETECTORS.names(), *{REID.get(n).table for n in REID.names()} - {None})
    t.finish()
    return PerceptionSettings(detector, reid, float(min_h), int(log_every),
                              0.2 if foot_offset is None else float(foot_offset),
                              {k: v for k, v in options.items() if v})


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
