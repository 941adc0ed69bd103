"""Track files: one MOTChallenge-style CSV per node, written by camera processes and by the
in-process simulator, read back for evaluation and viewing.

Columns: ``frame,id,camera,counter,x,y,w,h,vx,vy,observed,ell`` — ``id`` is the integer
``camera * 1_000_000 + counter`` for tools that want one number; ``(camera, counter)`` is the
tracker id of the paper; ``x..vy`` the corrected state in the scenario's ground units, written
as ``f"{v:.6f}"``; rows end with the csv module's default ``\\r\\n``.
"""
from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.core.types import Track

HEADER = ["frame", "id", "camera", "counter", "x", "y", "w", "h", "vx", "vy", "observed", "ell"]
ID_BASE = 1_000_000

__all__ = ["HEADER", "ID_BASE", "TrackWriter", "read_tracks", "track_row", "write_tracks"]


def track_row(t: Track) -> list[Any]:
    cam, cnt = t.id
    return [t.frame, cam * ID_BASE + cnt, cam, cnt, *(f"{v:.6f}" for v in t.x), int(t.observed),
            t.ell]


class TrackWriter:
    """Appends one frame's tracks at a time; ``flush`` is cheap enough to call once a second."""

    def __init__(self, path: Path | None, append: bool = False):
        """``append``: a restarted node continues its earlier life's file."""
        self.path = path
        self._f = None
        self._w = None
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            cont = append and path.exists() and path.stat().st_size > 0
            self._f = open(path, "a" if cont else "w", newline="")
            self._w = csv.writer(self._f)
            if not cont:
                self._w.writerow(HEADER)

    def write(self, tracks: Iterable[Track]) -> None:
        if self._w is not None:
            self._w.writerows(track_row(t) for t in tracks)

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


def write_tracks(path: Path, frames: list[list[Track]]) -> None:
    """A whole run's track file at once (the file a camera process writes frame by frame)."""
    with TrackWriter(Path(path)) as w:
        for tracks in frames:
            w.write(tracks)


def read_tracks(path: Path, frames: int | None = None) -> list[list[Track]]:
    """Read a track file back into ``frame -> [Track]`` (covariances are not stored: zeros)."""
    rows: dict[int, list[Track]] = {}
    with open(path, newline="") as f:
        r = csv.DictReader(f)
        if r.fieldnames != HEADER:
            raise ValueError(f"{path}: not a track file (header {r.fieldnames})")
        for row in r:
            k = int(row["frame"])
            x = np.array([float(row[c]) for c in ("x", "y", "w", "h", "vx", "vy")])
            rows.setdefault(k, []).append(Track((int(row["camera"]), int(row["counter"])), k, x,
                                                np.zeros((6, 6)), row["observed"] == "1",
                                                int(row["ell"])))
    n = (max(rows) + 1 if rows else 0) if frames is None else frames
    return [rows.get(k, []) for k in range(n)]
