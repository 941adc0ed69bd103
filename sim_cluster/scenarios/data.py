"""What a scenario gives the network: cameras, per-frame detections, and the ground truth."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from edge_node.core.types import Detection
from edge_node.geometry import Camera


@dataclass
class GroundTruth:
    """Ground truth of a scenario, frame by frame.

    ``ids[k]`` (n,) int person ids present in the monitored area at frame ``k`` (inside at least one
    camera's field of view), ``xy[k]`` (n, 2) their ground positions, ``wh[k]`` (n, 2) their
    cylinder width and height (ground units). ``boxes[c][k]`` is ``(ids (m,), boxes (m, 4))``:
    the people visible in camera ``c`` at frame ``k`` with their image boxes (the image-plane
    ground truth the paper evaluates against).
    """

    ids: list[np.ndarray]
    xy: list[np.ndarray]
    wh: list[np.ndarray]
    boxes: list[list[tuple[np.ndarray, np.ndarray]]]


@dataclass
class ScenarioData:
    """A fully materialised scenario: everything needed to run and evaluate a network.

    ``detections[k][c]`` are camera ``c``'s detections at frame ``k``; ``detection_truth[k][c]``
    the person id behind each of them (``-1`` for a false positive), for diagnostics only.
    Ground coordinates are in the scenario's own units; ``units_per_metre`` converts (1.0 for the
    synthetic world, about 30 for EPFL Terrace).
    """

    name: str
    cameras: list[Camera]
    frames: int
    fps: float
    units_per_metre: float
    detections: list[list[list[Detection]]]
    truth: GroundTruth
    detection_truth: list[list[np.ndarray]] = field(default_factory=list)
    area: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0)  # xmin, xmax, ymin, ymax
    seed: int = 0

    @property
    def num_cameras(self) -> int:
        return len(self.cameras)

    def has_descriptors(self) -> bool:
        """Whether any detection carries an appearance descriptor (a detector with re-id)."""
        return any(d.descriptor is not None for frame in self.detections for cam in frame
                   for d in cam)

    def without_descriptors(self) -> "ScenarioData":
        """The same detections without appearance: what a detector without re-id gives."""
        return replace(self, detections=[[[replace(d, descriptor=None) for d in cam]
                                          for cam in frame] for frame in self.detections])
