"""The det-file format's reader: MOTChallenge ``det.txt`` (+ descriptors ``.npy``), ``gt.txt``,
``gt_ground.csv`` and the cameras of ``calibration.json`` (layout: ``sim_cluster/detfiles.py``,
which writes it). It lives in ``edge_node`` because camera processes read it (a det-file
source) and ``edge_node`` does not import ``sim_cluster``; both use this one reader.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.core.types import Detection
from edge_node.geometry import Camera, GeometryError


class DetFilesError(ValueError):
    """A det-files directory or file that cannot be read; the message names the file and field."""


# -- text tables ------------------------------------------------------------------------------------
def read_table(path: Path, min_cols: int, what: str) -> np.ndarray:
    """A comma-separated numeric table (``#`` comments, blank lines and CRLF allowed)."""
    if not path.is_file():
        raise DetFilesError(f"{what} file not found: {path}")
    rows: list[list[float]] = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        f = [x.strip() for x in s.split(",")]
        if len(f) < min_cols:
            raise DetFilesError(f"{path}:{i}: {what} row needs at least {min_cols} fields, got {len(f)}")
        try:
            rows.append([float(x) for x in f])
        except ValueError as exc:
            raise DetFilesError(f"{path}:{i}: non-numeric field in {what} row: {s!r}") from exc
    width = max((len(r) for r in rows), default=min_cols)
    out = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    if len(out) and np.any(out[:, 0] < 1):
        bad = int(np.argmax(out[:, 0] < 1))
        raise DetFilesError(f"{path}: data row {bad + 1}: frame {out[bad, 0]:g} < 1 "
                            "(MOTChallenge frames are 1-based)")
    return out


def group_rows(frames0: np.ndarray, n: int) -> list[np.ndarray]:
    """Row indices per scenario frame ``0..n-1``, in file order."""
    groups: list[list[int]] = [[] for _ in range(n)]
    for r, k in enumerate(frames0):
        if 0 <= k < n:
            groups[k].append(r)
    return [np.array(g, dtype=int) for g in groups]


def read_det(path: str | os.PathLike[str], frames: int | None = None,
             descriptors: str | os.PathLike[str] | None = None, require_descriptors: bool = False
             ) -> tuple[list[list[Detection]], list[np.ndarray]]:
    """One camera's ``det.txt`` (and its descriptors ``.npy``) as detections per frame.

    Returns ``(detections[k], true_ids[k])`` for ``k`` in ``0..frames-1`` (``frames`` defaults to
    the last frame in the file). A missing descriptor file is an error only when required; an
    all-NaN descriptor row means "no descriptor" (``None``).
    """
    path = Path(path)
    t = read_table(path, 6, "det.txt")
    desc = no_desc = None
    if descriptors is not None and require_descriptors and not Path(descriptors).is_file():
        raise DetFilesError(f"descriptor file not found: {descriptors} (named for {path})")
    if descriptors is not None and Path(descriptors).is_file():
        try:
            desc = np.load(descriptors, allow_pickle=False)
        except ValueError as exc:
            raise DetFilesError(f"{descriptors}: not a numeric .npy array ({exc})") from exc
        if desc.ndim != 2 or len(desc) != len(t):
            raise DetFilesError(f"{descriptors}: shape {desc.shape} does not match {len(t)} rows "
                                f"of {path} (want ({len(t)}, D))")
        desc = desc.astype(np.float32, copy=False)
        no_desc = np.all(np.isnan(desc), axis=1)
    if len(t) and np.any(t[:, 4:6] <= 0):
        bad = int(np.argmax(np.any(t[:, 4:6] <= 0, axis=1)))
        raise DetFilesError(f"{path}: data row {bad + 1}: non-positive box width or height")
    f0 = t[:, 0].astype(int) - 1
    n = int(f0.max()) + 1 if frames is None and len(f0) else (frames or 0)
    dets, ids = [], []
    for rows in group_rows(f0, n):
        conf = t[rows, 6] if t.shape[1] > 6 else np.ones(len(rows))
        conf = np.where(np.isfinite(conf), conf, 1.0)
        dets.append([Detection(box=t[r, 2:6].copy(),
                               descriptor=None if desc is None or no_desc[r] else desc[r],
                               score=float(c)) for r, c in zip(rows, conf)])
        ids.append(t[rows, 1].astype(np.int64))
    return dets, ids


def read_gt(path: str | os.PathLike[str], frames: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """One camera's MOTChallenge ``gt.txt`` as ``(ids, boxes)`` per frame ``0..frames-1``."""
    path = Path(path)
    t = read_table(path, 6, "gt.txt")
    keep = np.ones(len(t), dtype=bool)
    if t.shape[1] > 6:
        keep &= ~(t[:, 6] == 0)  # consider flag
    if t.shape[1] > 7:
        keep &= np.isnan(t[:, 7]) | (t[:, 7] == 1) | (t[:, 7] == -1)  # pedestrians only
    t = t[keep]
    return [(t[rows, 1].astype(np.int64), t[rows, 2:6].copy())
            for rows in group_rows(t[:, 0].astype(int) - 1, frames)]


def read_gt_ground(path: str | os.PathLike[str], frames: int
                   ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """``gt_ground.csv`` (``frame,id,x,y,w,h``) as ``(ids, xy, wh)`` per frame ``0..frames-1``."""
    t = read_table(Path(path), 6, "gt_ground.csv")
    groups = group_rows(t[:, 0].astype(int) - 1, frames)
    return ([t[g, 1].astype(np.int64) for g in groups], [t[g, 2:4].copy() for g in groups],
            [t[g, 4:6].copy() for g in groups])


def last_frame(path: Path) -> int:
    if not path.is_file():
        return 0
    t = read_table(path, 1, path.name)
    return int(t[:, 0].max()) if len(t) else 0


def camera_from_entry(c: int, entry: dict[str, Any], path: Path, fps: float) -> Camera:
    try:
        size = entry.get("image_size")
        if size is None or len(size) != 2:
            raise DetFilesError(f"{path}: cameras[{c}].image_size must be [width, height]")
        P = entry.get("P")
        return Camera(id=int(entry.get("id", c)), image_size=(int(size[0]), int(size[1])),
                      G=np.asarray(entry["G"], dtype=float),
                      P=None if P is None else np.asarray(P, dtype=float),
                      pixel_scale=float(entry.get("pixel_scale", 1.0)),
                      fps=float(entry.get("fps", fps)))
    except KeyError as exc:
        raise DetFilesError(f"{path}: cameras[{c}] lacks field {exc.args[0]!r}") from exc
    except (GeometryError, TypeError, ValueError) as exc:
        if isinstance(exc, DetFilesError):
            raise
        raise DetFilesError(f"{path}: cameras[{c}]: {exc}") from exc
