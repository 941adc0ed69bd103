"""The measurer role: one camera's detections as measurements ``z, R`` on the ground (paper
III-A, the cylinder model through the camera's homography, ``measurement``), corrected by the
camera's learned registration when the node registers its cameras (``registration``). Boxes
that cannot be measured (NaN, inf, a size that is not positive) are counted, not measured.
Pure and deterministic."""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from edge_node.core.association import Observations
from edge_node.core.measurement import BoxMeasurements, box_measurements, fixed_R, uncorrected_many
from edge_node.core.registration import Registration
from edge_node.core.types import Detection
from edge_node.geometry import Camera


class Measurer:
    """``measurement``: the configuration's measurement parameters; ``cameras``: the node's;
    ``registrations``: its registrations (camera id -> ``Registration``; empty: none);
    ``descriptor``: how the node keeps a detection's descriptor (the association's; None
    drops it); ``stats``: the node's counters (``bad_detections``)."""

    def __init__(self, measurement, cameras: Sequence[Camera],
                 registrations: Mapping[int, Registration], descriptor, stats):
        self.cfg = measurement
        self.cameras = list(cameras)
        self.registrations = registrations
        self.descriptor = descriptor
        self.stats = stats

    def split(self, node: int, detections) -> dict[int, Sequence[Detection]]:
        """A frame's detections per camera: a mapping camera id -> detections, or, for a node
        of one camera, its detections."""
        if isinstance(detections, Mapping):
            unknown = set(detections) - {c.id for c in self.cameras}
            if unknown:
                raise ValueError(f"node {node}: detections for unknown camera(s) {sorted(unknown)}")
            return dict(detections)
        if len(self.cameras) != 1:
            raise ValueError(f"node {node} owns {len(self.cameras)} cameras: "
                             "pass detections as {camera_id: [...]}")
        return {self.cameras[0].id: detections}

    def usable(self, dets: Sequence[Detection]) -> tuple[list[Detection], np.ndarray]:
        """Detections with a finite box of positive size and their boxes ``(n, 4)``."""
        if not dets:
            return [], np.zeros((0, 4))
        try:  # every box four numbers (the common case): one call
            B = np.array([d.box for d in dets], float)
        except (ValueError, TypeError):
            B = None
        if B is None or B.shape != (len(dets), 4):  # box by box: a wrong shape is not usable
            boxes = [np.asarray(d.box, float) for d in dets]
            B = np.array([b if b.shape == (4,) else np.full(4, np.nan) for b in boxes])
        with np.errstate(invalid="ignore"):
            good = np.isfinite(B).all(axis=1) & (B[:, 2] > 0) & (B[:, 3] > 0)
        bad = len(B) - int(np.count_nonzero(good))
        if not bad:
            return list(dets), B
        self.stats.bad_detections += bad
        return [d for d, g in zip(dets, good) if g], B[good]

    def __call__(self, cam: Camera, dets: Sequence[Detection]
                 ) -> tuple[Observations, BoxMeasurements | None]:
        """One camera's frame: its observations (``z, R``, descriptors; an observation's
        ``raw`` is its row of the box measurements) and the box measurements themselves
        (registration residuals, box sizes; None without a usable box)."""
        good, boxes = self.usable(dets)
        if not good:
            return Observations(np.zeros((0, 4)), np.zeros((0, 4, 4)), []), None
        cfg = self.cfg
        raws = box_measurements(cam, boxes, cfg)
        descs = [self.descriptor(d.descriptor) for d in good]
        reg = self.registrations.get(cam.id)
        if reg is None:
            z, R = uncorrected_many(raws, cfg)
        else:
            z, R = reg.corrects(raws)
            if cfg.fixed_R is not None:
                R = np.broadcast_to(fixed_R(cfg), R.shape).copy()
        return Observations(z, R, descs), raws
