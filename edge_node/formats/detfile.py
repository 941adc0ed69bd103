"""The det-file format: MOTChallenge ``det.txt`` (+ descriptors ``.npy``), ``gt.txt`` and
``gt_ground.csv``, read and written here. A det-files directory ties them together with a
``calibration.json`` (:mod:`edge_node.formats.calibration`, where the layout is described).
Camera processes read one camera's files (a det-file source), the simulator reads and writes
whole directories (``sim_cluster export-detections``); both use this module.

Frames are 1-based in every file (MOTChallenge); frame ``k`` of a run is file frame ``k + 1``.
Boxes are pixels, top-left corner and size::

    det.txt        frame,id,x,y,w,h,conf,-1,-1,-1   (id: -1, or the true person id when known)
    det.npy        optional: (rows, D) descriptors, row i for det.txt's data row i; an all-NaN
                   row means "no descriptor"
    gt.txt         frame,id,x,y,w,h,consider,class,vis (rows with consider = 0 or a class other
                   than 1, pedestrian, are skipped, as MOTChallenge evaluation does)
    gt_ground.csv  frame,id,x,y,w,h in ground units (may start with # comment lines)

Frames are read on demand: :func:`open_det`, :func:`open_gt` and :func:`open_gt_ground` parse a
file once into one numpy table (a few numbers per row: the file, not the run), validate it, and
give frame ``k``'s rows when asked (a binary search in the rows sorted by frame; nothing is held
per frame). ``DetFile.detections(k)`` builds frame ``k``'s :class:`Detection` objects then; its
descriptors stay on disk (the ``.npy`` is memory-mapped) and are read per frame. So a camera
process replaying 100,000 frames holds its det file's table, not 100,000 lists of detections.

Every row's first six fields must be finite numbers, ``frame`` a whole number >= 1 and ``id`` a
whole number; a ``det.txt`` box must have ``w > 0`` and ``h > 0``; a descriptor row is all finite
or all NaN; ``frame`` is at most the source's length where a file states it (the ``frames`` of
its ``calibration.json``: a :class:`FrameBound`), else at most :data:`MAX_FRAME`. Anything else is
a :class:`DetFilesError` naming the file, the line and the field (a NaN box would otherwise reach
the tracker's assignment and stop the node). Fields after the sixth may be NaN (a NaN confidence
reads as 1.0). Bytes that are not UTF-8 (a binary file) are a :class:`DetFilesError` too, naming
the line and the byte offset.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from edge_node.core.types import Detection
from edge_node.formats.text import text_lines
from protocol.errors import DmttError

BOX_FMT = "%.4f"  # 1e-4 px: round trips well inside 1e-3 px

#: The largest frame number of a file whose source states no length (a ``calibration.json``
#: without ``frames``, another tool's files). 10**9 frames is over a year of video at 30 frames/s
#: (385 days; 463 at 25), longer than any recording a run replays, and exact in the float64
#: tables hold; anything larger is a typo or garbage, which was accepted (a frame number of 1e12
#: made the run, or an import, a trillion frames long).
MAX_FRAME = 10**9


class DetFilesError(DmttError, ValueError):
    """A det-files directory or file that cannot be read; the message names the file and field."""


class FrameBound(NamedTuple):
    """The number of frames a source has, as ``stated_by`` (its ``calibration.json``) states
    it: no file of the source holds a later frame."""

    frames: int
    stated_by: Path


# -- text tables ------------------------------------------------------------------------------------
DET_COLUMNS = ("frame", "id", "x", "y", "w", "h")  # the fields every table starts with


def _check_columns(path: Path, what: str, columns: tuple[str, ...], positive: tuple[str, ...],
                   t: np.ndarray, lines: list[int], bound: FrameBound | None = None) -> None:
    """The rules of the module docstring for the named fields of every row of ``t``
    (``lines[r]``: the file line of row ``r``); the first broken one is the error."""
    rules = []
    if bound is None:
        last, why = MAX_FRAME, "(MAX_FRAME: the source states no number of frames)"
    else:
        last, why = bound.frames, f"(the number of frames {bound.stated_by} states)"
    for c, name in enumerate(columns):
        v = t[:, c]
        rules.append((~np.isfinite(v), name, "must be a finite number"))
        if name in ("frame", "id"):
            rules.append((np.isfinite(v) & (v != np.round(v)), name, "must be a whole number"))
        if name == "frame":
            rules.append((v < 1, name, "must be >= 1 (MOTChallenge frames are 1-based)"))
            rules.append((np.isfinite(v) & (v > last), name, f"must be <= {last} {why}"))
        if name in positive:
            rules.append((v <= 0, name, "(box size) must be > 0"))
    bad = [(int(np.argmax(m)), k) for k, (m, _, _) in enumerate(rules) if np.any(m)]
    if bad:
        r, k = min(bad)
        _, name, rule = rules[k]
        got = t[r, columns.index(name)]
        raise DetFilesError(f"{path}:{lines[r]}: {what} field {name!r} {rule}, got {got:.15g}")


PARSE_BLOCK = 8192  # rows of a text table held as Python lists at once while parsing


def read_table(path: Path, columns: tuple[str, ...], what: str,
               positive: tuple[str, ...] = (), bound: FrameBound | None = None) -> np.ndarray:
    """A comma-separated numeric table (``#`` comments, blank lines and CRLF allowed) whose
    rows start with the fields ``columns``: finite, ``frame`` / ``id`` whole, ``frame >= 1`` and
    at most ``bound.frames`` (without a bound :data:`MAX_FRAME`), the fields named in
    ``positive`` > 0. Errors name the file, the line and the field.

    Rows are padded with NaN to the widest row. The file is parsed :data:`PARSE_BLOCK` rows at a
    time, so parsing holds the table's numbers and one block of Python lists, not a list per
    row of the whole file."""
    if not path.is_file():
        raise DetFilesError(f"{what} file not found: {path}")
    blocks = list(_parsed_blocks(path, columns, what))
    width = max((b.shape[1] for b, _ in blocks), default=len(columns))
    out = np.full((sum(len(b) for b, _ in blocks), width), np.nan)
    r = 0
    for b, _ in blocks:
        out[r:r + len(b), :b.shape[1]] = b
        r += len(b)
    lines = np.concatenate([at for _, at in blocks]) if blocks else np.zeros(0, np.int64)
    _check_columns(path, what, columns, positive, out, lines, bound)
    return out


def _parsed_blocks(path: Path, columns: tuple[str, ...], what: str
                   ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The data rows of ``path`` as ``(numbers, file lines)``, :data:`PARSE_BLOCK` rows a block
    (each block NaN-padded to its widest row)."""
    rows: list[list[float]] = []
    lines: list[int] = []
    for i, line in text_lines(path, lambda e: DetFilesError(str(e))):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        f = [x.strip() for x in s.split(",")]
        if len(f) < len(columns):
            raise DetFilesError(f"{path}:{i}: {what} row needs at least {len(columns)} "
                                f"fields ({','.join(columns)}), got {len(f)}")
        try:
            rows.append([float(x) for x in f])
        except ValueError as exc:
            raise DetFilesError(f"{path}:{i}: non-numeric field in {what} row: {s!r}") from exc
        lines.append(i)
        if len(rows) == PARSE_BLOCK:
            yield _padded(rows), np.array(lines, dtype=np.int64)
            rows, lines = [], []
    if rows:
        yield _padded(rows), np.array(lines, dtype=np.int64)


def _padded(rows: list[list[float]]) -> np.ndarray:
    out = np.full((len(rows), max(len(r) for r in rows)), np.nan)
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


# -- frames on demand -------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrameTable:
    """A parsed table read frame by frame: :meth:`rows` ``(k)`` are the row numbers of run frame
    ``k`` (file frame ``k + 1``) in file order, found by binary search in the rows sorted by
    frame. Nothing is held per frame (a run of 100,000 frames holds the table and its order)."""

    path: Path
    table: np.ndarray  # (rows, fields) as the file has them
    frames: int  # run frames 0..frames-1; rows of later frames are never returned
    order: np.ndarray  # row numbers sorted by frame (stable: file order within a frame)
    sorted_frames: np.ndarray  # the run frame of each row in that order

    @classmethod
    def of(cls, path: Path, table: np.ndarray, frames: int | None = None) -> FrameTable:
        """``table`` by frame; ``frames`` defaults to the last frame in it."""
        f0 = table[:, 0].astype(np.int64) - 1
        n = int(f0.max()) + 1 if frames is None and len(f0) else (frames or 0)
        order = np.argsort(f0, kind="stable")
        return cls(path, table, n, order, f0[order])

    def rows(self, k: int) -> np.ndarray:
        """Row numbers of frame ``k`` (none outside ``0..frames-1``)."""
        if not 0 <= k < self.frames:
            return self.order[:0]
        lo, hi = np.searchsorted(self.sorted_frames, (k, k + 1))
        return self.order[lo:hi]


@dataclass(frozen=True)
class DetFile:
    """One camera's ``det.txt`` and descriptors, a frame's :class:`Detection` built when asked
    (:func:`open_det`): boxes float64 as parsed, descriptors float32 read from the ``.npy``
    (memory-mapped: a frame's rows come from disk), all-NaN row = no descriptor, a NaN or
    missing confidence = 1.0."""

    rows: FrameTable
    descriptors: np.ndarray | None  # (rows, D) read-only memmap, det.txt's row order

    @property
    def frames(self) -> int:
        return self.rows.frames

    def detections(self, k: int) -> list[Detection]:
        """Frame ``k``'s detections, in file order (``[]`` outside ``0..frames-1``)."""
        t, rows = self.rows.table, self.rows.rows(k)
        conf = t[rows, 6] if t.shape[1] > 6 else np.ones(len(rows))
        conf = np.where(np.isfinite(conf), conf, 1.0)
        return [Detection(box=t[r, 2:6].copy(), descriptor=self._descriptor(r), score=float(c))
                for r, c in zip(rows, conf)]

    def true_ids(self, k: int) -> np.ndarray:
        """The ``id`` column of frame ``k``'s rows (the true person, or -1)."""
        return self.rows.table[self.rows.rows(k), 1].astype(np.int64)

    def _descriptor(self, r: int) -> np.ndarray | None:
        if self.descriptors is None:
            return None
        d = np.array(self.descriptors[r], dtype=np.float32)
        return None if np.all(np.isnan(d)) else d


def open_det(path: str | os.PathLike[str], frames: int | None = None,
             descriptors: str | os.PathLike[str] | None = None, require_descriptors: bool = False,
             bound: FrameBound | None = None) -> DetFile:
    """One camera's ``det.txt`` (and its descriptors ``.npy``), frames read on demand.

    ``frames`` (the frames to run) defaults to the last frame in the file; ``bound`` is the
    source's stated length, which no row may pass (:func:`read_table`). Everything is validated
    here, at opening (the table, and the descriptors' shape, dtype and rows, scanned in blocks);
    a missing descriptor file is an error only when required.
    """
    path = Path(path)
    t = read_table(path, DET_COLUMNS, "det.txt", positive=("w", "h"), bound=bound)
    if descriptors is not None and require_descriptors and not Path(descriptors).is_file():
        raise DetFilesError(f"descriptor file not found: {descriptors} (named for {path})")
    desc = None
    if descriptors is not None and Path(descriptors).is_file():
        desc = _open_descriptors(Path(descriptors), path, len(t))
    return DetFile(FrameTable.of(path, t, frames), desc)


def _open_descriptors(path: Path, det: Path, rows: int) -> np.ndarray:
    """The descriptor ``.npy`` of ``det`` (``rows`` data rows) memory-mapped, checked: shape
    ``(rows, D)``, numbers, every row all finite or all NaN (after the float32 conversion the
    detections get), scanned :data:`PARSE_BLOCK` rows at a time."""
    try:
        desc = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise DetFilesError(f"{path}: not a numeric .npy array ({exc})") from exc
    if not isinstance(desc, np.ndarray):
        raise DetFilesError(f"{path}: not a numeric .npy array (an archive of several arrays)")
    if desc.ndim != 2 or len(desc) != rows:
        raise DetFilesError(f"{path}: shape {desc.shape} does not match {rows} rows "
                            f"of {det} (want ({rows}, D))")
    if desc.dtype.kind not in "fiu":
        raise DetFilesError(f"{path}: descriptors must be numbers, got dtype {desc.dtype}")
    for a in range(0, rows, PARSE_BLOCK):
        block = np.asarray(desc[a:a + PARSE_BLOCK], dtype=np.float32)
        bad = ~np.all(np.isnan(block), axis=1) & ~np.all(np.isfinite(block), axis=1)
        if np.any(bad):
            r = a + int(np.argmax(bad))
            raise DetFilesError(f"{path}: row {r} (descriptor of {det.name}'s data row "
                                f"{r + 1}) has NaN or inf values: a row is all finite, or all "
                                "NaN for no descriptor")
    return desc


@dataclass(frozen=True)
class GtFile:
    """One camera's MOTChallenge ``gt.txt`` by frame (:func:`open_gt`)."""

    rows: FrameTable

    def boxes(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(ids (m,), boxes (m, 4))`` of frame ``k``."""
        t, r = self.rows.table, self.rows.rows(k)
        return t[r, 1].astype(np.int64), t[r, 2:6]


def open_gt(path: str | os.PathLike[str], frames: int,
            bound: FrameBound | None = None) -> GtFile:
    """One camera's ``gt.txt`` for frames ``0..frames-1`` (no row past ``bound``): rows with
    ``consider = 0`` or a class other than pedestrian (1, or -1 / NaN for unknown) are dropped
    here."""
    path = Path(path)
    t = read_table(path, DET_COLUMNS, "gt.txt", bound=bound)
    keep = np.ones(len(t), dtype=bool)
    if t.shape[1] > 6:
        keep &= ~(t[:, 6] == 0)  # consider flag
    if t.shape[1] > 7:
        keep &= np.isnan(t[:, 7]) | (t[:, 7] == 1) | (t[:, 7] == -1)  # pedestrians only
    return GtFile(FrameTable.of(path, t[keep], frames))


@dataclass(frozen=True)
class GroundFile:
    """``gt_ground.csv`` by frame (:func:`open_gt_ground`)."""

    rows: FrameTable

    def truth(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ids (n,), xy (n, 2), wh (n, 2))`` of frame ``k``."""
        t, r = self.rows.table, self.rows.rows(k)
        return t[r, 1].astype(np.int64), t[r, 2:4], t[r, 4:6]

    def positions(self) -> np.ndarray:
        """Every ground position ``(x, y)`` of frames ``0..frames-1`` (rows, 2)."""
        t = self.rows.table
        return t[t[:, 0] <= self.rows.frames, 2:4]


def open_gt_ground(path: str | os.PathLike[str], frames: int,
                   bound: FrameBound | None = None) -> GroundFile:
    """``gt_ground.csv`` (``frame,id,x,y,w,h``) for frames ``0..frames-1`` (no row past
    ``bound``)."""
    path = Path(path)
    t = read_table(path, DET_COLUMNS, "gt_ground.csv", bound=bound)
    return GroundFile(FrameTable.of(path, t, frames))


def last_frame(path: Path) -> int:
    if not path.is_file():
        return 0
    t = read_table(path, DET_COLUMNS[:1], path.name)
    return int(t[:, 0].max()) if len(t) else 0


# -- writing ----------------------------------------------------------------------------------------
def write_rows(path: Path, rows: list[str], header: str | None = None) -> None:
    """Text rows, ``\\n`` line ends, the parent folder made when missing."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", encoding="utf-8", newline="\n") as fh:
        if header:
            fh.write(header + "\n")
        fh.write("\n".join(rows) + ("\n" if rows else ""))


def _f(v: float) -> str:
    return BOX_FMT % float(v)


def write_det(path: Path, detections: list[list[Detection]], true_ids: list[np.ndarray],
              descriptors: Path, descriptor_dtype: str = "float16") -> bool:
    """One camera's ``det.txt`` (boxes to 1e-4 px, scores, ``true_ids`` in the id column) and its
    descriptors ``.npy`` of ``descriptor_dtype`` (an all-NaN row for a detection without one).
    No ``.npy`` is written (an old one is removed) when no detection has a descriptor; returns
    whether one was written."""
    if np.dtype(descriptor_dtype).kind != "f":
        raise DetFilesError(f"descriptor_dtype must be a float type, got {descriptor_dtype!r}")
    rows, descs, have = [], [], False
    for k, (dets, ids) in enumerate(zip(detections, true_ids)):
        for d, tid in zip(dets, ids):
            b = np.asarray(d.box, dtype=float)
            rows.append(f"{k + 1},{int(tid)},{_f(b[0])},{_f(b[1])},{_f(b[2])},{_f(b[3])},"
                        f"{float(d.score):.6g},-1,-1,-1")
            descs.append(d.descriptor)
            have = have or d.descriptor is not None
    write_rows(path, rows)
    if have:
        dim = next(len(x) for x in descs if x is not None)
        arr = np.stack([np.full(dim, np.nan) if x is None else np.asarray(x, float)
                        for x in descs]) if descs else np.zeros((0, dim))
        np.save(descriptors, arr.astype(descriptor_dtype))
    elif descriptors.exists():
        descriptors.unlink()
    return have


def write_gt(path: Path, truth: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """One camera's ``gt.txt`` from ``(ids, boxes)`` per frame (every row considered, class 1)."""
    rows = []
    for k, (ids, boxes) in enumerate(truth):
        for i, b in zip(np.asarray(ids).ravel(), np.asarray(boxes, float).reshape(-1, 4)):
            rows.append(f"{k + 1},{int(i)},{_f(b[0])},{_f(b[1])},{_f(b[2])},{_f(b[3])},1,1,1")
    write_rows(path, rows)


def write_gt_ground(path: Path, ids: list[np.ndarray], xy: list[np.ndarray],
                    wh: list[np.ndarray]) -> None:
    """``gt_ground.csv`` from ``(ids, xy, wh)`` per frame."""
    rows = []
    for k in range(len(ids)):
        for i, p, s in zip(np.asarray(ids[k]).ravel(), np.asarray(xy[k]).reshape(-1, 2),
                           np.asarray(wh[k]).reshape(-1, 2)):
            rows.append(f"{k + 1},{int(i)},{p[0]:.6f},{p[1]:.6f},{s[0]:.6f},{s[1]:.6f}")
    write_rows(path, rows, header="# frame,id,x,y,w,h (ground units, 1-based frames)")
