"""A person detector in ONNX format through OpenCV's DNN module (``detector = "onnx"``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from edge_node.perception import PerceptionError, require_cv2
from edge_node.perception.detectors.base import DETECTORS, Box, nms
from edge_node.perception.options import drop_none, file_option, pair_option


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

    @classmethod
    def options(cls, perception, base: Path, selected: bool) -> dict:
        """``[perception.onnx]``; its ``model`` is required when this is the detector."""
        o = perception.optional_table("onnx")
        if o is None:
            if selected:
                raise perception.error("onnx", "is required for detector = \"onnx\" "
                                       "([perception.onnx] model = \"your-detector.onnx\")")
            return {}
        out = drop_none({
            "model": file_option(o, "model", base, "an ONNX person detector", required=selected),
            "input_size": pair_option(o, "input_size", integer=True),
            "score_threshold": o.number("score_threshold", None, lo=0, hi=1),
            "nms_threshold": o.number("nms_threshold", None, lo=0, hi=1),
            "class_id": o.integer("class_id", None, lo=0),
            "layout": o.string("layout", None, choices=ONNX_LAYOUTS),
        })
        o.finish()
        return out

    @classmethod
    def from_options(cls, options: dict, *, camera=None, units_per_metre: float = 1.0):
        if "model" not in options:
            raise PerceptionError("onnx: a model file is required ([perception.onnx] model)")
        opts = dict(options)
        if "input_size" in opts:
            opts["input_size"] = tuple(opts["input_size"])
        return cls(**opts)

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


DETECTORS.add("onnx", OnnxDetector)
