"""The shipped, trained SSDLite-MobileNetV2 person detector (``detector = "ssdlite"``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from edge_node.perception import PerceptionError, require_cv2
from edge_node.perception.detectors.base import DETECTORS, Box, nms
from edge_node.perception.options import drop_none, file_option


#: The shipped model: SSDLite-MobileNetV2 trained on VOC07+12 people (MIT; models/PROVENANCE.md).
SSDLITE_MODEL = Path(__file__).resolve().parent.parent / "models" / "ssdlite_person.onnx"
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

    @classmethod
    def options(cls, perception, base: Path, selected: bool) -> dict:
        """``[perception.ssdlite]``, every key optional (:class:`~.base.DetectorKind`)."""
        d = perception.optional_table("ssdlite")
        if d is None:
            return {}
        out = drop_none({
            "model": file_option(d, "model", base, "an ONNX file with the shipped model's outputs"),
            "score_threshold": d.number("score_threshold", None, lo=0, hi=1),
            "nms_threshold": d.number("nms_threshold", None, lo=0, hi=1),
            "tiles": d.integer("tiles", None, lo=1, hi=4),
            "tile_overlap": d.number("tile_overlap", None, lo=0, hi=0.5),
            "backend": d.string("backend", None, choices=SSDLITE_BACKENDS),
            "threads": d.integer("threads", None, lo=1),
        })
        d.finish()
        return out

    @classmethod
    def from_options(cls, options: dict, *, camera=None, units_per_metre: float = 1.0):
        return cls(**options)

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


DETECTORS.add("ssdlite", SsdliteDetector)
