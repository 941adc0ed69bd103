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

Every row's first six fields must be finite numbers, ``frame`` a whole number >= 1 and ``id`` a
whole number; a ``det.txt`` box must have ``w > 0`` and ``h > 0``; a descriptor row is all finite
or all NaN. Anything else is a :class:`DetFilesError` naming the file, the line and the field
(a NaN box would otherwise reach the tracker's assignment and stop the node). Fields after the
sixth may be NaN (a NaN confidence reads as 1.0).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from edge_node.core.types import Detection

BOX_FMT = "%.4f"  # 1e-4 px: round trips well inside 1e-3 px


class DetFilesError(ValueError):
    """A det-files directory or file that cannot be read; the message names the file and field."""


# -- text tables ------------------------------------------------------------------------------------
DET_COLUMNS = ("frame", "id", "x", "y", "w", "h")  # the fields every table starts with


def _check_columns(path: Path, what: str, columns: tuple[str, ...], positive: tuple[str, ...],
                   t: np.ndarray, lines: list[int]) -> None:
    """The rules of the module docstring for the named fields of every row of ``t``
    (``lines[r]``: the file line of row ``r``); the first broken one is the error."""
    rules = []
    for c, name in enumerate(columns):
        v = t[:, c]
        rules.append((~np.isfinite(v), name, "must be a finite number"))
        if name in ("frame", "id"):
            rules.append((np.isfinite(v) & (v != np.round(v)), name, "must be a whole number"))
        if name == "frame":
            rules.append((v < 1, name, "must be >= 1 (MOTChallenge frames are 1-based)"))
        if name in positive:
            rules.append((v <= 0, name, "(box size) must be > 0"))
    bad = [(int(np.argmax(m)), k) for k, (m, _, _) in enumerate(rules) if np.any(m)]
    if bad:
        r, k = min(bad)
        _, name, rule = rules[k]
        got = t[r, columns.index(name)]
        raise DetFilesError(f"{path}:{lines[r]}: {what} field {name!r} {rule}, got {got:g}")


def read_table(path: Path, columns: tuple[str, ...], what: str,
               positive: tuple[str, ...] = ()) -> np.ndarray:
    """A comma-separated numeric table (``#`` comments, blank lines and CRLF allowed) whose
    rows start with the fields ``columns``: finite, ``frame`` / ``id`` whole, ``frame >= 1``,
    the fields named in ``positive`` > 0. Errors name the file, the line and the field."""
    if not path.is_file():
        raise DetFilesError(f"{what} file not found: {path}")
    rows: list[list[float]] = []
    lines: list[int] = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        f = [x.strip() for x in s.split(",")]
        if len(f) < len(columns):
            raise DetFilesError(f"{path}:{i}: {what} row needs at least {len(columns)} fields "
                                f"({','.join(columns)}), got {len(f)}")
        try:
            rows.append([float(x) for x in f])
        except ValueError as exc:
            raise DetFilesError(f"{path}:{i}: non-numeric field in {what} row: {s!r}") from exc
        lines.append(i)
    width = max((len(r) for r in rows), default=len(columns))
    out = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    _check_columns(path, what, columns, positive, out, lines)
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
    t = read_table(path, DET_COLUMNS, "det.txt", positive=("w", "h"))
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
        if desc.dtype.kind not in "fiu":
            raise DetFilesError(f"{descriptors}: descriptors must be numbers, got dtype "
                                f"{desc.dtype}")
        desc = desc.astype(np.float32, copy=False)
        no_desc = np.all(np.isnan(desc), axis=1)
        bad = ~no_desc & ~np.all(np.isfinite(desc), axis=1)
        if np.any(bad):
            r = int(np.argmax(bad))
            raise DetFilesError(f"{descriptors}: row {r} (descriptor of {path.name}'s data row "
                                f"{r + 1}) has NaN or inf values: a row is all finite, or all "
                                "NaN for no descriptor")
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
    t = read_table(path, DET_COLUMNS, "gt.txt")
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
    t = read_table(Path(path), DET_COLUMNS, "gt_ground.csv")
    groups = group_rows(t[:, 0].astype(int) - 1, frames)
    return ([t[g, 1].astype(np.int64) for g in groups], [t[g, 2:4].copy() for g in groups],
            [t[g, 4:6].copy() for g in groups])


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
