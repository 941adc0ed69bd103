"""Ground units per metre from the people in the data (``sim_cluster check-scale``).

Every length parameter of the tracker is in metres and converted by ``units_per_metre``, the
scale of the homographies' ground units; a wrong value (a calibration in centimetres declared as
metres) silently changes every gate. People are the ruler the data always holds:

**Box heights.** A homography maps the ground plane only, but with the usual camera assumptions
(square pixels, no skew, principal point at the image centre) it fixes the focal length
(Zhang's two constraints on a plane's homography, solved for ``1/f^2`` by least squares), and
so the whole projection ``P = K [r1 r2 r1xr2 t]`` in ground units. The height of an upright
person standing on a box's foot point is then the height whose top projects on the box's top
edge (``Camera.boxes_to_cylinders`` with that ``P``). Boxes cut by the image border or not
upright (height under 1.5 widths) are left out; the median height over the rest, divided by
an average person's :data:`PERSON_HEIGHT_M` (1.7 m), is the estimate. Detector boxes carry some
slack, so it tends to read a little high.

**Walking speed.** From ground tracks (the ground truth), each person's displacement over one
second; people stand as well as walk, so the speeds of the faster half (above the median) are
taken as walking, and their median divided by :data:`WALKING_SPEED_MPS` (1.3 m/s) is a second
estimate, coarser than the first (people walk 0.8-1.7 m/s).

A declared value more than :data:`TOLERANCE` (20 %) away from the estimate is reported.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from edge_node.geometry import Camera

PERSON_HEIGHT_M = 1.7
WALKING_SPEED_MPS = 1.3
TOLERANCE = 0.2
BORDER_PX = 2.0  # a box this close to the image border is cut by it
MIN_ASPECT = 1.5  # an upright person's box is at least this many widths high
MIN_BOXES = 20  # fewer usable boxes than this: no estimate from a camera


def projection_from_homography(camera: Camera) -> np.ndarray | None:
    """The 3x4 projection ``P`` (ground units, z up, to pixels) that ``camera``'s homography
    implies for a pinhole with square pixels, no skew and the principal point at the image
    centre; None when the homography does not determine a focal length (a camera looking
    straight down, or no positive solution)."""
    W, H = camera.image_size
    s = camera.pixel_scale
    to_ground = camera.G @ np.diag([s, s, 1.0])  # pixels -> ground
    M = np.linalg.inv(to_ground)  # ground -> pixels
    T = np.array([[1.0, 0.0, -W / 2.0], [0.0, 1.0, -H / 2.0], [0.0, 0.0, 1.0]])
    m1, m2, m3 = (T @ M).T
    # r1 . r2 = 0 and |r1| = |r2| with r_i ~ K^-1 m_i, K = diag(f, f, 1): linear in x = 1/f^2
    a = np.array([m1[0] * m2[0] + m1[1] * m2[1], m1[0] ** 2 + m1[1] ** 2 - m2[0] ** 2 - m2[1] ** 2])
    b = np.array([m1[2] * m2[2], m1[2] ** 2 - m2[2] ** 2])
    den = float(a @ a)
    if den <= 0:
        return None
    x = -float(a @ b) / den
    if not np.isfinite(x) or x <= 0:
        return None
    f = 1.0 / np.sqrt(x)
    Kinv = np.diag([1.0 / f, 1.0 / f, 1.0])
    c1, c2, c3 = Kinv @ m1, Kinv @ m2, Kinv @ m3
    lam = (np.linalg.norm(c1) + np.linalg.norm(c2)) / 2.0
    r1, r2, t = c1 / np.linalg.norm(c1), c2 / np.linalg.norm(c2), c3 / lam
    # sign: the ground point seen at the bottom centre of the image is in front (depth > 0)
    g = to_ground @ np.array([W / 2.0, H - 1.0, 1.0])
    g = g[:2] / g[2]
    if (r1 * g[0] + r2 * g[1] + t)[2] < 0:
        r1, r2, t = -r1, -r2, -t
    r3 = np.cross(r1, r2)
    K = np.array([[f, 0.0, W / 2.0], [0.0, f, H / 2.0], [0.0, 0.0, 1.0]])
    P = K @ np.column_stack([r1, r2, r3, t])
    # up is where a head is: above the feet in the image (a smaller row)
    foot, head = P @ np.array([g[0], g[1], 0.0, 1.0]), P @ np.array([g[0], g[1], 1e-3, 1.0])
    if head[1] / head[2] > foot[1] / foot[2]:
        P = K @ np.column_stack([r1, r2, -r3, t])
    return P


def upright(camera: Camera, boxes: np.ndarray) -> np.ndarray:
    """Which boxes ``(n, 4)`` show a whole upright person: inside the image (not cut by its
    border) and at least :data:`MIN_ASPECT` widths high."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    W, H = camera.image_size
    return ((b[:, 0] > BORDER_PX) & (b[:, 1] > BORDER_PX) & (b[:, 0] + b[:, 2] < W - BORDER_PX)
            & (b[:, 1] + b[:, 3] < H - BORDER_PX) & (b[:, 2] > 0)
            & (b[:, 3] >= MIN_ASPECT * b[:, 2]))


def box_heights(camera: Camera, boxes: np.ndarray, P: np.ndarray | None = None) -> np.ndarray:
    """Heights in ground units of the upright people in ``boxes`` (:func:`upright`) standing on
    their foot points, through ``P`` (default: the camera's own, else
    :func:`projection_from_homography`); empty when there is no projection."""
    P = P if P is not None else (camera.P if camera.P is not None
                                 else projection_from_homography(camera))
    b = np.asarray(boxes, float).reshape(-1, 4)
    b = b[upright(camera, b)]
    if P is None or not len(b):
        return np.zeros(0)
    h = replace(camera, P=P).boxes_to_cylinders(b)[:, 3]
    return h[np.isfinite(h) & (h > 0)]


def walking_speeds(ids: Sequence[np.ndarray], xy: Sequence[np.ndarray], fps: float
                   ) -> np.ndarray:
    """Each person's ground displacement over one second (frames ``k`` and ``k + fps``, where
    present at both), in ground units per second."""
    step = max(int(round(fps)), 1)
    out = []
    for k in range(len(ids) - step):
        a, b = np.asarray(ids[k]).ravel(), np.asarray(ids[k + step]).ravel()
        common, ia, ib = np.intersect1d(a, b, return_indices=True)
        if len(common):
            d = np.asarray(xy[k + step]).reshape(-1, 2)[ib] - np.asarray(xy[k]).reshape(-1, 2)[ia]
            out.append(np.linalg.norm(d, axis=1) * fps / step)
    return np.concatenate(out) if out else np.zeros(0)


@dataclass
class ScaleEstimate:
    """Units per metre from the people in the data (module docstring), against ``declared``."""

    declared: float
    from_heights: float | None = None
    boxes: int = 0
    per_camera: list[float | None] = field(default_factory=list)
    from_speed: float | None = None
    steps: int = 0

    @property
    def estimate(self) -> float | None:
        """From box heights when there are any, else from walking speed."""
        return self.from_heights if self.from_heights is not None else self.from_speed

    @property
    def ratio(self) -> float | None:
        """``declared / estimate`` (1.0: they agree)."""
        return None if self.estimate is None else self.declared / self.estimate

    @property
    def disagrees(self) -> bool:
        """The declared value is more than :data:`TOLERANCE` away from the estimate."""
        r = self.ratio
        return r is not None and abs(r - 1.0) > TOLERANCE

    def warning(self, what: str = "units_per_metre") -> str | None:
        """One line when the declared value disagrees (None when it agrees or nothing was
        measured)."""
        if not self.disagrees:
            return None
        how = ("box heights" if self.from_heights is not None else "walking speed")
        other = ""
        if self.from_heights is not None and self.from_speed is not None:
            other = f", walking speed {self.from_speed:.3g}"
        return (f"{what} {self.declared:g} is {self.ratio:.2f}x what the people in the data "
                f"give: {how} {self.estimate:.3g} units/m{other} (more than {TOLERANCE:.0%} off: "
                "check the homographies' ground units)")

    def lines(self, name: str) -> list[str]:
        """What ``sim_cluster check-scale`` prints."""
        out = [f"{name}: units_per_metre declared {self.declared:g}"]
        if self.from_heights is not None:
            cams = ", ".join("-" if v is None else f"{v:.3g}" for v in self.per_camera)
            out.append(f"  box heights: {self.boxes} upright boxes, median person "
                       f"{self.from_heights * PERSON_HEIGHT_M:.3g} units = {PERSON_HEIGHT_M} m "
                       f"-> {self.from_heights:.3g} units/m (per camera: {cams})")
        else:
            out.append("  box heights: too few upright boxes, or no camera model from the "
                       "homographies")
        if self.from_speed is not None:
            out.append(f"  walking speed: {self.steps} one-second steps, walking median "
                       f"{self.from_speed * WALKING_SPEED_MPS:.3g} units/s = "
                       f"{WALKING_SPEED_MPS} m/s -> {self.from_speed:.3g} units/m")
        else:
            out.append("  walking speed: no ground tracks (ground truth) to measure")
        if self.estimate is None:
            out.append("  no estimate: nothing to measure people by")
        elif self.disagrees:
            out.append(f"  WARNING: {self.warning()}")
        else:
            out.append(f"  declared {self.declared:g} agrees with {self.estimate:.3g} (within "
                       f"{TOLERANCE:.0%})")
        return out


def estimate_scale(cameras: Sequence[Camera], boxes: Iterable[np.ndarray], declared: float,
                   ids: Sequence[np.ndarray] = (), xy: Sequence[np.ndarray] = (),
                   fps: float = 25.0) -> ScaleEstimate:
    """Units per metre from ``boxes[c]`` (camera ``c``'s detection boxes, ``(n, 4)``) and,
    when given, ground tracks ``ids[k]``, ``xy[k]`` per frame (module docstring)."""
    est = ScaleEstimate(declared=float(declared))
    heights = []
    for cam, b in zip(cameras, boxes):
        h = box_heights(cam, b)
        est.per_camera.append(float(np.median(h)) / PERSON_HEIGHT_M if len(h) >= MIN_BOXES
                              else None)
        if len(h) >= MIN_BOXES:
            heights.append(h)
    if heights:
        h = np.concatenate(heights)
        est.from_heights, est.boxes = float(np.median(h)) / PERSON_HEIGHT_M, len(h)
    v = walking_speeds(ids, xy, fps)
    v = v[np.isfinite(v)]
    if len(v) >= MIN_BOXES:
        walking = v[v > np.median(v)]
        if len(walking) and np.median(walking) > 0:
            est.from_speed, est.steps = float(np.median(walking)) / WALKING_SPEED_MPS, len(v)
    return est
