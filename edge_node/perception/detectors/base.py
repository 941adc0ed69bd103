"""The detectors' one interface (:class:`Detector`), what makes one from a config
(:class:`DetectorKind`), the registry of kinds (:data:`DETECTORS`) and what they share
(non-maximum suppression)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from edge_node.perception import PerceptionError
from edge_node.plugins import Registry

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


class DetectorKind(Protocol):
    """What a ``detector = "<name>"`` needs: read its own ``[perception.<name>]`` table, and
    build the detector from what it read. The built-in kinds are the detector classes
    themselves (two class methods beside ``__init__``); a plug-in registers any such object in
    the entry-point group ``dmtt.detectors``."""

    def options(self, perception: Any, base: Path, selected: bool) -> dict[str, Any]:
        """The kind's keyword options from ``perception.optional_table("<name>")`` (an
        ``edge_node.settings.Table``; relative paths against ``base``), validated, with the
        table finished; ``selected``: this kind is the configured detector (a required key may
        then be enforced)."""

    def from_options(self, options: dict[str, Any], *, camera: Any,
                     units_per_metre: float) -> Detector:
        """The detector; ``camera`` (``edge_node.geometry.Camera`` or ``None``) and
        ``units_per_metre`` for detectors that read boxes with the camera's geometry."""


#: The detector kinds by name (``[perception] detector``; ``sim_cluster up --detector``).
DETECTORS: Registry[DetectorKind] = Registry("detector", "dmtt.detectors", PerceptionError)
