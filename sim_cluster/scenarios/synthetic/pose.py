"""A pinhole camera from its pose: what a scenario's ``[[cameras]]`` and a generated layout
(:mod:`~sim_cluster.scenarios.synthetic.layout`) both build their cameras with."""
from __future__ import annotations

import math

import numpy as np

from edge_node.geometry import Camera, GeometryError


def look_at_angles(position: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """``(yaw_deg, pitch_deg)`` of an optical axis from ``position`` towards ``target`` (xyz)."""
    d = np.asarray(target, float) - np.asarray(position, float)
    horiz = math.hypot(d[0], d[1])
    yaw = math.degrees(math.atan2(d[1], d[0])) if horiz > 1e-12 else 0.0
    pitch = math.degrees(math.atan2(-d[2], horiz))
    return yaw, pitch


def camera_from_pose(
    id: int,
    image_size: tuple[int, int],
    position: np.ndarray,
    yaw_deg: float,
    pitch_deg: float,
    roll_deg: float = 0.0,
    *,
    focal_px: float | None = None,
    fov_deg: float | None = None,
    principal_point: tuple[float, float] | None = None,
    fps: float = 25.0,
) -> Camera:
    """A pinhole camera: ``P = K [R | -R C]``, ``G = inv(K [r1 r2 -R C])`` (ground z = 0).

    World axes: x, y on the ground, z up. Camera axes: x right, y down, z forward. ``yaw`` is
    the optical axis' heading counter-clockwise from +x, ``pitch`` its tilt below the horizon,
    ``roll`` a rotation about it. Give ``focal_px`` or the horizontal ``fov_deg``.
    """
    W, H = image_size
    if (focal_px is None) == (fov_deg is None):
        raise GeometryError(f"camera {id}: give exactly one of focal_px and fov_deg")
    f = focal_px if focal_px is not None else (W / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    cx, cy = principal_point if principal_point is not None else (W / 2.0, H / 2.0)
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    fwd = np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), -math.sin(p)])
    right = np.array([math.sin(y), -math.cos(y), 0.0])
    down = np.cross(fwd, right)
    right, down = math.cos(r) * right + math.sin(r) * down, -math.sin(r) * right + math.cos(r) * down
    R = np.stack([right, down, fwd])
    C = np.asarray(position, float)
    t = -R @ C
    P = K @ np.hstack([R, t[:, None]])
    Hg = K @ np.stack([R[:, 0], R[:, 1], t], axis=1)  # ground (x, y, 1) -> pixels
    if abs(np.linalg.det(Hg)) < 1e-12 * max(1.0, np.abs(Hg).max()) ** 3:
        raise GeometryError(f"camera {id}: the ground plane is seen edge-on (camera at height 0?)")
    G = np.linalg.inv(Hg)
    G = G / np.abs(G).max()
    return Camera(id=id, image_size=(int(W), int(H)), G=G, P=P, pixel_scale=1.0, fps=fps)
