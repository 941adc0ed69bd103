"""Camera geometry on a ground plane: pure numpy, no OpenCV.

A camera is known by its image-to-ground homography ``G`` (3x3; ``g ~ G [s*u, s*v, 1]^T`` with
``s`` the calibration's pixel scale, EPFL convention) and, when its full calibration is known,
a projection ``P`` (3x4, ground coordinates ``(x, y, z=height)`` to pixels). ``P`` gives target
heights and exact cylinder boxes; without it heights come from the box's aspect ratio.

Boxes are ``(x, y, w, h)`` in pixels: top-left corner, width, height (MOTChallenge convention).
Cylinders are ``(x, y, w, h)`` on the ground: centre of the base, width, height (paper III-A).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from protocol.errors import DmttError


class GeometryError(DmttError, ValueError):
    """A camera description that cannot be used (singular homography, bad shapes)."""


def norms(x: np.ndarray, axis: int | tuple[int, int] = -1, keepdims: bool = False) -> np.ndarray:
    """Euclidean norms of ``x`` along ``axis`` (Frobenius norms over a pair of axes):
    ``numpy.linalg.norm(x, axis=axis)`` of a real array, by its own arithmetic (the square root
    of ``add.reduce`` of the squares, so the same bits) without its argument checks and
    dispatch, which cost more than the sums on the core's small arrays."""
    return np.sqrt(np.add.reduce(x * x, axis=axis, keepdims=keepdims))


def _h(pts: np.ndarray) -> np.ndarray:
    """Points ``(n, 2)`` in homogeneous coordinates ``(n, 3)``."""
    out = np.ones((pts.shape[0], 3))
    out[:, :2] = pts
    return out


def apply_homography(Hm: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Map ``(n, 2)`` points through a 3x3 homography (with the perspective divide)."""
    pts = np.atleast_2d(np.asarray(pts, dtype=float))
    q = _h(pts) @ Hm.T
    return q[:, :2] / q[:, 2:3]


def homography_jacobians(Hm: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """``d(H p)/dp`` at each of ``(n, 2)`` image points: ``(n, 2, 2)``, all in one pass.

    With ``q = H (p, 1)`` and ``w = q_3``: ``J = (H_{1:2,1:2} w - q_{1:2} H_{3,1:2}) / w^2``."""
    q = _h(np.asarray(pts, float).reshape(-1, 2)) @ Hm.T
    w = q[:, 2, None, None]
    return (Hm[None, :2, :2] * w - q[:, :2, None] * Hm[None, None, 2, :2]) / (w * w)


@dataclass(frozen=True)
class Camera:
    """One calibrated camera. ``id`` is the node's index in the network (``0..N-1``)."""

    id: int
    image_size: tuple[int, int]  # (width, height) in pixels
    G: np.ndarray  # image (scaled pixels) -> ground, 3x3
    P: np.ndarray | None = None  # ground (x, y, z) -> image pixels, 3x4
    pixel_scale: float = 1.0  # EPFL: g = G [u*s, v*s, 1]
    fps: float = 25.0
    G_inv: np.ndarray = field(init=False, repr=False, compare=False)
    # views of G and G_inv that image_and_jacobians reads for every point batch (made once)
    _views: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        G = np.asarray(self.G, dtype=float)
        if G.shape != (3, 3) or not np.all(np.isfinite(G)):
            raise GeometryError(f"camera {self.id}: homography must be a finite 3x3 matrix")
        if abs(np.linalg.det(G)) < 1e-15:
            raise GeometryError(f"camera {self.id}: homography is singular")
        if self.P is None:
            # A homography is defined up to scale, sign included; published calibrations use
            # either sign. Fix it so that the image's bottom centre (always in front of the
            # camera) has a positive homogeneous coordinate: then ``in_front`` is meaningful.
            W, Hh = self.image_size
            probe = G @ np.array([W / 2.0 * self.pixel_scale, Hh * self.pixel_scale, 1.0])
            if probe[2] < 0:
                G = -G
        object.__setattr__(self, "G", G)
        object.__setattr__(self, "G_inv", np.linalg.inv(G))
        object.__setattr__(self, "_views", (self.G_inv[:, :2].T, self.G_inv[:, 2], G[None, :2, :2],
                                            G[None, None, 2, :2]))
        if self.P is not None:
            P = np.asarray(self.P, dtype=float)
            if P.shape != (3, 4) or not np.all(np.isfinite(P)):
                raise GeometryError(f"camera {self.id}: projection must be a finite 3x4 matrix")
            object.__setattr__(self, "P", P)
        if self.pixel_scale <= 0 or self.fps <= 0:
            raise GeometryError(f"camera {self.id}: pixel_scale and fps must be positive")

    # -- points ---------------------------------------------------------------------------
    def to_ground(self, uv: np.ndarray) -> np.ndarray:
        """Image pixels ``(n, 2)`` to ground ``(n, 2)``."""
        return apply_homography(self.G, np.atleast_2d(uv) * self.pixel_scale)

    def to_image(self, xy: np.ndarray) -> np.ndarray:
        """Ground ``(n, 2)`` (height 0) to image pixels ``(n, 2)``."""
        return apply_homography(self.G_inv, xy) / self.pixel_scale

    def ground_jacobian(self, uv: np.ndarray) -> np.ndarray:
        """Jacobian of image->ground at pixel ``uv`` (ground units per pixel), 2x2."""
        return self.ground_jacobians(np.asarray(uv, float)[None])[0]

    def ground_jacobians(self, uv: np.ndarray) -> np.ndarray:
        """:meth:`ground_jacobian` at each of ``(n, 2)`` pixels: ``(n, 2, 2)``."""
        return homography_jacobians(self.G, np.asarray(uv, float) * self.pixel_scale) * self.pixel_scale

    def image_and_jacobians(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``to_image(xy)`` and ``ground_jacobians`` at those pixels, from the ground points
        ``(n, 2)`` directly, without mapping the pixels back to the ground: with
        ``h = G^-1 (g, 1)`` the pixel is ``h_12 / h_3`` (over the pixel scale ``s``), ``G`` maps
        it to ``q = (g, 1) / h_3``, and the Jacobian ``(G_12,12 q_3 - q_12 G_3,12) / q_3^2``
        (:func:`homography_jacobians`, times ``s``) is ``s h_3 (G_12,12 - g G_3,12)``. Equal to
        the round trip up to rounding."""
        g = np.asarray(xy, float).reshape(-1, 2)
        Ginv_xy_T, Ginv_1, G_xy, G_3xy = self._views
        h = g @ Ginv_xy_T + Ginv_1
        uv = h[:, :2] / h[:, 2:3] / self.pixel_scale
        J = (G_xy - g[:, :, None] * G_3xy) * (h[:, 2, None, None] * self.pixel_scale)
        return uv, J

    def in_front(self, xy: np.ndarray) -> np.ndarray:
        """Whether ground points project in front of the camera (positive depth)."""
        xy = np.atleast_2d(xy)
        if self.P is not None:
            q = np.hstack([xy, np.zeros((len(xy), 1)), np.ones((len(xy), 1))]) @ self.P.T
        else:
            q = _h(xy) @ self.G_inv.T
        return q[:, 2] > 0

    def center(self) -> np.ndarray | None:
        """The camera centre ``(x, y, z)`` in ground coordinates, when ``P`` is known."""
        if self.P is None:
            return None
        _, _, vt = np.linalg.svd(self.P)
        c = vt[-1]
        return c[:3] / c[3]

    # -- boxes <-> cylinders ----------------------------------------------------------------
    def box_to_cylinder(self, box: np.ndarray) -> np.ndarray:
        """Box ``(x, y, w, h)`` px to cylinder ``(x, y, w, h)`` on the ground (paper III-A).

        Base centre: the box's bottom centre through ``G``. Width: distance between the
        projected bottom corners. Height: from ``P`` when known (the height whose top projects
        on the box's top edge), else the width times the box's aspect ratio.
        """
        return self.boxes_to_cylinders(np.asarray(box, float)[None])[0]

    def boxes_to_cylinders(self, boxes: np.ndarray) -> np.ndarray:
        """:meth:`box_to_cylinder` of ``(n, 4)`` boxes at once: ``(n, 4)``."""
        boxes = np.asarray(boxes, float).reshape(-1, 4)
        bx, by, bw, bh = boxes.T
        n = len(boxes)
        bottom = by + bh
        # foot (bottom centre), bottom-left and bottom-right corners, through G in one pass
        pts = np.empty((3, n, 2))
        pts[:, :, 0] = bx + bw / 2.0, bx, bx + bw
        pts[:, :, 1] = bottom
        g = self.to_ground(pts.reshape(-1, 2))
        c, left, right = g[:n], g[n:2 * n], g[2 * n:]
        w = norms(right - left, axis=1)
        aspect = w * bh / np.maximum(bw, 1e-9)
        h = aspect if self.P is None else self._heights(c, by)
        out = np.empty((n, 4))  # (filled column by column: np.stack costs more than the rest)
        out[:, :2] = c
        out[:, 2] = w
        out[:, 3] = np.where(np.isfinite(h) & (h > 0), h, aspect)
        return out

    def _heights(self, c: np.ndarray, v_top: np.ndarray) -> np.ndarray:
        """Heights whose top projects on the image rows ``v_top`` above ground points ``c``
        (``nan`` where the row is parallel to the vertical's image)."""
        P = self.P
        p = c @ P[:, :2].T + P[:, 3]
        q = P[:, 2]
        den = v_top * q[2] - q[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.abs(den) < 1e-12, np.nan, (p[:, 1] - v_top * p[:, 2]) / den)

    def cylinder_to_box(self, cyl: np.ndarray) -> np.ndarray:
        """Cylinder ``(x, y, w, h)`` to the box ``(x, y, w, h)`` px that frames it in this image."""
        x, y, w, h = (float(v) for v in cyl[:4])
        if self.P is not None:
            # Sample the cylinder's silhouette: base and top circles.
            ang = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
            r = w / 2.0
            ring = np.stack([x + r * np.cos(ang), y + r * np.sin(ang)], axis=1)
            pts = np.vstack([
                np.hstack([ring, np.zeros((16, 1))]),
                np.hstack([ring, np.full((16, 1), h)]),
            ])
            q = np.hstack([pts, np.ones((len(pts), 1))]) @ self.P.T
            uv = q[:, :2] / q[:, 2:3]
            u0, v0 = uv.min(axis=0)
            u1, v1 = uv.max(axis=0)
            return np.array([u0, v0, u1 - u0, v1 - v0])
        foot = self.to_image(np.array([[x, y]]))[0]
        J = self.ground_jacobian(foot)
        # Pixels per ground unit along the image's horizontal axis at the foot point.
        px_per_unit = 1.0 / max(float(np.linalg.norm(J[:, 0])), 1e-12)
        bw = w * px_per_unit
        bh = bw * h / max(w, 1e-9)
        return np.array([foot[0] - bw / 2.0, foot[1] - bh, bw, bh])

    def footprint(self, max_range: float | None = None) -> np.ndarray:
        """The ground polygon the image sees (bottom image corners and the horizon-clipped top)."""
        W, H = self.image_size
        vs = np.linspace(0, H, 9)
        pts = []
        for u in (0.0, float(W)):
            for v in (vs if u == 0.0 else vs[::-1]):
                g = self.to_ground(np.array([[u, v]]))[0]
                if self.in_front(g[None])[0] and (max_range is None or np.all(np.isfinite(g))):
                    pts.append(g)
        return np.array(pts)
