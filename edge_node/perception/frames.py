"""Where frames come from: a video file, a folder of images, the EPFL dataset layout, a live
camera. Each source yields :class:`Frame` objects ``(index, timestamp, image)``: ``index`` counts
from 0 in the source's order, ``timestamp`` is in seconds (the video's own clock, ``index / fps``
for images, the wall clock for a live camera), ``image`` is BGR ``uint8`` (``None`` when one image
of a folder cannot be decoded: that frame then has no detections, the run goes on).

Every source is opened, and its first frame decoded, at construction, so a missing or unreadable
input fails at start-up with a :class:`~edge_node.perception.PerceptionError`.

EPFL layout (the CVLab multi-camera pedestrian videos): a folder holding
``<sequence>-c<camera>.avi`` (e.g. ``terrace1-c0.avi``; ``.mp4`` / ``.mkv`` too) or a folder of
images ``<sequence>-c<camera>/``, and optionally ``homographies.json`` (the calibration file of
``shared/data/epfl_pom``: per sequence ``H`` per camera, ``image_scale``, the image size) that gives
the camera when the node's config has no ``[camera]`` table.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import re
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator

import numpy as np

from edge_node.formats.homographies import (HomographiesError, read_homographies,
                                            sequence_cameras, sequence_entry)
from edge_node.perception import PerceptionError, require_cv2

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm")
VIDEO_EXTENSIONS = (".avi", ".mp4", ".mkv", ".mov", ".mpg", ".mpeg", ".webm")


@dataclass
class Frame:
    index: int
    timestamp: float  # seconds
    image: np.ndarray | None  # BGR uint8 (H, W, 3)


class FrameSource(ABC):
    """Base: ``read()`` the next frame (``None`` at the end), iterate, ``close()``.

    ``frames`` is the number of frames when known (``None`` for a live camera), ``fps`` the frame
    rate, ``image_size`` ``(width, height)`` of the first frame.
    """

    description = "frames"
    fps: float = 25.0
    frames: int | None = None
    image_size: tuple[int, int] = (0, 0)

    @abstractmethod
    def read(self) -> Frame | None:
        """The next frame, or ``None`` at the end of the source."""

    def __iter__(self) -> Iterator[Frame]:
        while True:
            f = self.read()
            if f is None:
                return
            yield f

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _size(img: np.ndarray) -> tuple[int, int]:
    return int(img.shape[1]), int(img.shape[0])


def _as_bgr(img: np.ndarray, cv2) -> np.ndarray:
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


class VideoFile(FrameSource):
    """A video file read with OpenCV. ``fps`` overrides the file's when the file has none."""

    def __init__(self, path: str | Path, fps: float | None = None):
        cv2 = require_cv2()
        self.cv2 = cv2
        self.path = Path(path)
        if not self.path.is_file():
            raise PerceptionError(f"video file not found: {self.path}")
        self.cap = cv2.VideoCapture(str(self.path))
        if not self.cap.isOpened():
            raise PerceptionError(f"{self.path}: OpenCV cannot open this video")
        ok, first = self.cap.read()
        if not ok or first is None:
            self.cap.release()
            raise PerceptionError(f"{self.path}: no frame can be decoded")
        own = float(self.cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = own if own > 0 and np.isfinite(own) else float(fps or 25.0)
        n = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        self.frames = n if n > 0 else None
        self.image_size = _size(first)
        self.description = f"video {self.path}"
        self._pending: np.ndarray | None = first
        self._next = 0

    def read(self) -> Frame | None:
        if self._pending is not None:
            img, self._pending = self._pending, None
        else:
            ok, img = self.cap.read()
            if not ok or img is None:
                return None
        k = self._next
        self._next += 1
        ms = float(self.cap.get(self.cv2.CAP_PROP_POS_MSEC) or 0.0)
        ts = k / self.fps  # the container's clock when it has one, else the nominal rate
        if ms > 0 and k > 0:
            ts = ms / 1000.0
        return Frame(k, ts, _as_bgr(img, self.cv2))

    def close(self) -> None:
        self.cap.release()


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]


class ImageFolder(FrameSource):
    """The images of a folder in natural order (``img2`` before ``img10``); ``pattern`` is a
    glob (default: every common image extension). Timestamps are ``index / fps``."""

    def __init__(self, path: str | Path, pattern: str | None = None, fps: float = 25.0):
        cv2 = require_cv2()
        self.cv2 = cv2
        self.path = Path(path)
        if not self.path.is_dir():
            raise PerceptionError(f"image folder not found: {self.path}")
        if pattern:
            files = [p for p in self.path.glob(pattern) if p.is_file()]
        else:
            files = [p for p in self.path.iterdir()
                     if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS]
        self.files = sorted(files, key=_natural_key)
        if not self.files:
            raise PerceptionError(f"{self.path}: no images"
                                  + (f" matching {pattern!r}" if pattern else ""))
        if fps <= 0:
            raise PerceptionError(f"image folder fps must be > 0, got {fps}")
        first = cv2.imread(str(self.files[0]), cv2.IMREAD_COLOR)
        if first is None:
            raise PerceptionError(f"{self.files[0]}: cannot decode this image")
        self.fps = float(fps)
        self.frames = len(self.files)
        self.image_size = _size(first)
        self.description = f"images {self.path} ({len(self.files)} files)"
        self._first = first
        self._next = 0
        self.unreadable: list[Path] = []

    def read(self) -> Frame | None:
        k = self._next
        if k >= len(self.files):
            return None
        self._next += 1
        if k == 0 and self._first is not None:
            img, self._first = self._first, None
        else:
            img = self.cv2.imread(str(self.files[k]), self.cv2.IMREAD_COLOR)
            if img is None:
                self.unreadable.append(self.files[k])
        return Frame(k, k / self.fps, img)


class LiveCamera(FrameSource):
    """A live camera through OpenCV: a device index (``0``) or a stream URL / device path.
    Timestamps are the wall clock at capture; ``frames`` is ``None`` (until stopped)."""

    def __init__(self, device: int | str = 0, fps: float | None = None,
                 size: tuple[int, int] | None = None):
        cv2 = require_cv2()
        self.cv2 = cv2
        dev: int | str = int(device) if isinstance(device, int) or str(device).isdigit() else str(device)
        self.cap = cv2.VideoCapture(dev)
        if not self.cap.isOpened():
            raise PerceptionError(f"camera {device!r}: OpenCV cannot open it")
        if size is not None:
            self.cap.set(cv2.CAP_PROP_FRAME_WIDTH, int(size[0]))
            self.cap.set(cv2.CAP_PROP_FRAME_HEIGHT, int(size[1]))
        if fps is not None:
            self.cap.set(cv2.CAP_PROP_FPS, float(fps))
        ok, first = self.cap.read()
        if not ok or first is None:
            self.cap.release()
            raise PerceptionError(f"camera {device!r}: opened, but no frame arrives")
        own = float(self.cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = float(fps) if fps else (own if own > 0 else 25.0)
        self.frames = None
        self.image_size = _size(first)
        self.description = f"camera {device!r}"
        self._pending: tuple[np.ndarray, float] | None = (first, time.time())
        self._next = 0

    def read(self) -> Frame | None:
        if self._pending is not None:
            (img, ts), self._pending = self._pending, None
        else:
            ok, img = self.cap.read()
            ts = time.time()
            if not ok or img is None:
                return None
        k = self._next
        self._next += 1
        return Frame(k, ts, _as_bgr(img, self.cv2))

    def close(self) -> None:
        self.cap.release()


class EpflLayout(FrameSource):
    """Camera ``camera`` of sequence ``sequence`` in an EPFL-style folder (module docstring)."""

    def __init__(self, root: str | Path, sequence: str, camera: int, fps: float = 25.0,
                 calibration: str | Path | None = None):
        self.root = Path(root)
        if not self.root.is_dir():
            raise PerceptionError(f"EPFL folder not found: {self.root}")
        self.sequence = sequence
        self.camera_index = int(camera)
        stem = f"{sequence}-c{camera}"
        inner: FrameSource | None = None
        for ext in VIDEO_EXTENSIONS:
            p = self.root / f"{stem}{ext}"
            if p.is_file():
                inner = VideoFile(p, fps=fps)
                break
        if inner is None and (self.root / stem).is_dir():
            inner = ImageFolder(self.root / stem, fps=fps)
        if inner is None:
            have = sorted(p.name for p in self.root.iterdir())[:12]
            raise PerceptionError(f"{self.root}: no {stem}.avi (or .mp4, .mkv, or folder {stem}/) "
                                  f"for sequence {sequence!r} camera {camera}; the folder holds "
                                  f"{have}")
        self.inner = inner
        self.fps, self.frames, self.image_size = inner.fps, inner.frames, inner.image_size
        self.description = f"EPFL {sequence} camera {camera} ({inner.description})"
        self.calibration_file = Path(calibration) if calibration else None
        if self.calibration_file is None:
            for d in (self.root, self.root.parent):
                if (d / "homographies.json").is_file():
                    self.calibration_file = d / "homographies.json"
                    break

    def read(self) -> Frame | None:
        return self.inner.read()

    def close(self) -> None:
        self.inner.close()

    def camera(self, node: int):
        """This camera's calibration from ``homographies.json`` (``None`` without the file)."""
        if self.calibration_file is None:
            return None
        path = self.calibration_file
        try:
            entry = sequence_entry(read_homographies(path), self.sequence, path, loose=True)
            cams = sequence_cameras(entry, self.sequence, path, fps=self.fps,
                                    image_size=self.image_size)
        except (OSError, HomographiesError) as e:
            raise PerceptionError(str(e) if isinstance(e, HomographiesError)
                                  else f"{path}: cannot read ({e})") from None
        if self.camera_index >= len(cams):
            raise PerceptionError(f"{path}: {self.sequence}: no homography H[{self.camera_index}]")
        return replace(cams[self.camera_index], id=node)


FRAME_KINDS = ("video", "images", "epfl", "camera")


def open_frames(kind: str, *, path: str | Path | None = None, camera: int = 0,
                sequence: str | None = None, pattern: str | None = None,
                device: int | str | None = None, fps: float | None = None) -> FrameSource:
    """The frame source of ``[source] kind`` (``FRAME_KINDS``)."""
    if kind == "video":
        return VideoFile(path, fps=fps)
    if kind == "images":
        return ImageFolder(path, pattern=pattern, fps=fps or 25.0)
    if kind == "epfl":
        if not sequence:
            raise PerceptionError("epfl: a sequence name is required (e.g. terrace1)")
        return EpflLayout(path, sequence, camera, fps=fps or 25.0)
    if kind == "camera":
        return LiveCamera(0 if device is None else device, fps=fps)
    raise PerceptionError(f"unknown frame source {kind!r} (known: {', '.join(FRAME_KINDS)})")
