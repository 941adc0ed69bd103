"""A scenario's ``units_per_metre`` checked against the people in it
(``sim_cluster check-scale``; :mod:`edge_node.perception.scale` measures)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from edge_node.perception import scale as measure
from edge_node.perception.scale import ScaleEstimate, estimate_scale
from sim_cluster.scenarios.data import ScenarioData

EVERY = 5  # frames: the boxes of every 5th frame (people move little in 0.2 s)


def scenario_scale(data: ScenarioData, *, use_projection: bool = True,
                   every: int = EVERY) -> ScaleEstimate:
    """The estimate from ``data``'s detection boxes (every ``every``-th frame) and its ground
    truth tracks. ``use_projection=False`` ignores the cameras' ``P`` where known (a synthetic
    world's), as for real cameras known by their homography only."""
    cams = data.cameras if use_projection else [replace(c, P=None) for c in data.cameras]
    boxes = [np.array([d.box for k in range(0, data.frames, every)
                       for d in data.detections[k][c]]).reshape(-1, 4)
             for c in range(data.num_cameras)]
    return estimate_scale(cams, boxes, data.units_per_metre, data.truth.ids, data.truth.xy,
                          data.fps)


def scale_doc() -> str:
    """The help of ``sim_cluster check-scale``: how the estimate is made."""
    return (
        "Estimate the scenario's ground units per metre from the people in it and compare it "
        f"with the declared units_per_metre. Box heights: each camera's homography (with square "
        "pixels and the principal point at the image centre) gives its projection, so the height "
        "of a person standing on a box's foot point with the head at the box's top; the median "
        f"over upright boxes not cut by the image border, over {measure.PERSON_HEIGHT_M} m. "
        "Walking speed: from the ground truth, the median of the faster half of every person's "
        f"one-second steps, over {measure.WALKING_SPEED_MPS} m/s. A WARNING line when the "
        f"declared value is more than {measure.TOLERANCE:.0%} from the box-height estimate (the "
        "walking-speed one without boxes). run and import-detections print the same warning for "
        "det-files folders.")
