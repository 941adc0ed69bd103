"""Track files: one MOTChallenge-style CSV per node, written by camera processes and by the
in-process simulator, read back for evaluation and viewing.

Columns: ``frame,id,camera,counter,x,y,w,h,vx,vy,observed,ell,bx,by,bw,bh``: ``id`` is the
integer ``camera * 1_000_000 + counter`` for tools that want one number; ``(camera, counter)`` is
the tracker id of the paper; ``x..vy`` the corrected state in the scenario's ground units, written
as ``f"{v:.6f}"``; ``bx..bh`` the track in the node's own image (``Track.boxes``: top-left corner
and size in pixels, ``f"{v:.3f}"``), empty when that camera has not seen the target recently.
Rows end with the csv module's default CRLF. Files of the earlier 12-column form (no boxes) are
still read.
"""
from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.core.types import Track

HEADER = ["frame", "id", "camera", "counter", "x", "y", "w", "h", "vx", "vy", "observed", "ell",
          "bx", "by", "bw", "bh"]
_BOX = ("bx", "by", "bw", "bh")
ID_BASE = 1_000_000

__all__ = ["HEADER", "ID_BASE", "TrackWriter", "read_tracks", "track_row", "write_tracks"]


def track_row(t: Track, camera: int | None = None) -> list[Any]:
    """One row; the box columns hold ``t.boxes[camera]`` (the node's own camera)."""
    cam, cnt = t.id
    box = (t.boxes or {}).get(camera) if camera is not None else None
    return [t.frame, cam * ID_BASE + cnt, cam, cnt, *(f"{v:.6f}" for v in t.x), int(t.observed),
            t.ell, *((f"{v:.3f}" for v in box) if box is not None else ("",) * 4)]


class TrackWriter:
    """Appends one frame's tracks at a time; ``flush`` is cheap enough to call once a second.

    Rotation, for a node that runs for months: with ``rotate_bytes`` the file is rotated after
    the frame that takes it past that size (``tracks.csv`` -> ``tracks.csv.1`` -> ... ->
    ``tracks.csv.<keep>``, the oldest dropped; each file starts with the header and holds whole
    frames). :meth:`reopen` starts a new file after an outside tool (logrotate) moved it.
    """

    def __init__(self, path: Path | None, append: bool = False, camera: int | None = None,
                 rotate_bytes: int | None = None, keep: int = 5):
        """``append``: a restarted node continues its earlier life's file. ``camera``: the
        node's own camera, whose view the box columns hold."""
        self.path = path
        self.camera = camera
        self.rotate_bytes = rotate_bytes
        self.keep = keep
        self.rotations = 0
        self._f = None
        self._w = None
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._open(append)

    def _open(self, append: bool) -> None:
        cont = append and self.path.exists() and self.path.stat().st_size > 0
        self._f = open(self.path, "a" if cont else "w", newline="")
        self._w = csv.writer(self._f)
        if not cont:
            self._w.writerow(HEADER)

    def write(self, tracks: Iterable[Track]) -> None:
        if self._w is not None:
            self._w.writerows(track_row(t, self.camera) for t in tracks)
            if self.rotate_bytes is not None and self._f.tell() >= self.rotate_bytes:
                self.rotate()

    def rotate(self) -> None:
        """Close the file, shift the older ones up by one, start a new file."""
        if self._f is None:
            return
        self.close()
        old = [self.path.with_name(f"{self.path.name}.{i}") for i in range(self.keep + 1)]
        old[0] = self.path
        if self.keep == 0:
            self.path.unlink(missing_ok=True)
        else:
            old[-1].unlink(missing_ok=True)
            for i in range(self.keep - 1, -1, -1):
                if old[i].exists():
                    old[i].replace(old[i + 1])
        self.rotations += 1
        self._open(append=False)

    def reopen(self) -> None:
        """Continue in the file at ``path`` (a new one when it was moved away)."""
        if self._f is not None:
            self.close()
            self._open(append=True)

    def flush(self) -> None:
        if self._f is not None:
            self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None
            self._w = None

    def __enter__(self) -> "TrackWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_tracks(path: Path, frames: list[list[Track]], camera: int | None = None) -> None:
    """A whole run's track file at once (the file a camera process writes frame by frame)."""
    with TrackWriter(Path(path), camera=camera) as w:
        for tracks in frames:
            w.write(tracks)


def read_tracks(path: Path, frames: int | None = None, camera: int = 0) -> list[list[Track]]:
    """Read a track file back into ``frame -> [Track]`` (covariances are not stored: zeros).

    ``camera``: the node's own camera, the key of the boxes read (``Track.boxes``); files without
    box columns give ``boxes = None`` (unknown)."""
    rows: dict[int, list[Track]] = {}
    with open(path, newline="") as f:
        r = csv.DictReader(f)
        if r.fieldnames not in (HEADER, HEADER[:-4]):
            raise ValueError(f"{path}: not a track file (header {r.fieldnames})")
        with_boxes = r.fieldnames == HEADER
        for row in r:
            k = int(row["frame"])
            x = np.array([float(row[c]) for c in ("x", "y", "w", "h", "vx", "vy")])
            boxes = None
            if with_boxes:
                boxes = {} if row["bx"] == "" else {camera: np.array([float(row[c]) for c in _BOX])}
            rows.setdefault(k, []).append(Track((int(row["camera"]), int(row["counter"])), k, x,
                                                np.zeros((6, 6)), row["observed"] == "1",
                                                int(row["ell"]), boxes))
    n = (max(rows) + 1 if rows else 0) if frames is None else frames
    return [rows.get(k, []) for k in range(n)]
