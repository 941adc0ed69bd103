"""``homographies.json``: the calibration file of the EPFL multi-camera data (``epfl_pom``).

Per sequence (a key of the file, e.g. ``terrace``) the image-to-ground homographies ``H`` (camera
order = list order), the ``image_scale`` they expect (``g = H [u s, v s, 1]``, taken from the
file, never assumed), the annotation image size and the files' sequence name::

    {"terrace": {"sequence": "terrace1", "image_scale": 1.0,
                 "image_size_annotations": [360, 288], "H": [[[...], [...], [...]], ...]}}

Read by the EPFL scenarios (every camera of a sequence, ``sim_cluster/scenarios/epfl.py``) and by
a camera process running from EPFL videos (its own camera, ``edge_node/perception/frames.py``).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.formats.text import read_text
from edge_node.geometry import Camera, GeometryError
from protocol.errors import DmttError

FILE = "homographies.json"
ANNOTATION_SIZE = (360, 288)


class HomographiesError(DmttError, ValueError):
    """A calibration file that cannot be used; the message names the file and the field."""


def read_homographies(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The parsed file (a missing one raises ``FileNotFoundError``; bytes that are not UTF-8
    are a :class:`HomographiesError` naming the line and the byte offset)."""
    path = Path(path)
    try:
        doc = json.loads(read_text(path, lambda e: HomographiesError(str(e))))
    except json.JSONDecodeError as exc:
        raise HomographiesError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(doc, dict):
        raise HomographiesError(f"{path}: not a table of sequences")
    return doc


def sequence_entry(doc: dict[str, Any], sequence: str, path: str | os.PathLike[str], *,
                   loose: bool = False) -> dict[str, Any]:
    """The entry of ``sequence``: its key, or with ``loose`` also the entry whose ``sequence`` is
    it or whose key it starts with and then only digits (``terrace1`` -> ``terrace``)."""
    entry = doc.get(sequence)
    if not isinstance(entry, dict) and loose:
        entry = next((v for k, v in doc.items() if isinstance(v, dict) and (
            v.get("sequence") == sequence or sequence.rstrip("0123456789") == k)), None)
    if not isinstance(entry, dict):
        keys = [k for k, v in doc.items() if isinstance(v, dict)]
        raise HomographiesError(f"{path}: no sequence {sequence!r} (has {keys})")
    return entry


def sequence_cameras(entry: dict[str, Any], sequence: str, path: str | os.PathLike[str], *,
                     fps: float, image_size: tuple[int, int] = ANNOTATION_SIZE) -> list[Camera]:
    """Every camera of a sequence's entry: ``G = H[c]``, ``pixel_scale = image_scale``, the image
    size from ``image_size_annotations`` (else ``image_size``), camera ids ``0..``."""
    Hs = entry.get("H")
    if not isinstance(Hs, list):
        raise HomographiesError(f"{path}: {sequence}.H (per-camera homographies) is missing")
    scale = float(entry.get("image_scale", 1.0))
    size = entry.get("image_size_annotations", list(image_size))
    cams = []
    for c, H in enumerate(Hs):
        try:
            cams.append(Camera(id=c, image_size=(int(size[0]), int(size[1])),
                               G=np.asarray(H, dtype=float), pixel_scale=scale, fps=fps))
        except (GeometryError, ValueError, TypeError) as exc:
            raise HomographiesError(f"{path}: {sequence}.H[{c}]: {exc}") from exc
    return cams
