"""From a detector box to the measurement ``z = (x, y, w, h)`` and its covariance ``R_i``.

``R_i`` propagates the detector's pixel noise through the image-to-ground homography (its
Jacobian at the foot point: far targets are less certain). What the pixel noise does not cover
is the camera's registration error (calibration, and where on the person the box's bottom edge
lands): with online registration (``edge_node.core.registration``) it is estimated and corrected
and only its remaining uncertainty is added; without it, ``calib_sigma`` is added on the ground
position (docs/concepts.md, registration: about 0.8 m between cameras on EPFL Terrace). With
``fixed_R`` set, the paper's constant ``R`` is used instead.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.stacks import Columns
from edge_node.geometry import Camera, norms


@dataclass(frozen=True)
class MeasurerSettings(Slice):
    """What the measurement model reads; each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    pixel_sigma: float
    calib_sigma: float
    size_meas_floor: float
    border_px: float
    fixed_R: tuple[float, float] | None
    units_per_metre: float
    fps: float


@dataclass(eq=False, slots=True)
class BoxMeasurement:
    """One box as its camera measures it, before any registration correction (read only, not
    frozen: see ``association.Candidate``).

    ``z`` the cylinder ``(x, y, w, h)`` through the camera's homography; ``R`` its covariance from
    the pixel noise alone; ``foot`` the box's bottom centre (px); ``away`` the unit ground
    direction in which the foot point moves when it goes up the image (away from the camera):
    the direction of the foot-point offset along the viewing ray.
    """

    z: np.ndarray
    R: np.ndarray
    foot: np.ndarray
    away: np.ndarray
    size: np.ndarray  # (w, h) of the box in px over px-per-ground-unit at the foot point
    cut: bool = False  # the image border cuts the box: no use for registration


class BoxMeasurements(Columns):
    """One camera frame's box measurements as arrays, one row per box: what
    :func:`box_measurements` computes for all boxes at once, kept stacked so that the
    registration (R5, R2) and the association read the columns without splitting them into
    rows and stacking them again (stacking twenty small arrays costs about 40 k instructions,
    as much as the arithmetic on them). ``[i]`` is row ``i`` as a :class:`BoxMeasurement`."""

    __slots__ = ("z", "R", "foot", "away", "size", "cut")

    def __init__(self, z: np.ndarray, R: np.ndarray, foot: np.ndarray, away: np.ndarray,
                 size: np.ndarray, cut: np.ndarray):
        self.z, self.R, self.foot, self.away, self.size = z, R, foot, away, size  # (n, ...)
        self.cut = cut  # (n,) bool

    @classmethod
    def of(cls, ms: "BoxMeasurements | Sequence[BoxMeasurement]") -> "BoxMeasurements":
        """``ms`` itself, or a list of rows stacked."""
        if isinstance(ms, BoxMeasurements):
            return ms
        return cls(np.array([m.z for m in ms]), np.array([m.R for m in ms]),
                   np.array([m.foot for m in ms]), np.array([m.away for m in ms]),
                   np.array([m.size for m in ms]), np.array([m.cut for m in ms], bool))

    def _row(self, i: int) -> BoxMeasurement:
        return BoxMeasurement(self.z[i], self.R[i], self.foot[i], self.away[i], self.size[i],
                              bool(self.cut[i]))

    def take(self, rows: np.ndarray | Sequence[int]) -> "BoxMeasurements":
        """The rows ``rows`` (row numbers; copies)."""
        at = np.asarray(rows, np.intp)  # (rows by take: see stacks)
        return BoxMeasurements(*(a.take(at, axis=0) for a in (self.z, self.R, self.foot, self.away,
                                                              self.size, self.cut)))


def pixels_per_unit(J: np.ndarray) -> np.ndarray | float:
    """Pixels per ground unit along the image's horizontal axis (``J``: ground per pixel, one
    ``(2, 2)`` or a stack ``(n, 2, 2)``)."""
    out = 1.0 / np.maximum(norms(J[..., :, 0]), 1e-12)
    return float(out) if np.ndim(out) == 0 else out


def away_direction(J: np.ndarray) -> np.ndarray:
    """Unit ground direction of moving up the image at a point with ground Jacobian ``J``
    (one ``(2, 2)`` or a stack ``(n, 2, 2)``)."""
    d = -J[..., :, 1]
    return d / np.maximum(norms(d), 1e-12)[..., None]


def box_measurement(camera: Camera, box: np.ndarray, cfg: MeasurerSettings) -> BoxMeasurement:
    """``z`` and the pixel-noise ``R`` of one box ``(x, y, w, h)`` px seen by ``camera``."""
    return box_measurements(camera, np.asarray(box, float)[None], cfg)[0]


def box_measurements(camera: Camera, boxes: np.ndarray, cfg: MeasurerSettings) -> BoxMeasurements:
    """:func:`box_measurement` of ``(n, 4)`` boxes, computed for all of them at once."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    if not len(boxes):
        return BoxMeasurements(np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros((0, 2)),
                               np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool))
    z = camera.boxes_to_cylinders(boxes)
    bx, by, bw, bh = boxes.T
    foot = np.empty((len(boxes), 2))  # the boxes' bottom centres
    foot[:, 0] = bx + bw / 2.0
    foot[:, 1] = by + bh
    J = camera.ground_jacobians(foot)
    s2 = cfg.pixel_sigma**2
    # Foot point (u, v): u is the mean of two noisy edges (var s2/2), v one edge (var s2).
    # A box cut by the image border does not show where the person stands: the cut side's
    # edge is the border, not the person's (var of a uniform offset over the hidden part).
    W, H = camera.image_size
    cut = cfg.border_px
    var_u = s2 / 2.0 + np.where((bx <= cut) | (bx + bw >= W - cut), bw**2 / 3.0, 0.0)
    var_v = s2 + np.where(by + bh >= H - cut, (0.5 * bh) ** 2 / 3.0, 0.0)
    var = np.empty((len(boxes), 1, 2))
    var[:, 0, 0], var[:, 0, 1] = var_u, var_v
    R = np.zeros((len(boxes), 4, 4))
    R[:, :2, :2] = (J * var) @ J.transpose(0, 2, 1)
    floor = cfg.m(cfg.size_meas_floor)
    # Width and height are differences of two noisy edges: var 2 s2 in pixels, scaled to ground.
    sw = z[:, 2] / np.maximum(bw, 1e-9) * cfg.pixel_sigma * np.sqrt(2.0)
    sh = z[:, 3] / np.maximum(bh, 1e-9) * cfg.pixel_sigma * np.sqrt(2.0)
    R[:, 2, 2] = sw**2 + floor**2
    R[:, 3, 3] = sh**2 + floor**2
    size = boxes[:, 2:] / pixels_per_unit(J)[:, None]
    away = away_direction(J)
    cuts = (var_u > s2) | (var_v > s2)
    return BoxMeasurements(z, R, foot, away, size, cuts)


def fixed_R(cfg: MeasurerSettings) -> np.ndarray:
    """The paper's constant ``R`` (``cfg.fixed_R`` = sigmas of position and size, metres)."""
    sxy, swh = (cfg.m(s) for s in cfg.fixed_R)
    return np.diag([sxy**2, sxy**2, swh**2, swh**2])


def uncorrected(m: BoxMeasurement, cfg: MeasurerSettings) -> tuple[np.ndarray, np.ndarray]:
    """``(z, R)`` of a box measurement without registration: ``calib_sigma`` on the position
    (or the paper's fixed ``R``)."""
    return m.z, uncorrected_many(BoxMeasurements.of([m]), cfg)[1][0]


def uncorrected_many(ms: BoxMeasurements, cfg: MeasurerSettings) -> tuple[np.ndarray, np.ndarray]:
    """:func:`uncorrected` of a frame's measurements: ``z`` ``(n, 4)`` and ``R`` ``(n, 4, 4)``."""
    if cfg.fixed_R is not None:
        return ms.z, np.broadcast_to(fixed_R(cfg), ms.R.shape).copy()
    R = ms.R.copy()
    R[:, :2, :2] = R[:, :2, :2] + np.eye(2) * cfg.m(cfg.calib_sigma) ** 2
    return ms.z, R


def measure(camera: Camera, box: np.ndarray, cfg: MeasurerSettings) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(z, R)`` for one box without registration: ``calib_sigma`` on the position."""
    return uncorrected(box_measurement(camera, box, cfg), cfg)
