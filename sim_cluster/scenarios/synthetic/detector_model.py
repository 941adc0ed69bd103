"""A statistical people detector: turns true image boxes into noisy detections.

Used by the synthetic world and by replays of real ground truth. Per true box, in this order:

1. the effective visible fraction is ``visible_fraction`` (the part of the in-image box not hidden
   by other people; pass 1 when unknown) times the fraction of the box inside the image;
2. the box is missed if that is below ``occlusion_miss_threshold``, if its visible height is
   below ``min_box_height_px``, or at random with probability ``miss_rate``;
3. a kept box gets independent Gaussian noise (sigma ``box_noise_px``) on each of its four edges,
   is clipped to the image, and gets a descriptor from the appearance model.

False positives: a Poisson number (mean ``false_positives_per_frame``) of person-sized boxes at
random image positions, sized from the camera geometry at the sampled foot point when the
camera is calibrated and the point is on the visible ground, else from a height range.

Randomness is drawn in a fixed order whose amounts do not depend on the parameters (miss draws,
box noise, scores and descriptor noise for every true box, false positives last), so changing
for example the miss rate leaves the surviving detections' boxes and descriptors unchanged.
:func:`detect` handles one frame (give each frame its own generator to keep frames independent);
:func:`detect_frames` handles a whole sequence of one camera at once (what the world uses).
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from edge_node.core.types import Detection
from edge_node.geometry import Camera
from protocol.errors import DmttError
from sim_cluster.scenarios.synthetic.appearance import AppearanceModel


class DetectorParamsError(DmttError, ValueError):
    """Detector parameters out of range."""


@dataclass(frozen=True)
class DetectorParams:
    """Detector behaviour. Lengths are image pixels; rates are per camera per frame."""

    miss_rate: float = 0.1  # probability of missing a well-visible person
    occlusion_miss_threshold: float = 0.5  # visible fraction below which a person is missed
    false_positives_per_frame: float = 0.2  # Poisson mean per camera per frame
    box_noise_px: float = 2.0  # Gaussian sigma on each box edge
    min_box_height_px: float = 10.0  # visible boxes shorter than this are missed
    fp_person_height_m: tuple[float, float] = (1.5, 1.9)  # false-positive size (ground units)
    fp_height_frac: tuple[float, float] = (0.15, 0.5)  # fallback: box height / image height

    def __post_init__(self) -> None:
        def check(name: str, ok: bool, want: str) -> None:
            if not ok:
                raise DetectorParamsError(f"{name} must be {want}, got {getattr(self, name)!r}")

        check("miss_rate", 0.0 <= self.miss_rate <= 1.0, "in [0, 1]")
        check("occlusion_miss_threshold", 0.0 <= self.occlusion_miss_threshold <= 1.0, "in [0, 1]")
        check(
            "false_positives_per_frame",
            math.isfinite(self.false_positives_per_frame) and self.false_positives_per_frame >= 0,
            ">= 0",
        )
        check("box_noise_px", math.isfinite(self.box_noise_px) and self.box_noise_px >= 0, ">= 0")
        check(
            "min_box_height_px",
            math.isfinite(self.min_box_height_px) and self.min_box_height_px >= 0,
            ">= 0",
        )
        lo, hi = self.fp_person_height_m
        check("fp_person_height_m", 0 < lo <= hi, "a range 0 < lo <= hi")
        lo, hi = self.fp_height_frac
        check("fp_height_frac", 0 < lo <= hi <= 1, "a range 0 < lo <= hi <= 1")


def in_image_fraction(boxes: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Fraction of each box ``(n, 4)`` (x, y, w, h) lying inside a ``(W, H)`` image."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    W, H = image_size
    x0 = np.clip(b[:, 0], 0, W)
    y0 = np.clip(b[:, 1], 0, H)
    x1 = np.clip(b[:, 0] + b[:, 2], 0, W)
    y1 = np.clip(b[:, 1] + b[:, 3], 0, H)
    area = b[:, 2] * b[:, 3]
    inside = (x1 - x0) * (y1 - y0)
    return np.where(area > 0, inside / np.where(area > 0, area, 1.0), 0.0)


def clip_boxes(boxes: np.ndarray, image_size: tuple[int, int], min_size: float = 1.0) -> np.ndarray:
    """Clip boxes ``(n, 4)`` to the image, keeping at least ``min_size`` px of width/height."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    W, H = image_size
    x0 = np.clip(b[:, 0], 0, W - min_size)
    y0 = np.clip(b[:, 1], 0, H - min_size)
    x1 = np.clip(b[:, 0] + b[:, 2], x0 + min_size, W)
    y1 = np.clip(b[:, 1] + b[:, 3], y0 + min_size, H)
    return np.stack([x0, y0, x1 - x0, y1 - y0], axis=1)


def _false_positive_boxes(
    camera: Camera, n: int, params: DetectorParams, rng: np.random.Generator
) -> np.ndarray:
    """``n`` person-sized boxes at random positions, clipped to the image.

    Draws ``5 n`` uniforms (foot column and row, person height, fallback height fraction,
    aspect). The foot row is in the lower three quarters of the image (people stand on the
    ground); the size is that of a person standing there when the camera is calibrated and the
    point is on the visible ground, else ``fp_height_frac`` of the image height.
    """
    W, H = camera.image_size
    if n == 0:
        return np.zeros((0, 4))
    u = rng.uniform(0.0, W, n)
    v = rng.uniform(0.25 * H, H, n)
    ph = rng.uniform(*params.fp_person_height_m, n)
    frac = rng.uniform(*params.fp_height_frac, n)
    aspect = rng.uniform(0.3, 0.5, n)
    bw = aspect * frac * H
    bh = frac * H
    if camera.P is not None:
        g = camera.to_ground(np.stack([u, v], axis=1))
        ok = np.all(np.isfinite(g), axis=1)
        ok[ok] = camera.in_front(g[ok])
        for i in np.flatnonzero(ok):
            box = camera.cylinder_to_box(np.array([g[i, 0], g[i, 1], ph[i] * 0.3, ph[i]]))
            if np.all(np.isfinite(box)) and params.min_box_height_px <= box[3] <= H:
                bw[i], bh[i] = box[2], box[3]
    out = np.stack([u - bw / 2.0, v - bh, bw, bh], axis=1)
    return clip_boxes(out, camera.image_size)


def detect_frames(
    camera: Camera,
    frame: np.ndarray,
    ids: np.ndarray,
    boxes: np.ndarray,
    visible_fraction: np.ndarray,
    frames: int,
    params: DetectorParams,
    appearance: AppearanceModel,
    rng: np.random.Generator,
) -> list[tuple[list[Detection], np.ndarray]]:
    """Simulate one camera's detector on ``frames`` frames at once (same model as :func:`detect`).

    ``frame`` (M,) is the frame index (``0 <= frame < frames``) of each true box, ``ids`` (M,)
    the person ids, ``boxes`` (M, 4) the true boxes, ``visible_fraction`` (M,) as in
    :func:`detect`. Returns per frame the detections (that frame's true positives in input
    order, then its false positives) and the true id behind each (``-1``: false positive).

    Draw order: per true box a miss uniform, 4 edge noises, a score noise, the descriptor noise;
    then one Poisson false-positive count per frame; then the false positives themselves.
    """
    frame = np.asarray(frame, dtype=np.int64).reshape(-1)
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    n = len(ids)
    if b.shape[0] != n or frame.shape[0] != n:
        raise ValueError(f"frame ({frame.shape[0]}), ids ({n}) and boxes ({b.shape[0]}) differ in length")
    if n and (frame.min() < 0 or frame.max() >= frames):
        raise ValueError(f"frame indices must be in [0, {frames})")
    vis = np.broadcast_to(np.asarray(visible_fraction, dtype=float), (n,))
    W, H = camera.image_size

    # Fixed-size draws first, so the amounts never depend on the parameters.
    u_miss = rng.random(n)
    edge_noise = rng.standard_normal((n, 4))
    edge_noise *= params.box_noise_px
    score_noise = rng.standard_normal(n)
    desc = appearance.descriptors(ids, camera.id, rng)

    effective = vis * in_image_fraction(b, camera.image_size)
    visible_h = np.clip(b[:, 1] + b[:, 3], 0, H) - np.clip(b[:, 1], 0, H)
    keep = (
        (effective >= params.occlusion_miss_threshold)
        & (effective > 0)
        & (visible_h >= params.min_box_height_px)
        & (u_miss >= params.miss_rate)
    )

    x0 = b[:, 0] + edge_noise[:, 0]
    y0 = b[:, 1] + edge_noise[:, 1]
    x1 = b[:, 0] + b[:, 2] + edge_noise[:, 2]
    y1 = b[:, 1] + b[:, 3] + edge_noise[:, 3]
    x0, x1 = np.minimum(x0, x1 - 1.0), np.maximum(x1, x0 + 1.0)
    y0, y1 = np.minimum(y0, y1 - 1.0), np.maximum(y1, y0 + 1.0)
    noisy = clip_boxes(np.stack([x0, y0, x1 - x0, y1 - y0], axis=1), camera.image_size)
    scores = np.clip(0.55 + 0.4 * effective + 0.05 * score_noise, 0.05, 1.0)

    out: list[tuple[list[Detection], list[int]]] = [([], []) for _ in range(frames)]
    kept = np.flatnonzero(keep)
    kept = kept[np.argsort(frame[kept], kind="stable")]
    kept_boxes, kept_desc = noisy[kept], desc[kept]  # compact: missed rows are not kept alive
    for j, (k, pid, s) in enumerate(zip(frame[kept].tolist(), ids[kept].tolist(),
                                        scores[kept].tolist())):
        out[k][0].append(Detection(box=kept_boxes[j], descriptor=kept_desc[j], score=s))
        out[k][1].append(pid)

    # False positives last: theirs are the only parameter-dependent amounts of draws.
    lam = params.false_positives_per_frame
    n_fp = rng.poisson(lam, frames) if lam > 0 else np.zeros(frames, dtype=np.int64)
    total = int(n_fp.sum())
    if total:
        fp_boxes = _false_positive_boxes(camera, total, params, rng)
        fp_desc = appearance.false_positive_descriptors(total, rng)
        fp_scores = rng.uniform(0.3, 0.8, total)
        fp_frame = np.repeat(np.arange(frames), n_fp)
        for j, k in enumerate(fp_frame.tolist()):
            out[k][0].append(Detection(box=fp_boxes[j], descriptor=fp_desc[j], score=float(fp_scores[j])))
            out[k][1].append(-1)
    return [(dets, np.asarray(t, dtype=np.int64)) for dets, t in out]


def detect(
    camera: Camera,
    ids: np.ndarray,
    boxes: np.ndarray,
    visible_fraction: np.ndarray,
    params: DetectorParams,
    appearance: AppearanceModel,
    rng: np.random.Generator,
) -> tuple[list[Detection], np.ndarray]:
    """Simulate one camera's detector on one frame.

    ``ids`` (n,) person ids, ``boxes`` (n, 4) their true boxes (x, y, w, h) px (may extend past
    the image), ``visible_fraction`` (n,) the fraction of each box's in-image part that no
    nearer person hides (1 when unknown). Returns the detections (true positives in input
    order, then false positives) and the true id behind each (``-1`` for a false positive).
    Give each frame its own generator to keep frames independent of each other.
    """
    n = len(np.asarray(ids).reshape(-1))
    return detect_frames(camera, np.zeros(n, dtype=np.int64), ids, boxes, visible_fraction, 1,
                         params, appearance, rng)[0]
