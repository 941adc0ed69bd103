"""Known registration errors in the synthetic world (``[calibration_error]``, issue 12 item 4).

Real homographies are off (docs/concepts.md, registration); this module makes the seeded world off
by a known amount, so that the tracker's online registration (``edge_node/core/registration.py``)
can be checked against the truth.

Ground similarities. ``S = similarity(c, shift, rotation)`` is the map of the ground plane

    S(p) = c + R(rotation) (p - c) + shift

a rotation (degrees, counter-clockwise) about the point ``c`` followed by a shift (metres), as a
3 x 3 homogeneous matrix. For camera ``i`` the centre ``c`` is always the reference point of the
TRUE camera as configured (``edge_node.core.registration.reference_point``: the ground point
seen at the middle of the image's lower half), so the rotation does not move that point.

What the world does with them (``world.generate``):

* **Believed cameras.** Detections are produced by the true cameras, exactly as without the
  table. The cameras handed to the tracker (``ScenarioData.cameras``, what the user believes)
  have an image-to-ground map that is off by ``E_i``: ``G_believed = E_i o G_true``, and a
  projection consistent with it, ``P_believed = P_true o lift(E_i^-1)`` (``lift``: the same
  similarity on x, y, height unchanged). A person at true ground point ``p`` is therefore
  measured by camera ``i`` at ``E_i(p)``; the correction the tracker should find maps a
  believed point ``g`` back to ``E_i^-1(g)`` (up to the network's common frame).
* **A bump** at frame ``K`` moves camera ``b``'s TRUE camera: from frame ``K`` on, it sees a
  person at true ground ``p`` where the original camera would have seen a person at ``B(p)``
  (``B`` a ground similarity about the same reference point). The moved camera is
  ``P_moved = P_true o lift(B)``, ``G_moved = B^-1 o G_true`` (:func:`moved_camera`): a real
  camera (turned about the vertical axis and shifted), so boxes, box sizes, visibility,
  occlusion order (its centre moved to ``B^-1(centre)``) and image-plane ground truth come out
  of the ordinary projection with it, consistently. The believed camera does not change (the
  user does not know), so camera ``b`` measures ``p`` at ``E_b(B(p))`` from frame ``K`` on.

Ground-truth positions stay the true ones. Without the table nothing changes: the world is
identical, bit for bit, to a world without it (and so is one whose errors are all zero and
which has no bump). With a bump, the bumped camera's detector draws its noise for a different
set of boxes after the bump, so its detections differ (in their noise, not in distribution)
from the unbumped world's before the bump too; every other camera's detections are identical.
The bumped camera's false positives are sized with the camera before the bump (random boxes).
Rendered video (``render.py``) draws the true cameras before any bump.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import math

import numpy as np

from edge_node.core.registration import reference_point
from edge_node.geometry import Camera


def similarity(centre: np.ndarray, shift: np.ndarray, rotation_deg: float) -> np.ndarray:
    """The ground similarity ``p -> centre + R(rotation) (p - centre) + shift`` (3 x 3)."""
    a = math.radians(float(rotation_deg))
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    c = np.asarray(centre, float).reshape(2)
    S = np.eye(3)
    S[:2, :2] = R
    S[:2, 2] = c - R @ c + np.asarray(shift, float).reshape(2)
    return S


def lift(S: np.ndarray) -> np.ndarray:
    """A ground similarity (3 x 3 on ``(x, y, 1)``) acting on ``(x, y, z, 1)``, height kept."""
    L = np.eye(4)
    L[:2, :2] = S[:2, :2]
    L[:2, 3] = S[:2, 2]
    return L


def believed_camera(camera: Camera, E: np.ndarray) -> Camera:
    """What the user believes camera ``camera`` is when its ground map is off by ``E``:
    ``G = E o G_true`` and ``P = P_true o lift(E^-1)``."""
    P = None if camera.P is None else camera.P @ lift(np.linalg.inv(E))
    return replace(camera, G=E @ camera.G, P=P)


def moved_camera(camera: Camera, B: np.ndarray) -> Camera:
    """The camera after a bump ``B``: it sees at ``p`` what ``camera`` saw at ``B(p)``
    (``P = P_true o lift(B)``, ``G = B^-1 o G_true``)."""
    P = None if camera.P is None else camera.P @ lift(B)
    return replace(camera, G=np.linalg.inv(B) @ camera.G, P=P)


@dataclass(frozen=True)
class CalibrationBump:
    """The true camera ``camera`` moves at frame ``frame`` by ``shift`` (m) and ``rotation_deg``
    about its reference point (see the module docstring for what "moves" means)."""

    camera: int
    frame: int
    shift: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0


@dataclass(frozen=True)
class CalibrationOffsets:
    """Per camera (in camera order) the error of the believed ground map: ``shifts[i]`` (m) and
    ``rotations_deg[i]`` about the camera's reference point; an optional bump."""

    shifts: tuple[tuple[float, float], ...]
    rotations_deg: tuple[float, ...]
    bump: CalibrationBump | None = None

    def errors(self, cameras: list[Camera]) -> list[np.ndarray]:
        """``E_i`` of every camera (3 x 3 ground similarities)."""
        if len(cameras) != len(self.shifts):
            raise ValueError(f"calibration error: {len(self.shifts)} cameras configured, "
                             f"the world has {len(cameras)}")
        return [similarity(reference_point(cam), s, r)
                for cam, s, r in zip(cameras, self.shifts, self.rotations_deg)]

    def bump_map(self, cameras: list[Camera]) -> np.ndarray | None:
        """``B`` of the bump (3 x 3), or None without a bump."""
        b = self.bump
        if b is None:
            return None
        return similarity(reference_point(cameras[b.camera]), b.shift, b.rotation_deg)
