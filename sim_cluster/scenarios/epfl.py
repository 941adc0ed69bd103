"""Real data: the EPFL multi-camera pedestrian ground truth (Terrace, Campus) as a scenario.

Two annotation formats are read, one file per camera, with identities consistent across cameras:

``mot-csv`` (the files under ``<data root>/epfl_pom/``, see its PROVENANCE.md):
    ``frame,id,x,y,w,h,lost,occluded,generated,label`` integers, CRLF, 0-based frames at 25 fps,
    boxes top-left + size in the 360x288 annotation images. Rows with ``lost = 1`` are skipped.
``vatic`` (the original EPFL/VATIC text files):
    ``track_id xmin ymin xmax ymax frame lost occluded generated label`` separated by spaces
    (``label`` may be quoted); ``w = xmax - xmin``, ``h = ymax - ymin``; ``lost = 1`` rows skipped.

In both a frame is a whole number in ``0..MAX_FRAME - 1`` (``edge_node.formats.detfile``: the
files state no length); anything else, and bytes that are not UTF-8, is an
:class:`EpflFormatError` naming the file and the line (the byte offset too).

Calibration is a JSON file (``epfl_pom/homographies.json``, ``edge_node/formats/homographies.py``)
holding per sequence the image-to-ground homographies ``H`` (camera order = list order), the
``image_scale`` they expect (``g = H [u s, v s, 1]``, taken from the file, never assumed) and the
annotation image size.

Ground truth built from the annotations (``GroundTruth``):

* ``ids[k]``: everyone annotated in at least one camera at frame ``k`` (a person hidden from every
  camera is not in the ground truth: there is no other source of their position).
* ``xy[k]``: the mean of that person's box foot points ``(x + w/2, y + h)`` projected through the
  homographies of the cameras that see them. Across cameras these projections disagree by a median
  of about 25 ground units (0.8 m) on Terrace (calibration and foot-point error), so the mean is
  itself an estimate, good to a few tens of centimetres.
* ``wh[k]``: a per-person typical cylinder: the median over that person's annotations (boxes not
  touching the image border) of ``Camera.box_to_cylinder``'s width and height, in ground units;
  0.5 m x 1.75 m (``units_per_metre`` scaled) when a person has no usable box. These are box
  measures, consistent with what a tracker fed by ``box_to_cylinder`` estimates, not body sizes:
  on Terrace about 30-37 x 90-99 units (~1.1 m x 3.2 m at 30 units/m), because annotated boxes
  carry slack and, without ``P``, the height is the width times the box's aspect ratio.
* ``boxes[c][k]``: camera ``c``'s annotated boxes at frame ``k``.

Detections ("gt-replay"): each camera's annotated boxes go through ``detector_model.detect``, the
same miss / false-positive / box-noise model as the synthetic world, with the visible fraction of
each box computed from the boxes in front of it in the same image (a larger bottom edge is closer to
the camera), and synthetic appearance per real identity from ``AppearanceModel``.

Frames come on demand (:func:`open_epfl_gt`, a ``ScenarioStream``; :func:`load_epfl_gt`
materialises): the annotation files are read once (they are the sequence, not the run), and so
are each person's typical size and the scenario's ``area``; the ground truth and the detections
are made a chunk of ``CHUNK_FRAMES`` frames at a time (:class:`GtReplay`), camera ``c``'s
detector drawing chunk ``j`` from its own generator ``default_rng([seed, c, j])``. Frame ``k``
is therefore the same whatever the run's length and whichever frames were read before it. A
camera process (``ScenarioStream.camera``) replays its own camera's boxes only (``focus``).

Data root resolution (first that applies): an explicit ``data_root`` argument (the CLI's
``--data-root``, or ``[source] data_root`` in a scenario file) > environment ``DMTT_DATA`` >
``<repo root>/../shared/data`` (repo root = parent of the ``sim_cluster`` package directory) >
``./../shared/data`` from the working directory. Never copy the data into the repository.
"""
from __future__ import annotations

import copy
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.formats.detfile import MAX_FRAME
from edge_node.formats.homographies import (FILE, HomographiesError, read_homographies,
                                            sequence_cameras, sequence_entry)
from edge_node.formats.text import read_text, text_lines
from edge_node.geometry import Camera
from protocol.errors import DmttError
from sim_cluster.scenarios.data import (CHUNK_FRAMES, Frame, GroundTruth, ScenarioData,
                                        ScenarioStream)
from sim_cluster.scenarios.files import ScenarioError, scenario_table
from sim_cluster.scenarios.synthetic.appearance import AppearanceModel, AppearanceParams
from sim_cluster.scenarios.synthetic.detector_model import DetectorParams, detect_frames
from sim_cluster.scenarios.synthetic.schema import (appearance_params_from_table,
                                                    detector_params_from_table)

ENV_DATA_ROOT = "DMTT_DATA"
EPFL_DIR = "epfl_pom"
CALIBRATION_FILE = FILE
DEFAULT_FPS = 25.0
PERSON_WIDTH_M = 0.5
PERSON_HEIGHT_M = 1.75


class DataNotFoundError(DmttError, FileNotFoundError):
    """The data root or a data file is missing; the message names every path tried."""


class EpflFormatError(DmttError, ValueError):
    """An annotation or calibration file that cannot be parsed; the message names file and field."""


# -- data root --------------------------------------------------------------------------------------
def repo_root() -> Path:
    """The repository root: the parent of the ``sim_cluster`` package directory."""
    return Path(__file__).resolve().parents[2]  # sim_cluster/scenarios/epfl.py


def data_root_candidates(data_root: str | os.PathLike[str] | None = None) -> list[Path]:
    """The data roots to try, in order: explicit argument, else ``$DMTT_DATA``, else the defaults."""
    if data_root is not None and str(data_root) != "":
        return [Path(data_root).expanduser()]
    env = os.environ.get(ENV_DATA_ROOT, "")
    if env:
        return [Path(env).expanduser()]
    return [repo_root().parent / "shared" / "data", Path.cwd() / ".." / "shared" / "data"]


def resolve_data_root(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The first existing data root (see the module docstring); ``DataNotFoundError`` otherwise.

    An explicit argument or ``$DMTT_DATA`` that does not exist is an error, not a fall-through.
    """
    tried = data_root_candidates(data_root)
    for p in tried:
        if p.is_dir():
            return p.resolve()
    source = ("argument data_root" if data_root not in (None, "")
              else f"${ENV_DATA_ROOT}" if os.environ.get(ENV_DATA_ROOT) else "default locations")
    raise DataNotFoundError(
        f"data root not found ({source}); tried: {', '.join(str(p) for p in tried)}. "
        f"Pass --data-root or set {ENV_DATA_ROOT} to the folder holding {EPFL_DIR}/.")


def epfl_dir(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The folder with ``homographies.json``: ``<root>/epfl_pom`` or the root itself."""
    root = resolve_data_root(data_root)
    tried = [root / EPFL_DIR, root]
    for d in tried:
        if (d / CALIBRATION_FILE).is_file():
            return d
    raise DataNotFoundError(f"no {CALIBRATION_FILE} in: {', '.join(str(d) for d in tried)}")


# -- annotation files -------------------------------------------------------------------------------
@dataclass
class Annotations:
    """One camera's annotated boxes, one row per box, sorted by frame (stable)."""

    frames: np.ndarray  # (n,) int, 0-based
    ids: np.ndarray  # (n,) int
    boxes: np.ndarray  # (n, 4) float (x, y, w, h) px
    generated: np.ndarray  # (n,) bool, interpolated by VATIC

    def sorted(self) -> Annotations:
        o = np.argsort(self.frames, kind="stable")
        return Annotations(self.frames[o], self.ids[o], self.boxes[o], self.generated[o])


def _rows(path: Path) -> list[tuple[int, str]]:
    try:
        text = read_text(path, lambda e: EpflFormatError(str(e)))
    except FileNotFoundError as exc:
        raise DataNotFoundError(f"annotation file not found: {path}") from exc
    return [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())
            if ln.strip() and not ln.lstrip().startswith("#")]


def _num(path: Path, line: int, field: str, s: str) -> float:
    try:
        return float(s)
    except ValueError as exc:
        raise EpflFormatError(f"{path}:{line}: field {field!r} is not a number: {s!r}") from exc


def _frame(path: Path, line: int, field: str, s: str) -> float:
    """The 0-based frame number ``s`` (module docstring)."""
    v = _num(path, line, field, s)
    if not (math.isfinite(v) and v == round(v) and 0 <= v < MAX_FRAME):
        raise EpflFormatError(f"{path}:{line}: field {field!r} must be a whole number in "
                              f"0..{MAX_FRAME - 1} (0-based, MAX_FRAME), got {s!r}")
    return v


def read_mot_csv(path: str | os.PathLike[str]) -> Annotations:
    """Read ``frame,id,x,y,w,h,lost,occluded,generated,label`` (CRLF or LF; optional header)."""
    path = Path(path)
    fast = _read_csv_fast(path)
    if fast is not None:
        return fast
    names = ("frame", "id", "x", "y", "w", "h", "lost", "occluded", "generated", "label")
    out: list[list[float]] = []
    for n, (line, text) in enumerate(_rows(path)):
        f = [s.strip() for s in text.split(",")]
        if n == 0 and f and not f[0].lstrip("-").replace(".", "", 1).isdigit():
            continue  # a header line
        if len(f) < 6:
            raise EpflFormatError(f"{path}:{line}: expected at least 6 comma-separated fields "
                                  f"({','.join(names)}), got {len(f)}")
        vals = [_num(path, line, names[i], f[i]) for i in range(min(len(f), 9))]
        vals[0] = _frame(path, line, names[0], f[0])
        lost = vals[6] if len(vals) > 6 else 0.0
        if lost == 1:
            continue
        gen = vals[8] if len(vals) > 8 else 0.0
        out.append([vals[0], vals[1], vals[2], vals[3], vals[4], vals[5], gen])
    return _annotations(path, out)


def _read_csv_fast(path: Path) -> Annotations | None:
    """The common case (numeric, >= 9 columns, no header, good frames) through numpy; None to
    parse slowly."""
    try:
        a = np.loadtxt(path, delimiter=",", dtype=float, ndmin=2, comments="#")
    except FileNotFoundError as exc:
        raise DataNotFoundError(f"annotation file not found: {path}") from exc
    except ValueError:  # bytes that are not UTF-8 too
        return None  # header, ragged rows or bad fields: the line parser names the culprit
    if a.shape[0] == 0 or a.shape[1] < 9:
        return None
    f = a[:, 0]
    if not np.all(np.isfinite(f) & (f == np.round(f)) & (f >= 0) & (f < MAX_FRAME)):
        return None  # a bad frame: the line parser names its line
    a = a[a[:, 6] != 1]
    return _annotations(path, np.column_stack([a[:, :6], a[:, 8]]).tolist())


def read_vatic(path: str | os.PathLike[str]) -> Annotations:
    """Read ``track_id xmin ymin xmax ymax frame lost occluded generated label`` (spaces)."""
    path = Path(path)
    names = ("track_id", "xmin", "ymin", "xmax", "ymax", "frame", "lost", "occluded", "generated")
    out: list[list[float]] = []
    for line, text in _rows(path):
        f = text.split()
        if len(f) < 9:
            raise EpflFormatError(f"{path}:{line}: expected 10 space-separated fields "
                                  f"({' '.join(names)} label), got {len(f)}")
        v = [_num(path, line, names[i], f[i]) for i in range(9)]
        v[5] = _frame(path, line, names[5], f[5])
        if v[6] == 1:
            continue
        out.append([v[5], v[0], v[1], v[2], v[3] - v[1], v[4] - v[2], v[8]])
    return _annotations(path, out)


def _annotations(path: Path, rows: list[list[float]]) -> Annotations:
    a = np.array(rows, dtype=float).reshape(-1, 7)
    if np.any(a[:, 4:6] <= 0):
        line = int(np.argmax(np.any(a[:, 4:6] <= 0, axis=1)))
        raise EpflFormatError(f"{path}: box {line + 1} (data row) has non-positive width or height")
    return Annotations(a[:, 0].astype(np.int64), a[:, 1].astype(np.int64), a[:, 2:6].copy(),
                       a[:, 6] != 0).sorted()


def _first_row(path: Path) -> str:
    try:
        for _, line in text_lines(path, lambda e: EpflFormatError(str(e))):
            if line.strip() and not line.lstrip().startswith("#"):
                return line
    except FileNotFoundError as exc:
        raise DataNotFoundError(f"annotation file not found: {path}") from exc
    return ""


def read_annotations(path: str | os.PathLike[str], fmt: str = "auto") -> Annotations:
    """Read one camera's annotations; ``fmt`` is ``mot-csv``, ``vatic`` or ``auto`` (by content)."""
    path = Path(path)
    if fmt == "auto":
        fmt = "mot-csv" if "," in _first_row(path) else "vatic"
    if fmt == "mot-csv":
        return read_mot_csv(path)
    if fmt == "vatic":
        return read_vatic(path)
    raise EpflFormatError(f"{path}: unknown annotation format {fmt!r} (mot-csv, vatic, auto)")


# -- calibration ------------------------------------------------------------------------------------
def read_calibration(path: str | os.PathLike[str], sequence: str,
                     fps: float = DEFAULT_FPS) -> tuple[list[Camera], dict[str, Any]]:
    """Cameras of ``sequence`` (a key of the calibration JSON) and its entry (for ``sequence`` name).

    Each camera gets ``G = H[c]``, ``pixel_scale = image_scale``, ``image_size`` from
    ``image_size_annotations`` (default 360x288): ``edge_node/formats/homographies.py``.
    """
    try:
        entry = sequence_entry(read_homographies(path), sequence, path)
        return sequence_cameras(entry, sequence, path, fps=fps), entry
    except FileNotFoundError as exc:
        raise DataNotFoundError(f"calibration file not found: {path}") from exc
    except HomographiesError as exc:
        raise EpflFormatError(str(exc)) from exc


# -- a sequence -------------------------------------------------------------------------------------
@dataclass
class EpflSequence:
    """A sequence's cameras and per-camera annotations (frames as in the files)."""

    name: str
    cameras: list[Camera]
    annotations: list[Annotations]

    @property
    def frame_range(self) -> tuple[int, int]:
        """First and last annotated frame over all cameras (inclusive)."""
        fr = [a.frames for a in self.annotations if len(a.frames)]
        if not fr:
            return (0, -1)
        return int(min(f.min() for f in fr)), int(max(f.max() for f in fr))


def load_sequence(sequence: str, data_root: str | os.PathLike[str] | None = None,
                  annotations: list[str] | None = None, calibration: str | None = None,
                  fmt: str = "auto", fps: float = DEFAULT_FPS) -> EpflSequence:
    """Load ``sequence`` (``terrace``, ``campus``: a key of the calibration file).

    By default the files are ``<epfl dir>/<key>/<entry sequence>-c<i>.gt.csv``; ``annotations``
    (paths relative to the data root, or absolute) and ``calibration`` override, e.g. for the
    original VATIC files.
    """
    if calibration is not None:
        root = resolve_data_root(data_root)
        cal = Path(calibration) if Path(calibration).is_absolute() else root / calibration
        base = root
    else:
        base = epfl_dir(data_root)
        cal = base / CALIBRATION_FILE
    cams, entry = read_calibration(cal, sequence, fps)
    if annotations is None:
        stem = str(entry.get("sequence", sequence))
        files = [base / sequence / f"{stem}-c{c}.gt.csv" for c in range(len(cams))]
    else:
        root = resolve_data_root(data_root)
        files = [Path(p) if Path(p).is_absolute() else root / p for p in annotations]
        if len(files) != len(cams):
            raise EpflFormatError(f"{len(files)} annotation files for {len(cams)} cameras of "
                                  f"{sequence!r} in {cal}")
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise DataNotFoundError(f"annotation files not found: {', '.join(missing)}")
    return EpflSequence(sequence, cams, [read_annotations(f, fmt) for f in files])


# -- ground truth -----------------------------------------------------------------------------------
def _foot_points(cam: Camera, boxes: np.ndarray) -> np.ndarray:
    uv = np.stack([boxes[:, 0] + boxes[:, 2] / 2.0, boxes[:, 1] + boxes[:, 3]], axis=1)
    return cam.to_ground(uv) if len(uv) else np.zeros((0, 2))


def _cylinder_sizes(cam: Camera, boxes: np.ndarray) -> np.ndarray:
    """``Camera.box_to_cylinder``'s (w, h) for many boxes."""
    return cam.boxes_to_cylinders(boxes)[:, 2:]


def _typical_sizes(seq: EpflSequence, units_per_metre: float) -> dict[int, np.ndarray]:
    """Per person: median cylinder (w, h) from box_to_cylinder over boxes off the image border."""
    samples: dict[int, list[np.ndarray]] = {}
    for cam, ann in zip(seq.cameras, seq.annotations):
        W, H = cam.image_size
        b = ann.boxes
        inner = (b[:, 0] > 1) & (b[:, 1] > 1) & (b[:, 0] + b[:, 2] < W - 1) & (b[:, 1] + b[:, 3] < H - 1)
        if cam.P is not None and inner.sum() > 2000:  # the per-box path: an even subsample suffices
            keep = np.flatnonzero(inner)
            inner = np.zeros_like(inner)
            inner[keep[np.linspace(0, len(keep) - 1, 2000).astype(int)]] = True
        wh = _cylinder_sizes(cam, b[inner])
        ok = np.all(np.isfinite(wh), axis=1) & np.all(wh > 0, axis=1)
        for pid in np.unique(ann.ids[inner][ok]):
            samples.setdefault(int(pid), []).append(wh[ok][ann.ids[inner][ok] == pid])
    default = np.array([PERSON_WIDTH_M, PERSON_HEIGHT_M]) * units_per_metre
    ids = set(samples) | {int(i) for a in seq.annotations for i in np.unique(a.ids)}
    return {pid: (np.median(np.vstack(samples[pid]), axis=0) if pid in samples else default.copy())
            for pid in ids}


def _camera_rows(ann: Annotations, start: int, frames: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A camera's annotations of sequence frames ``start .. start+frames-1``: ``(frame, ids,
    boxes)`` in frame order, frames counted from ``start``."""
    lo, hi = np.searchsorted(ann.frames, [start, start + frames])
    return ann.frames[lo:hi] - start, ann.ids[lo:hi], ann.boxes[lo:hi]


def _people(seq: EpflSequence, units_per_metre: float) -> tuple[np.ndarray, np.ndarray]:
    """Every annotated person id, sorted, and their typical cylinder (w, h) (``_typical_sizes``):
    computed once per sequence from its annotations, whatever frames a run reads."""
    ids = np.array(sorted({int(i) for a in seq.annotations for i in np.unique(a.ids)}),
                   dtype=np.int64)
    sizes = _typical_sizes(seq, units_per_metre)
    return ids, np.array([sizes[int(p)] for p in ids]).reshape(-1, 2)


def _ground_truth(seq: EpflSequence, start: int, frames: int, people: np.ndarray,
                  sizes: np.ndarray) -> GroundTruth:
    """Ground truth for sequence frames ``start .. start+frames-1`` (the module docstring);
    ``people`` (sorted ids) and ``sizes`` from :func:`_people`."""
    sum_xy = np.zeros((frames, len(people), 2))
    count = np.zeros((frames, len(people)), dtype=int)
    boxes: list[list[tuple[np.ndarray, np.ndarray]]] = []
    for cam, ann in zip(seq.cameras, seq.annotations):
        fr, ids, bx = _camera_rows(ann, start, frames)
        cols = np.searchsorted(people, ids)
        xy = _foot_points(cam, bx)
        ok = np.all(np.isfinite(xy), axis=1)
        np.add.at(sum_xy, (fr[ok], cols[ok]), xy[ok])
        np.add.at(count, (fr[ok], cols[ok]), 1)
        cuts = np.searchsorted(fr, np.arange(frames + 1))
        boxes.append([(ids[cuts[k]:cuts[k + 1]].copy(), bx[cuts[k]:cuts[k + 1]].copy())
                      for k in range(frames)])
    t_ids, t_xy, t_wh = [], [], []
    for k in range(frames):
        present = count[k] > 0
        t_ids.append(people[present])
        t_xy.append(sum_xy[k, present] / count[k, present][:, None])
        t_wh.append(sizes[present].copy())
    return GroundTruth(ids=t_ids, xy=t_xy, wh=t_wh, boxes=boxes)


def build_ground_truth(seq: EpflSequence, start: int, frames: int,
                       units_per_metre: float) -> GroundTruth:
    """Ground truth for sequence frames ``start .. start+frames-1`` (scenario frames ``0..``)."""
    return _ground_truth(seq, start, frames, *_people(seq, units_per_metre))


def _area(seq: EpflSequence, start: int, frames: int,
          people: np.ndarray) -> tuple[float, float, float, float]:
    """``(xmin, xmax, ymin, ymax)``: the extent of the ground truth's positions over sequence
    frames ``start .. start+frames-1`` (the mean foot point per person and frame, as
    :func:`_ground_truth`), widened on every side by 5 % of its larger side (1 unit when there
    is one position or none); from the annotation arrays, without building the frames."""
    fr, col, xy = [], [], []
    for cam, ann in zip(seq.cameras, seq.annotations):
        f, ids, bx = _camera_rows(ann, start, frames)
        p = _foot_points(cam, bx)
        ok = np.all(np.isfinite(p), axis=1)
        fr.append(f[ok])
        col.append(np.searchsorted(people, ids[ok]))
        xy.append(p[ok])
    key = np.concatenate(fr) * max(len(people), 1) + np.concatenate(col)
    _, slot = np.unique(key, return_inverse=True)
    pts = np.vstack(xy)
    n = np.bincount(slot)
    allxy = (np.stack([np.bincount(slot, pts[:, 0]) / n, np.bincount(slot, pts[:, 1]) / n], axis=1)
             if len(slot) else np.zeros((1, 2)))
    lo, hi = allxy.min(axis=0), allxy.max(axis=0)
    margin = 0.05 * float(np.max(hi - lo)) if len(allxy) > 1 else 1.0
    return (float(lo[0] - margin), float(hi[0] + margin), float(lo[1] - margin),
            float(hi[1] + margin))


def visible_fractions(boxes: np.ndarray, frame: np.ndarray | None = None,
                      grid: tuple[int, int] = (6, 12)) -> np.ndarray:
    """Fraction of each box not covered by boxes closer to the camera in the same frame.

    Closer means a larger bottom edge (ground-plane cameras looking down). ``boxes`` (m, 4),
    ``frame`` (m,) the frame of each box (all one frame when None). Estimated on a ``grid``
    (columns, rows) of sample points per box; ``(m,)`` in ``[0, 1]``.
    """
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    m = len(b)
    fr = np.zeros(m, dtype=np.int64) if frame is None else np.asarray(frame, dtype=np.int64)
    if m == 0:
        return np.ones(0)
    order = np.argsort(fr, kind="stable")
    b, fr = b[order], fr[order]
    _, start, size = np.unique(fr, return_index=True, return_counts=True)
    grp = np.repeat(np.arange(len(start)), size)
    n_pairs = size[grp]  # partners per row (its frame's size, itself included)
    I = np.repeat(np.arange(m), n_pairs)
    first = np.repeat(np.cumsum(n_pairs) - n_pairs, n_pairs)
    J = np.repeat(start[grp], n_pairs) + (np.arange(len(I)) - first)
    bottom = b[:, 1] + b[:, 3]
    sel = bottom[J] > bottom[I]  # J stands in front of I
    I, J = I[sel], J[sel]
    gx = (np.arange(grid[0]) + 0.5) / grid[0]
    gy = (np.arange(grid[1]) + 0.5) / grid[1]
    u = (b[I, 0:1] + b[I, 2:3] * np.tile(gx, grid[1])[None, :])  # (pairs, S)
    v = (b[I, 1:2] + b[I, 3:4] * np.repeat(gy, grid[0])[None, :])
    inside = ((u >= b[J, 0:1]) & (u <= b[J, 0:1] + b[J, 2:3])
              & (v >= b[J, 1:2]) & (v <= b[J, 1:2] + b[J, 3:4]))
    covered = np.zeros((m, grid[0] * grid[1]), dtype=bool)
    np.logical_or.at(covered, I, inside)
    vis = np.empty(m)
    vis[order] = 1.0 - covered.mean(axis=1)
    return vis


# -- the scenario -----------------------------------------------------------------------------------
class GtReplay:
    """The ``chunk`` of an ``epfl-gt`` :class:`~sim_cluster.scenarios.data.ScenarioStream`.

    Chunk ``j`` is scenario frames ``j * CHUNK_FRAMES ..`` (sequence frames from ``start`` on),
    always whole, also past the run's last frame: its ground truth is built from those frames'
    annotations, and each camera's annotated boxes go through ``detector_model.detect_frames``
    with the camera's own generator for the chunk, ``default_rng([seed, c, j])``. So frame ``k``
    depends neither on the run's length nor on the frames read before it, and a camera's
    detections not on the other cameras. :meth:`only` makes some cameras' detections and image
    ground truth (a camera process needs its own), the same as the whole chunk's.
    """

    def __init__(self, seq: EpflSequence, start: int, units_per_metre: float, detector: Any,
                 appearance: AppearanceModel, seed: int):
        self.seq, self.start, self.seed = seq, start, seed
        self.detector, self.appearance = detector, appearance
        self.people, self.sizes = _people(seq, units_per_metre)
        self.cameras: list[int] | None = None  # all

    def only(self, cameras: list[int]) -> GtReplay:
        """The same replay making cameras ``cameras``' detections and image ground truth only
        (the others' are empty); the ``focus`` of the stream."""
        focused = copy.copy(self)
        focused.cameras = list(cameras)
        return focused

    def __call__(self, j: int) -> list[Frame]:
        F = CHUNK_FRAMES
        truth = _ground_truth(self.seq, self.start + j * F, F, self.people, self.sizes)
        C = len(self.seq.cameras)
        made = range(C) if self.cameras is None else [c for c in range(C) if c in self.cameras]
        no_boxes = (np.zeros(0, np.int64), np.zeros((0, 4)))
        frames = [Frame(detections=[[] for _ in range(C)],
                        detection_truth=[np.zeros(0, np.int64)] * C,
                        ids=truth.ids[k], xy=truth.xy[k], wh=truth.wh[k],
                        boxes=[truth.boxes[c][k] if c in made else no_boxes for c in range(C)])
                  for k in range(F)]
        for c in made:
            cam, ann = self.seq.cameras[c], self.seq.annotations[c]
            fr, ids, bx = _camera_rows(ann, self.start + j * F, F)
            out = detect_frames(cam, fr, ids, bx, visible_fractions(bx, fr), F, self.detector,
                                self.appearance, np.random.default_rng([self.seed, c, j]))
            for f, (dets, true_ids) in zip(frames, out):
                f.detections[c] = dets
                f.detection_truth[c] = np.asarray(true_ids, dtype=np.int64)
        return frames


def open_epfl_gt(sequence: str, *, seed: int = 0, frames: int | None = None,
                 start_frame: int | None = None, units_per_metre: float = 30.0,
                 detector: Any = None, appearance: Any = None,
                 data_root: str | os.PathLike[str] | None = None, name: str | None = None,
                 annotations: list[str] | None = None, calibration: str | None = None,
                 fmt: str = "auto", fps: float = DEFAULT_FPS) -> ScenarioStream:
    """An EPFL sequence as a ``ScenarioStream`` with GT-replay detections, frames on demand
    (:class:`GtReplay`; the annotation files are read here, once).

    ``start_frame`` defaults to the first annotated frame; ``frames`` to the rest of the sequence
    (clipped to the last annotated frame). ``detector``/``appearance`` are ``DetectorParams`` and
    ``AppearanceParams`` (defaults when None).
    """
    if units_per_metre <= 0:
        raise EpflFormatError(f"units_per_metre must be positive, got {units_per_metre}")
    seq = load_sequence(sequence, data_root, annotations, calibration, fmt, fps)
    first, last = seq.frame_range
    start = first if start_frame is None else int(start_frame)
    if start < 0 or start > last:
        raise EpflFormatError(f"start_frame {start} outside the annotated frames {first}..{last} "
                              f"of {sequence!r}")
    n = last - start + 1 if frames is None else min(int(frames), last - start + 1)
    if n <= 0:
        raise EpflFormatError(f"frames must be positive, got {frames}")
    detector = detector if detector is not None else DetectorParams()
    app = AppearanceModel(appearance if appearance is not None else AppearanceParams(), seed)
    replay = GtReplay(seq, start, float(units_per_metre), detector, app, seed)
    return ScenarioStream(
        name=name or f"{sequence}-gt", cameras=seq.cameras, frames=n, fps=fps,
        units_per_metre=float(units_per_metre), chunk=replay, chunk_frames=CHUNK_FRAMES,
        area=_area(seq, start, n, replay.people), seed=seed, focus=replay.only)


def load_epfl_gt(sequence: str, **kwargs: Any) -> ScenarioData:
    """:func:`open_epfl_gt` (same arguments) with every frame in memory."""
    return open_epfl_gt(sequence, **kwargs).materialise()


def scenario_from_table(raw: dict[str, Any], path: Path, seed: int, frames: int | None,
                        data_root: str | os.PathLike[str] | None = None) -> ScenarioStream:
    """The scenario loader of kind ``epfl-gt`` (``loader.SCENARIO_KINDS``).

    Top level: ``name``, ``description``, ``seed``, ``frames`` (the ``frames`` argument overrides
    it), ``fps``. ``[source]``: ``kind``, ``sequence`` (required; a key of the calibration file),
    ``start_frame``, ``units_per_metre``, ``data_root`` (relative to the scenario file),
    ``annotations`` (list of per-camera files), ``calibration``, ``format``. ``[detector]`` and
    ``[appearance]`` as in synthetic scenarios. ``data_root`` (the CLI's ``--data-root``)
    overrides ``[source] data_root``. Errors are ``ScenarioError`` naming file and field;
    missing data raises ``DataNotFoundError`` (an ``OSError``).
    """
    file = Path(path).name
    top = scenario_table(raw, file)
    name = top.string("name", Path(path).stem)
    top.string("description", "")
    top.integer("seed", 0, lo=0)  # validated; the resolved seed is passed in
    n = top.integer("frames", None, lo=1)
    n = frames if frames is not None else n
    fps = top.number("fps", DEFAULT_FPS, lo=0.0, lo_open=True)
    src = top.table("source")
    src.string("kind")
    sequence = src.string("sequence")
    start = src.integer("start_frame", None, lo=0)
    upm = src.number("units_per_metre", 30.0, lo=0.0, lo_open=True)
    root = src.string("data_root", None)
    ann = src.raw("annotations", None)
    if ann is not None and (not isinstance(ann, list) or not all(isinstance(a, str) for a in ann)):
        raise src.error("annotations", f"must be a list of file paths, got {ann!r}")
    cal = src.string("calibration", None)
    fmt = src.string("format", "auto")
    if fmt not in ("auto", "mot-csv", "vatic"):
        raise src.error("format", f"must be one of auto, mot-csv, vatic, got {fmt!r}")
    src.finish()
    detector = detector_params_from_table(top.table("detector"))
    appearance = appearance_params_from_table(top.table("appearance"))
    top.finish()
    if data_root is None and root:
        data_root = Path(root).expanduser()
        if not data_root.is_absolute():
            data_root = Path(path).parent / data_root  # relative to the scenario file
    try:
        return open_epfl_gt(sequence, seed=seed, frames=n, start_frame=start,
                            units_per_metre=upm, detector=detector, appearance=appearance,
                            data_root=data_root, name=name, annotations=ann, calibration=cal,
                            fmt=fmt, fps=fps)
    except EpflFormatError as exc:
        raise ScenarioError(file, None, str(exc)) from None
