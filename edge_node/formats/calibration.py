"""``calibration.json``: the cameras and the files of a det-files directory.

A det-files directory (written by ``sim_cluster export-detections``, or by hand for any external
detector)::

    calibration.json       cameras, frame count, fps, units per metre (below)
    c0/det.txt             camera 0's detections (edge_node.formats.detfile)
    c0/det.npy             optional: its descriptors
    c0/gt.txt              optional: image ground truth
    c1/...
    gt_ground.csv          optional: ground truth on the ground plane

``calibration.json``::

    {"name": "...", "frames": 1000, "fps": 25.0, "units_per_metre": 30.0,
     "area": [xmin, xmax, ymin, ymax],            # optional
     "seed": 0,                                    # optional: the seed the export used
     "gt_ground": "gt_ground.csv",                 # optional, this default
     "cameras": [{"id": 0, "image_size": [360, 288], "G": [[...], [...], [...]],
                  "pixel_scale": 1.0, "P": null,   # P optional (3x4)
                  "det": "c0/det.txt", "descriptors": "c0/det.npy", "gt": "c0/gt.txt"}]}

Paths are relative to ``calibration.json``; the per-camera file entries default to the layout
above. ``frames`` defaults to the last frame in any det, gt or gt_ground file; when given, no file
may hold a later frame (:attr:`Calibration.bound`), and without it no frame may pass
``detfile.MAX_FRAME``. A camera process reads one camera of it, the simulator all of them: both
through :func:`read_calibration`.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.formats.detfile import MAX_FRAME, DetFilesError, FrameBound, last_frame
from edge_node.formats.text import read_text
from edge_node.geometry import Camera, GeometryError

CALIBRATION = "calibration.json"
GT_GROUND = "gt_ground.csv"
DEFAULT_FPS = 25.0


@dataclass(frozen=True)
class CameraFiles:
    """One camera's files (absolute paths)."""

    det: Path
    descriptors: Path
    descriptors_required: bool  # the entry names its descriptor file: it must exist
    gt: Path


@dataclass(frozen=True)
class Calibration:
    """A parsed ``calibration.json``; ``cameras[i]`` and ``files[i]`` are camera ``i``."""

    path: Path
    cameras: list[Camera]
    files: list[CameraFiles]
    fps: float
    units_per_metre: float
    frames: int | None  # as the file says; frame_count() falls back to the files
    gt_ground: Path
    name: str | None = None
    area: tuple[float, float, float, float] | None = None
    seed: int | None = None

    @property
    def bound(self) -> FrameBound | None:
        """The frames the file states, which no det, gt or gt_ground row may pass (None when
        it states none)."""
        return None if self.frames is None else FrameBound(int(self.frames), self.path)

    def frame_count(self) -> int:
        """``frames`` from the file, else the last frame in any det, gt or gt_ground file."""
        if self.frames is not None:
            return int(self.frames)
        return max([last_frame(f) for fs in self.files for f in (fs.det, fs.gt)]
                   + [last_frame(self.gt_ground)])


def calibration_path(path: str | os.PathLike[str]) -> Path:
    """A det-files directory or its ``calibration.json`` -> the ``calibration.json``."""
    p = Path(path)
    return p if p.is_file() else p / CALIBRATION


def camera_from_entry(c: int, entry: dict[str, Any], path: Path, fps: float) -> Camera:
    """Camera entry ``c`` of ``calibration.json`` (``path`` names it in errors)."""
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


def read_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read a det-files directory's ``calibration.json`` (or the directory itself)."""
    cal = calibration_path(path)
    if not cal.is_file():
        raise DetFilesError(f"calibration file not found: {cal}")
    try:
        doc = json.loads(read_text(cal, lambda e: DetFilesError(str(e))))
    except json.JSONDecodeError as exc:
        raise DetFilesError(f"{cal}: not valid JSON ({exc})") from exc
    except OSError as exc:
        raise DetFilesError(f"{cal}: cannot read ({exc})") from exc
    base = cal.parent
    fps = float(doc.get("fps", DEFAULT_FPS))
    entries = doc.get("cameras")
    if not isinstance(entries, list) or not entries:
        raise DetFilesError(f"{cal}: 'cameras' must be a non-empty list")
    cams = [camera_from_entry(c, e, cal, fps) for c, e in enumerate(entries)]
    files = []
    for c, e in enumerate(entries):
        det_rel = e.get("det", f"c{c}/det.txt")
        npy_rel = e.get("descriptors", str(Path(det_rel).with_suffix(".npy")))
        files.append(CameraFiles(base / det_rel, base / npy_rel, "descriptors" in e,
                                 base / e.get("gt", f"c{c}/gt.txt")))
    upm = float(doc.get("units_per_metre", 1.0))
    if upm <= 0:
        raise DetFilesError(f"{cal}: units_per_metre must be positive, got {upm}")
    frames = doc.get("frames")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, (int, float))
                               or not 1 <= frames <= MAX_FRAME or frames != int(frames)):
        raise DetFilesError(f"{cal}: frames must be a whole number in 1..{MAX_FRAME} (MAX_FRAME), "
                            f"got {frames!r}")
    area = doc.get("area")
    return Calibration(
        path=cal, cameras=cams, files=files, fps=fps, units_per_metre=upm,
        frames=None if frames is None else int(frames),
        gt_ground=base / doc.get("gt_ground", GT_GROUND),
        name=doc.get("name"), area=None if area is None else tuple(float(v) for v in area),
        seed=doc.get("seed"))


def camera_entry(camera: Camera, det: str, gt: str, descriptors: str | None = None) -> dict:
    """The ``cameras[i]`` entry of ``camera`` with its files (relative to the directory)."""
    entry: dict[str, Any] = {
        "id": camera.id, "image_size": list(camera.image_size), "G": camera.G.tolist(),
        "pixel_scale": camera.pixel_scale, "fps": camera.fps,
        "P": None if camera.P is None else camera.P.tolist(), "det": det, "gt": gt}
    if descriptors is not None:
        entry["descriptors"] = descriptors
    return entry


def write_calibration(directory: Path, *, name: str, frames: int, fps: float,
                      units_per_metre: float, area, seed: int, cameras: list[dict],
                      gt_ground: str = GT_GROUND) -> Path:
    """Write ``directory/calibration.json`` (``cameras``: :func:`camera_entry` dicts)."""
    doc = {"name": name, "frames": frames, "fps": fps, "units_per_metre": units_per_metre,
           "area": list(area), "seed": seed, "gt_ground": gt_ground, "cameras": cameras}
    cal = Path(directory) / CALIBRATION
    cal.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return cal
