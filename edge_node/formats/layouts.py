"""Other tools' layouts of detection files, read as a det-files directory without a
``calibration.json``: the cameras from a homography file, each camera's MOTChallenge files found
by their place in the folder, the ground truth as ground points or derived from the cameras'
boxes. :func:`read_layout` gives the same :class:`~edge_node.formats.calibration.Calibration`
a ``calibration.json`` gives, plus the ground truth and one-line notes on what it assumed.

The accepted forms are :data:`LAYOUTS` (also the help text of ``sim_cluster run`` and
``import-detections``). Camera order is the natural order of the camera names (``cam2`` before
``cam10``); a homography file lists its matrices in that order or names them by camera. Anything
that does not fit is a :class:`LayoutError` naming the file or field at fault and the layout
expected.
"""
from __future__ import annotations

import configparser
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.formats.calibration import CALIBRATION, DEFAULT_FPS, Calibration, CameraFiles
from edge_node.formats.detfile import (DetFilesError, FrameTable, GroundFile, open_gt,
                                       read_table)
from edge_node.formats.text import read_text
from edge_node.geometry import Camera, GeometryError

LAYOUTS = """\
A scenario folder without calibration.json holds one camera's detections per MOTChallenge
det.txt (frame,id,x,y,w,h,conf,...; 1-based frames; optional descriptors as .npy beside it,
one row per det.txt row), in one of these layouts (camera order: natural order of the names):

  DIR/<cam>/det/det.txt   MOTChallenge sequence folders, one per camera; optional
                          <cam>/gt/gt.txt (boxes) and <cam>/seqinfo.ini (imWidth, imHeight,
                          frameRate)
  DIR/<cam>/det.txt       the same without det/: optional <cam>/gt.txt, <cam>/det.npy
  DIR/<cam>.txt           flat files, e.g. cam0.txt, cam1.txt; optional DIR/gt/<cam>.txt
                          (boxes) and DIR/<cam>.npy (descriptors)

plus homographies, image-to-ground (g = H [u, v, 1]), one 3x3 per camera: --homographies FILE
or DIR/homographies.json|.npy|.npz:

  .json  [H0, H1, ...]  or  {"H": [H0, ...], "image_size": [w, h], "units_per_metre": u,
         "fps": f}  or  {"<cam>": H | {"H": H, "image_size": [w, h]}, ...}
  .npy   one array (cameras, 3, 3)
  .npz   one array (cameras, 3, 3), or one 3x3 array per camera named like the camera

and optionally ground truth on the ground: --ground-truth FILE or DIR/gt_ground.csv|.txt, rows
frame,id,X,Y (or frame,id,X,Y,w,h) in the homographies' ground units. Without it, the cameras'
gt boxes (same person, same id in every camera) give it: their foot points through the
homographies, averaged per frame and id. Image size: --image-size WxH, seqinfo.ini, or
image_size in the JSON; frame rate: --fps, seqinfo.ini, the JSON, else 25; ground units per
metre: --units-per-metre, the JSON, else 1 (metres)."""

HOMOGRAPHY_FILES = ("homographies.json", "homographies.npy", "homographies.npz")
GROUND_FILES = ("gt_ground.csv", "gt_ground.txt")
PERSON_WH_M = (0.5, 1.75)  # the cylinder given to ground-truth points without a size


class LayoutError(DetFilesError):
    """A folder of detection files that does not fit an accepted layout (:data:`LAYOUTS`); the
    message names the file or field at fault."""


@dataclass(frozen=True)
class ImportOptions:
    """What a command line adds to a folder without ``calibration.json`` (None: from the files)."""

    homographies: Path | None = None
    ground_truth: Path | None = None
    units_per_metre: float | None = None
    fps: float | None = None
    image_size: tuple[int, int] | None = None

    @property
    def given(self) -> list[str]:
        """The options set, as command-line names (for "only for such folders" errors)."""
        names = {"homographies": "--homographies", "ground_truth": "--ground-truth",
                 "units_per_metre": "--units-per-metre", "fps": "--fps",
                 "image_size": "--image-size"}
        return [flag for attr, flag in names.items() if getattr(self, attr) is not None]


@dataclass(frozen=True)
class Imported:
    """A folder read by :func:`read_layout`: its calibration, ground truth and notes."""

    calibration: Calibration
    ground: GroundFile | None
    notes: tuple[str, ...] = field(default=())
    names: tuple[str, ...] = field(default=())  # camera names, camera order


# -- cameras' files ---------------------------------------------------------------------------------
def _natural(name: str) -> list[Any]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


@dataclass(frozen=True)
class _Cam:
    name: str
    det: Path
    descriptors: Path
    gt: Path
    seqinfo: Path | None


def find_cameras(directory: Path, ground_truth: Path | None = None) -> tuple[str, list[_Cam]]:
    """The layout (``"folders"`` or ``"flat"``) and every camera's files, camera order."""
    d = Path(directory)
    if not d.is_dir():
        raise LayoutError(f"{d}: no such folder (a det-files folder with {CALIBRATION}, or "
                          "another tool's detection files: sim_cluster run --help)")
    if (d / "det" / "det.txt").is_file():  # one MOTChallenge sequence: one camera
        return "folders", [_folder_cam(d)]
    subs = [s for s in d.iterdir() if s.is_dir() and ((s / "det" / "det.txt").is_file()
                                                      or (s / "det.txt").is_file())]
    skip = {n.lower() for n in GROUND_FILES} | {"readme.txt"}
    gt_file = None if ground_truth is None else Path(ground_truth).resolve()
    flat = [f for f in d.glob("*.txt") if f.is_file() and f.name.lower() not in skip
            and f.resolve() != gt_file]
    if subs and flat:
        raise LayoutError(f"{d}: both camera folders ({', '.join(s.name for s in subs[:3])}) "
                          f"and flat det files ({', '.join(f.name for f in flat[:3])}): use one "
                          f"layout\n{LAYOUTS}")
    if subs:
        return "folders", [_folder_cam(s) for s in sorted(subs, key=lambda s: _natural(s.name))]
    if flat:
        return "flat", [_Cam(f.stem, f, f.with_suffix(".npy"), d / "gt" / f.name, None)
                        for f in sorted(flat, key=lambda f: _natural(f.stem))]
    raise LayoutError(f"{d}: no {CALIBRATION} and no detection files in an accepted layout\n"
                      f"{LAYOUTS}")


def _folder_cam(s: Path) -> _Cam:
    det = s / "det" / "det.txt" if (s / "det" / "det.txt").is_file() else s / "det.txt"
    gt = s / "gt" / "gt.txt" if (s / "gt" / "gt.txt").is_file() else s / "gt.txt"
    info = s / "seqinfo.ini"
    return _Cam(s.name, det, det.with_suffix(".npy"), gt, info if info.is_file() else None)


def read_seqinfo(path: Path) -> dict[str, float]:
    """``imWidth``, ``imHeight``, ``frameRate`` of a MOTChallenge ``seqinfo.ini`` (those present)."""
    cp = configparser.ConfigParser()
    try:
        cp.read_string(read_text(path, lambda e: LayoutError(str(e))))
    except configparser.Error as exc:
        raise LayoutError(f"{path}: not an INI file ({exc})") from None
    if not cp.has_section("Sequence"):
        raise LayoutError(f"{path}: no [Sequence] section (MOTChallenge seqinfo.ini)")
    out = {}
    for key in ("imWidth", "imHeight", "frameRate"):
        if cp.has_option("Sequence", key):
            raw = cp.get("Sequence", key)
            try:
                v = float(raw)
            except ValueError:
                v = math.nan
            if not math.isfinite(v) or v <= 0:
                raise LayoutError(f"{path}: [Sequence] {key} must be a positive number, got {raw!r}")
            out[key] = v
    return out


# -- homographies -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Homographies:
    """One image-to-ground homography per camera (camera order) and what the file adds."""

    H: list[np.ndarray]
    image_size: list[tuple[int, int] | None]
    pixel_scale: float = 1.0
    units_per_metre: float | None = None
    fps: float | None = None


def _matrix(path: Path, where: str, value: Any) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise LayoutError(f"{path}: {where} must be a 3x3 matrix of numbers") from None
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise LayoutError(f"{path}: {where} must be a finite 3x3 matrix, got shape {m.shape}")
    return m


def _size(path: Path, where: str, value: Any) -> tuple[int, int]:
    ok = isinstance(value, (list, tuple)) and len(value) == 2 and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in value)
    if not ok:
        raise LayoutError(f"{path}: {where} must be [width, height] in pixels, got {value!r}")
    return int(value[0]), int(value[1])


def _positive(path: Path, where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 \
            or not math.isfinite(value):
        raise LayoutError(f"{path}: {where} must be a positive number, got {value!r}")
    return float(value)


def _stack(path: Path, where: str, value: Any, names: list[str]) -> list[np.ndarray]:
    a = np.asarray(value, dtype=float) if not isinstance(value, np.ndarray) else value
    if a.ndim == 2 and len(names) == 1:
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (3, 3):
        raise LayoutError(f"{path}: {where} must hold one 3x3 homography per camera "
                          f"(shape (cameras, 3, 3)), got shape {a.shape}")
    if len(a) != len(names):
        raise LayoutError(f"{path}: {where} has {len(a)} homographies for {len(names)} cameras "
                          f"({', '.join(names)})")
    return [_matrix(path, f"{where}[{i}]", m) for i, m in enumerate(a)]


def read_homographies(path: str | os.PathLike[str], names: list[str]) -> Homographies:
    """The homography file ``path`` (JSON, ``.npy`` or ``.npz``: :data:`LAYOUTS`) for the cameras
    ``names`` (camera order)."""
    path = Path(path)
    if not path.is_file():
        raise LayoutError(f"homography file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            a = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise LayoutError(f"{path}: not a numeric .npy array ({exc})") from None
        H = _stack(path, "the array", a, names)
        return Homographies(H, [None] * len(H))
    if suffix == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (ValueError, OSError) as exc:
            raise LayoutError(f"{path}: not a NumPy .npz archive ({exc})") from None
        if len(arrays) == 1:
            (k, a), = arrays.items()
            H = _stack(path, f"array {k!r}", a, names)
        else:
            missing = [n for n in names if n not in arrays]
            if missing:
                raise LayoutError(f"{path}: holds arrays {sorted(arrays)}; want one (cameras, 3, "
                                  f"3) array or one 3x3 array per camera named {names} "
                                  f"(missing {missing})")
            H = [_matrix(path, f"array {n!r}", arrays[n]) for n in names]
        return Homographies(H, [None] * len(H))
    if suffix != ".json":
        raise LayoutError(f"{path}: homographies must be a .json, .npy or .npz file")
    try:
        doc = json.loads(read_text(path, lambda e: LayoutError(str(e))))
    except json.JSONDecodeError as exc:
        raise LayoutError(f"{path}: not valid JSON ({exc})") from None
    return _json_homographies(path, doc, names)


def _json_homographies(path: Path, doc: Any, names: list[str]) -> Homographies:
    if isinstance(doc, list):
        H = _stack(path, "the list", doc, names)
        return Homographies(H, [None] * len(H))
    if not isinstance(doc, dict):
        raise LayoutError(f"{path}: want a list of 3x3 matrices or an object (see --help)")
    seqs = [k for k, v in doc.items() if isinstance(v, dict) and isinstance(v.get("H"), list)
            and k not in names]
    if "H" not in doc and len(seqs) == 1:  # EPFL's homographies.json: one sequence
        doc = doc[seqs[0]]
    extra = dict(
        pixel_scale=_positive(path, "image_scale", doc.get("image_scale", doc.get(
            "pixel_scale", 1.0))),
        units_per_metre=(None if doc.get("units_per_metre") is None
                         else _positive(path, "units_per_metre", doc["units_per_metre"])),
        fps=None if doc.get("fps") is None else _positive(path, "fps", doc["fps"]))
    size_key = "image_size" if "image_size" in doc else "image_size_annotations"
    if "H" in doc:
        H = _stack(path, "H", doc["H"], names)
        sizes: list[tuple[int, int] | None] = [None] * len(H)
        size = doc.get(size_key)
        if isinstance(size, list) and len(size) == len(H) and all(isinstance(s, list)
                                                                   for s in size):
            sizes = [_size(path, f"{size_key}[{i}]", s) for i, s in enumerate(size)]
        elif size is not None:
            sizes = [_size(path, size_key, size)] * len(H)
        return Homographies(H, sizes, **extra)
    missing = [n for n in names if n not in doc]
    if missing:
        raise LayoutError(f"{path}: no homography for camera(s) {missing}: want a list, "
                          f"{{\"H\": [...]}} or one entry per camera named {names}")
    H, sizes = [], []
    default = None if doc.get("image_size") is None else _size(path, "image_size",
                                                               doc["image_size"])
    for n in names:
        e = doc[n]
        if isinstance(e, dict):
            if "H" not in e:
                raise LayoutError(f"{path}: {n} lacks field 'H' (its 3x3 homography)")
            H.append(_matrix(path, f"{n}.H", e["H"]))
            sizes.append(_size(path, f"{n}.image_size", e["image_size"])
                         if "image_size" in e else default)
        else:
            H.append(_matrix(path, n, e))
            sizes.append(default)
    return Homographies(H, sizes, **extra)


# -- ground truth -----------------------------------------------------------------------------------
def read_ground_points(path: Path, frames: int, default_wh: tuple[float, float]) -> GroundFile:
    """Ground truth rows ``frame,id,X,Y`` (or ``frame,id,X,Y,w,h``), ground units, 1-based
    frames; ``w, h`` default to ``default_wh`` (ground units)."""
    t = read_table(path, ("frame", "id", "X", "Y"), "ground truth")
    if t.shape[1] not in (4, 6):
        raise LayoutError(f"{path}: ground truth rows are frame,id,X,Y (or frame,id,X,Y,w,h) in "
                          f"ground units, got {t.shape[1]} fields (a MOTChallenge gt.txt of boxes "
                          "belongs to its camera: <cam>/gt/gt.txt, <cam>/gt.txt or gt/<cam>.txt)")
    table = np.empty((len(t), 6))
    table[:, :4] = t[:, :4]
    table[:, 4:] = default_wh
    if t.shape[1] == 6:
        wh = t[:, 4:6]
        ok = np.all(np.isfinite(wh), axis=1) & np.all(wh > 0, axis=1)
        table[ok, 4:] = wh[ok]
    return GroundFile(FrameTable.of(path, table, frames))


def ground_from_boxes(cameras: list[Camera], gt_files: list[Path | None], frames: int,
                      default_wh: tuple[float, float]) -> GroundFile | None:
    """Ground truth from the cameras' gt boxes: each box's foot point through its camera's
    homography, averaged per frame and id over the cameras that see the person; None without
    boxes."""
    parts = []
    for cam, path in zip(cameras, gt_files):
        if path is None:
            continue
        t = open_gt(path, frames).rows.table
        if not len(t):
            continue
        uv = np.stack([t[:, 2] + t[:, 4] / 2.0, t[:, 3] + t[:, 5]], axis=1)
        xy = cam.to_ground(uv)
        ok = np.all(np.isfinite(xy), axis=1)
        parts.append(np.column_stack([t[ok, 0], t[ok, 1], xy[ok]]))
    if not parts:
        return None
    rows = np.vstack(parts)
    keys, inverse = np.unique(rows[:, :2], axis=0, return_inverse=True)
    inverse = inverse.ravel()
    count = np.bincount(inverse, minlength=len(keys))
    xy = np.stack([np.bincount(inverse, rows[:, 2 + i], len(keys)) for i in (0, 1)], axis=1)
    table = np.column_stack([keys, xy / count[:, None], np.tile(default_wh, (len(keys), 1))])
    return GroundFile(FrameTable.of(Path("<ground truth from the cameras' gt boxes>"), table,
                                    frames))


# -- the folder -------------------------------------------------------------------------------------
def read_layout(directory: str | os.PathLike[str], options: ImportOptions | None = None,
                frames: int | None = None) -> Imported:
    """A folder of detection files without ``calibration.json`` (:data:`LAYOUTS`) with the
    command line's ``options``, as a calibration, ground truth and notes."""
    opts = options or ImportOptions()
    d = Path(directory).resolve()
    layout, cams = find_cameras(d, opts.ground_truth)
    names = [c.name for c in cams]
    hpath = opts.homographies
    if hpath is None:
        hpath = next((d / f for f in HOMOGRAPHY_FILES if (d / f).is_file()), None)
        if hpath is None:
            raise LayoutError(f"{d}: no homographies for cameras {', '.join(names)}: pass "
                              f"--homographies FILE or put {' / '.join(HOMOGRAPHY_FILES)} in the "
                              "folder (image-to-ground, one 3x3 per camera, in camera order)")
    homs = read_homographies(hpath, names)
    infos = [read_seqinfo(c.seqinfo) if c.seqinfo else {} for c in cams]
    notes = [f"{d.name}: {len(cams)} camera(s) from {layout} det files: "
             + ", ".join(f"{i}={c.det.relative_to(d) if c.det.is_relative_to(d) else c.det}"
                         for i, c in enumerate(cams))
             + f"; homographies from {hpath.name}"]
    fps = opts.fps or homs.fps or next((i["frameRate"] for i in infos if "frameRate" in i), None)
    if fps is None:
        fps = DEFAULT_FPS
        notes.append(f"{d.name}: no frame rate given (--fps, seqinfo.ini frameRate or fps in "
                     f"the homographies JSON): assuming {DEFAULT_FPS:g} frames/s")
    upm = opts.units_per_metre or homs.units_per_metre
    if upm is None:
        upm = 1.0
        notes.append(f"{d.name}: no units_per_metre given (--units-per-metre or units_per_metre "
                     "in the homographies JSON): ground units taken as metres")
    cameras = []
    for i, (c, info) in enumerate(zip(cams, infos)):
        size = opts.image_size or (
            (int(info["imWidth"]), int(info["imHeight"])) if "imWidth" in info
            and "imHeight" in info else homs.image_size[i])
        if size is None:
            raise LayoutError(f"{d}: image size of camera {c.name} unknown: pass --image-size "
                              f"WxH, or give {c.name}/seqinfo.ini (imWidth, imHeight) or "
                              f"image_size in the homographies JSON")
        try:
            cameras.append(Camera(id=i, image_size=size, G=homs.H[i],
                                  pixel_scale=homs.pixel_scale, fps=fps))
        except GeometryError as exc:
            raise LayoutError(f"{hpath}: camera {c.name}: {exc}") from None
    files = [CameraFiles(c.det, c.descriptors, False, c.gt) for c in cams]
    gpath = opts.ground_truth
    if gpath is None:
        gpath = next((d / f for f in GROUND_FILES if (d / f).is_file()), None)
    elif not Path(gpath).is_file():
        raise LayoutError(f"ground truth file not found: {gpath}")
    cal = Calibration(path=d / CALIBRATION, cameras=cameras, files=files, fps=float(fps),
                      units_per_metre=float(upm), frames=None,  # no file states a length
                      gt_ground=Path(gpath) if gpath is not None else d / GROUND_FILES[0],
                      name=d.name)
    n = cal.frame_count() if frames is None else frames
    if n <= 0:
        raise LayoutError(f"{d}: no frames in the det files")
    wh = (PERSON_WH_M[0] * upm, PERSON_WH_M[1] * upm)
    if gpath is not None:
        ground = read_ground_points(Path(gpath), n, wh)
    else:
        ground = ground_from_boxes(cameras, [c.gt if c.gt.is_file() else None for c in cams],
                                   n, wh)
        if ground is not None:
            notes.append(f"{d.name}: ground truth from the cameras' gt boxes (foot points through "
                         "the homographies, averaged per frame and id: ids must name the same "
                         "person in every camera)")
        else:
            notes.append(f"{d.name}: no ground truth (gt_ground.csv, --ground-truth or gt "
                         "boxes): tracks are written, metrics are undefined")
    return Imported(cal, ground, tuple(notes), tuple(names))
