"""From a detector box to the measurement ``z = (x, y, w, h)`` and its covariance ``R_i``.

``R_i`` propagates the detector's pixel noise through the image-to-ground homography (its
Jacobian at the foot point: far targets are less certain) and adds ``calib_sigma`` on the ground
position for the per-camera offset that calibration and foot-point error cause (DESIGN.md,
"What real data does": about 0.8 m between cameras on EPFL Terrace). With ``fixed_R`` set, the
paper's constant ``R`` is used instead.
"""
from __future__ import annotations

import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.geometry import Camera


def measure(camera: Camera, box: np.ndarray, cfg: TrackerConfig) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(z, R)`` for one box ``(x, y, w, h)`` px seen by ``camera``."""
    box = np.asarray(box, dtype=float)
    z = camera.box_to_cylinder(box)
    if cfg.fixed_R is not None:
        sxy, swh = (cfg.m(s) for s in cfg.fixed_R)
        return z, np.diag([sxy**2, sxy**2, swh**2, swh**2])
    bx, by, bw, bh = box
    foot = np.array([bx + bw / 2.0, by + bh])
    J = camera.ground_jacobian(foot)
    s2 = cfg.pixel_sigma**2
    R = np.zeros((4, 4))
    # Foot point (u, v): u is the mean of two noisy edges (var s2/2), v one edge (var s2).
    R[:2, :2] = J @ np.diag([s2 / 2.0, s2]) @ J.T + np.eye(2) * cfg.m(cfg.calib_sigma) ** 2
    floor = cfg.m(cfg.size_meas_floor)
    # Width and height are differences of two noisy edges: var 2 s2 in pixels, scaled to ground.
    sw = z[2] / max(bw, 1e-9) * cfg.pixel_sigma * np.sqrt(2.0)
    sh = z[3] / max(bh, 1e-9) * cfg.pixel_sigma * np.sqrt(2.0)
    R[2, 2] = sw**2 + floor**2
    R[3, 3] = sh**2 + floor**2
    return z, R
