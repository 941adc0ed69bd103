"""OpenCV's HOG + linear SVM people detector (``detector = "hog"``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from edge_node.perception import PerceptionError, require_cv2
from edge_node.perception.detectors.base import DETECTORS, Box, nms
from edge_node.perception.options import drop_none


def hog_available() -> bool:
    """Whether this OpenCV has the HOG people detector (OpenCV 4.x, or opencv-contrib 5.x)."""
    try:
        cv2 = require_cv2()
    except PerceptionError:
        return False
    return hasattr(cv2, "HOGDescriptor")


class HogDetector:
    """OpenCV's default HOG people detector on an upscaled image, boxes tightened to the person."""

    name = "hog"

    def __init__(self, *, upscale: float = 2.0, win_stride: int = 8, padding: int = 8,
                 scale: float = 1.05, hit_threshold: float = 0.0, nms_threshold: float = 0.4,
                 min_score: float = 0.0, tighten: bool = True):
        cv2 = require_cv2()
        if not hasattr(cv2, "HOGDescriptor"):
            raise PerceptionError(
                f"this OpenCV ({cv2.__version__}) has no HOG people detector: OpenCV 5 moved it to "
                "opencv-contrib (pip install opencv-contrib-python-headless in place of "
                "opencv-python-headless, or OpenCV 4.x); or use detector = \"mog2\" / \"onnx\"")
        if upscale <= 0 or scale <= 1 or win_stride < 1:
            raise PerceptionError("hog: upscale > 0, scale > 1 and win_stride >= 1 are required")
        self.cv2 = cv2
        self.hog = cv2.HOGDescriptor()
        getter = getattr(cv2.HOGDescriptor, "getDefaultPeopleDetector", None) or getattr(
            cv2, "HOGDescriptor_getDefaultPeopleDetector")
        self.hog.setSVMDetector(getter())
        self.upscale = float(upscale)
        self.win_stride = int(win_stride)
        self.padding = int(padding)
        self.scale = float(scale)
        self.hit_threshold = float(hit_threshold)
        self.nms_threshold = float(nms_threshold)
        self.min_score = float(min_score)
        self.tighten = bool(tighten)

    @classmethod
    def options(cls, perception, base: Path, selected: bool) -> dict:
        """``[perception.hog]``, every key optional (:class:`~.base.DetectorKind`)."""
        h = perception.optional_table("hog")
        if h is None:
            return {}
        out = drop_none({
            "upscale": h.number("upscale", None, lo=0, lo_open=True),
            "win_stride": h.integer("win_stride", None, lo=1),
            "padding": h.integer("padding", None, lo=0),
            "scale": h.number("scale", None, lo=1, lo_open=True),
            "hit_threshold": h.number("hit_threshold", None),
            "nms_threshold": h.number("nms_threshold", None, lo=0, hi=1),
            "min_score": h.number("min_score", None),
        })
        h.finish()
        return out

    @classmethod
    def from_options(cls, options: dict, *, camera=None, units_per_metre: float = 1.0):
        return cls(**options)

    def detect(self, image: np.ndarray) -> list[Box]:
        cv2 = self.cv2
        img = image
        if self.upscale != 1.0:
            img = cv2.resize(image, None, fx=self.upscale, fy=self.upscale,
                             interpolation=cv2.INTER_LINEAR)
        rects, weights = self.hog.detectMultiScale(
            img, hitThreshold=self.hit_threshold, winStride=(self.win_stride, self.win_stride),
            padding=(self.padding, self.padding), scale=self.scale)
        if len(rects) == 0:
            return []
        b = np.asarray(rects, float).reshape(-1, 4) / self.upscale
        s = np.asarray(weights, float).ravel()
        if self.tighten:  # the 64x128 training window: person 96 px tall, ~32-40 px wide
            b = np.stack([b[:, 0] + 0.2 * b[:, 2], b[:, 1] + 0.125 * b[:, 3],
                          0.6 * b[:, 2], 0.75 * b[:, 3]], axis=1)
        ok = s >= self.min_score
        b, s = b[ok], s[ok]
        keep = nms(b, s, self.nms_threshold)
        return [(b[i], float(s[i])) for i in keep]


DETECTORS.add("hog", HogDetector)
