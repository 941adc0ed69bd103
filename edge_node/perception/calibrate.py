"""The image-to-ground homography from point pairs (``edge_node calibrate``).

Input: a CSV (or whitespace-separated) file of four or more pairs ``u, v, x, y``: a pixel
``(u, v)`` in the camera image and the ground point ``(x, y)`` (metres, or any ground unit) it
shows; a header line and ``#`` comments are allowed. OpenCV's ``findHomography`` fits
``G`` (image -> ground, the ``[camera] homography`` of a node config) by least squares over all
pairs, or with RANSAC (``ransac_px``) when some pairs may be wrong. The report gives the
reprojection error of every pair on the ground (``|G(u, v) - (x, y)|``) and in the image
(``|G^-1(x, y) - (u, v)|``), so a mistyped pair stands out.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge_node.formats.text import read_text
from edge_node.perception import PerceptionError, require_cv2


@dataclass
class Calibration:
    G: np.ndarray  # 3x3 image -> ground, normalised so that G[2, 2] = 1 (when possible)
    image_points: np.ndarray  # (n, 2)
    ground_points: np.ndarray  # (n, 2)
    ground_error: np.ndarray  # (n,) ground units
    image_error: np.ndarray  # (n,) pixels
    inliers: np.ndarray  # (n,) bool

    def summary(self) -> dict:
        g, p = self.ground_error[self.inliers], self.image_error[self.inliers]
        return {"pairs": int(len(self.ground_error)), "inliers": int(self.inliers.sum()),
                "ground_rms": float(np.sqrt(np.mean(g ** 2))), "ground_max": float(g.max()),
                "image_rms_px": float(np.sqrt(np.mean(p ** 2))), "image_max_px": float(p.max())}

    def toml(self, image_size: tuple[int, int] | None = None) -> str:
        """A ``[camera]`` table for a node config."""
        rows = ",\n    ".join("[" + ", ".join(f"{v:.10g}" for v in r) + "]" for r in self.G)
        out = ["[camera]", f"homography = [\n    {rows},\n]"]
        if image_size is not None:
            out.append(f"image_size = [{int(image_size[0])}, {int(image_size[1])}]")
        return "\n".join(out)


def read_pairs(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(image (n, 2), ground (n, 2))`` from a pairs file (module docstring); errors, bytes
    that are not UTF-8 among them, are a ``PerceptionError`` naming the file and the line."""
    path = Path(path)
    try:
        text = read_text(path, lambda e: PerceptionError(str(e)))
    except OSError as e:
        raise PerceptionError(f"cannot read the point pairs file {path}: {e.strerror or e}") from None
    rows = []
    for i, line in enumerate(text.splitlines(), start=1):
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        f = [x for x in re.split(r"[,\s;]+", s) if x]
        try:
            vals = [float(x) for x in f]
        except ValueError:
            if not rows:  # a header line
                continue
            raise PerceptionError(f"{path}:{i}: not four numbers u, v, x, y: {line!r}") from None
        if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
            raise PerceptionError(f"{path}:{i}: need four finite numbers u, v, x, y, got {line!r}")
        rows.append(vals)
    if len(rows) < 4:
        raise PerceptionError(f"{path}: {len(rows)} point pairs; a homography needs at least 4")
    a = np.array(rows, float)
    return a[:, :2], a[:, 2:]


def fit_homography(image_points: np.ndarray, ground_points: np.ndarray,
                   ransac_px: float | None = None) -> Calibration:
    """Fit ``G`` (image -> ground) with ``cv2.findHomography`` and measure the errors."""
    cv2 = require_cv2()
    img = np.asarray(image_points, np.float64).reshape(-1, 2)
    gnd = np.asarray(ground_points, np.float64).reshape(-1, 2)
    if len(img) != len(gnd) or len(img) < 4:
        raise PerceptionError("need at least 4 image/ground point pairs")
    method = cv2.RANSAC if ransac_px else 0
    # RANSAC's threshold is in the target (ground) units; findHomography(ground -> image) lets the
    # threshold be in pixels, so fit that way round and invert.
    H, mask = cv2.findHomography(gnd, img, method, float(ransac_px or 3.0))
    if H is None or not np.all(np.isfinite(H)) or abs(np.linalg.det(H)) < 1e-12:
        raise PerceptionError("no homography fits these points (are 3 of them on one line, or "
                              "two pairs the same point?)")
    G = np.linalg.inv(H)
    if abs(G[2, 2]) > 1e-12:
        G = G / G[2, 2]
    # every pair is fitted without RANSAC; OpenCV 5 still returns a mask then (the pairs within
    # the threshold of the fit), which is not which pairs were used
    inliers = np.ones(len(img), bool) if mask is None or not ransac_px else mask.ravel().astype(bool)
    gh = np.hstack([img, np.ones((len(img), 1))]) @ G.T
    g = gh[:, :2] / gh[:, 2:3]
    ih = np.hstack([gnd, np.ones((len(gnd), 1))]) @ H.T
    p = ih[:, :2] / ih[:, 2:3]
    return Calibration(G, img, gnd, np.linalg.norm(g - gnd, axis=1), np.linalg.norm(p - img, axis=1),
                       inliers)


def report(cal: Calibration, image_size: tuple[int, int] | None = None) -> str:
    """What ``edge_node calibrate`` prints: the ``[camera]`` TOML and the error table."""
    s = cal.summary()
    lines = [cal.toml(image_size), "",
             f"# {s['pairs']} point pairs, {s['inliers']} used; reprojection error: ground rms "
             f"{s['ground_rms']:.4g} (max {s['ground_max']:.4g}) ground units, image rms "
             f"{s['image_rms_px']:.3g} px (max {s['image_max_px']:.3g} px)",
             "#   pair        u        v          x          y   ground err   image err px"]
    for i, ((u, v), (x, y), ge, pe, ok) in enumerate(zip(cal.image_points, cal.ground_points,
                                                         cal.ground_error, cal.image_error,
                                                         cal.inliers)):
        lines.append(f"# {i:>6} {u:>8.1f} {v:>8.1f} {x:>10.3f} {y:>10.3f} {ge:>12.4f} {pe:>12.2f}"
                     + ("" if ok else "   (outlier: not used)"))
    return "\n".join(lines)
