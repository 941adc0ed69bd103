"""Track files: one MOTChallenge-style CSV per node, and reading them back.

Columns: ``frame,id,camera,counter,x,y,w,h,vx,vy,observed,ell`` — ``id`` is the integer
``camera * 1_000_000 + counter`` for tools that want one number; ``(camera, counter)`` is the
tracker id of the paper; ``x..vy`` the corrected state in the scenario's ground units.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from edge_node.core.types import Track
from edge_node.runtime.output import HEADER, ID_BASE, TrackWriter  # one format for both shells

__all__ = ["HEADER", "ID_BASE", "read_tracks", "write_tracks"]


def write_tracks(path: Path, frames: list[list[Track]]) -> None:
    """The file a camera process writes (``edge_node.runtime.output.TrackWriter``), at once."""
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
