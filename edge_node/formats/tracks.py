"""Track files: one MOTChallenge-style CSV per node, written by camera processes and by the
in-process simulator, read back for evaluation and viewing.

Columns: ``frame,id,camera,counter,x,y,w,h,vx,vy,observed,ell,bx,by,bw,bh``: ``id`` is the
integer ``camera * 1_000_000 + counter`` for tools that want one number; ``(camera, counter)`` is
the tracker id of the paper; ``x..vy`` the corrected state in the scenario's ground units, written
as ``f"{v:.6f}"``; ``bx..bh`` the track in the node's own image (``Track.boxes``: top-left corner
and size in pixels, ``f"{v:.3f}"``), empty when that camera has not seen the target recently.
Rows end with CRLF (the csv module's default). Files of the earlier 12-column form (no boxes)
are still read.

Crash safety. A node runs for months and may be killed, or find its disk full, at any byte:

* :class:`TrackWriter` hands the file whole rows only. Rows wait in memory and go to the file
  in chunks of whole frames, with one ``os.write`` loop; a write that fails part-way (a full
  disk) is cut back to the last whole row (``ftruncate``) and the rows wait for the next try,
  with a backoff (``RETRY_S`` doubling up to ``RETRY_MAX_S``). While the file fails the writer
  says so (``failing``, ``error``) and never raises: the node goes on tracking. What waits is
  bounded (``max_pending_bytes``): beyond it the oldest waiting frames are dropped and counted
  (``frames_dropped``).
* Reopening a file to continue it (a restart, ``append``) repairs a torn last line first: the
  bytes after the last newline are cut, with a warning naming the file and the byte. The last
  frame already written is known (``last_frame``), so a restarted node does not write a frame
  twice.
* :func:`read_tracks` reads what it can: a row that is not a track row is reported by file and
  line (one warning for the file) and skipped, not fatal to the whole file.
"""
from __future__ import annotations

import errno
import logging
import os
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.core.types import Track

HEADER = ["frame", "id", "camera", "counter", "x", "y", "w", "h", "vx", "vy", "observed", "ell",
          "bx", "by", "bw", "bh"]
_BOX = ("bx", "by", "bw", "bh")
ID_BASE = 1_000_000
HEADER_LINE = (",".join(HEADER) + "\r\n").encode()
OLD_HEADER_LINE = (",".join(HEADER[:-4]) + "\r\n").encode()

CHUNK_BYTES = 64 * 1024  # rows waiting in memory are written once they reach this much
MAX_PENDING_BYTES = 64 * 1024 * 1024  # rows kept while the file fails (about 10 h of 9 people)
RETRY_S = 0.5  # first wait after a failed write ...
RETRY_MAX_S = 5.0  # ... doubling up to this (space freed: written again within seconds)

log = logging.getLogger("edge_node.formats")

__all__ = ["HEADER", "ID_BASE", "TrackWriter", "iter_tracks", "read_tracks", "repair_tail",
           "track_row", "write_tracks"]


def track_row(t: Track, camera: int | None = None) -> list[Any]:
    """One row; the box columns hold ``t.boxes[camera]`` (the node's own camera)."""
    cam, cnt = t.id
    box = (t.boxes or {}).get(camera) if camera is not None else None
    return [t.frame, cam * ID_BASE + cnt, cam, cnt, *(f"{v:.6f}" for v in t.x), int(t.observed),
            t.ell, *((f"{v:.3f}" for v in box) if box is not None else ("",) * 4)]


def _line(t: Track, camera: int | None) -> str:
    return ",".join(map(str, track_row(t, camera))) + "\r\n"


def repair_tail(path: Path) -> tuple[int | None, int]:
    """Cut a torn last line off ``path`` (the bytes after its last newline: a write a crash or
    a full disk cut short) and return ``(last frame written, bytes cut)``. A warning names the
    file and the byte where the cut starts. ``last frame`` is ``None`` when the file holds no
    data row."""
    size = path.stat().st_size
    if size == 0:
        return None, 0
    with open(path, "rb+") as f:
        tail = b""
        pos = size
        while pos > 0 and tail.count(b"\n") < 2:  # the last whole line, and the torn rest
            step = min(4096, pos)
            pos -= step
            f.seek(pos)
            tail = f.read(step) + tail
        keep = tail.rfind(b"\n") + 1  # within tail; 0: no newline at all
        cut = len(tail) - keep
        if cut:
            at = pos + keep
            log.warning("%s: cut a torn last line of %d bytes at byte %d (a write that a crash or "
                        "a full disk cut short)", path, cut, at)
            f.truncate(at)
        lines = tail[:keep].splitlines()
    last = lines[-1] if lines else b""
    try:
        return int(last.split(b",", 1)[0]), cut
    except ValueError:  # the header, or nothing whole
        return None, cut


class TrackWriter:
    """Appends one frame's tracks at a time, whole rows only (module docstring); ``flush`` is
    cheap enough to call once a second and never raises.

    Rotation, for a node that runs for months: with ``rotate_bytes`` the file is rotated after
    the frame that takes it past that size (``tracks.csv`` -> ``tracks.csv.1`` -> ... ->
    ``tracks.csv.<keep>``, the oldest dropped; each file starts with the header and holds whole
    frames). :meth:`reopen` starts a new file after an outside tool (logrotate) moved it.
    """

    def __init__(self, path: Path | None, append: bool = False, camera: int | None = None,
                 rotate_bytes: int | None = None, keep: int = 5, *,
                 max_pending_bytes: int = MAX_PENDING_BYTES,
                 clock: Callable[[], float] = time.monotonic):
        """``append``: a restarted node continues its earlier life's file (a torn last line is
        cut first; ``last_frame`` is the last frame it holds). ``camera``: the node's own
        camera, whose view the box columns hold."""
        self.path = path
        self.camera = camera
        self.rotate_bytes = rotate_bytes
        self.keep = keep
        self.max_pending_bytes = max_pending_bytes
        self.clock = clock
        self.rotations = 0
        self.last_frame: int | None = None  # the newest frame in the file (or waiting for it)
        self.frames_dropped = 0  # frames lost while the file failed (beyond max_pending_bytes)
        self.failures = 0  # failed writes (each retried)
        self.error: str | None = None  # why the last write failed; None once one succeeded
        self._fd: int | None = None
        self._size = 0  # bytes in the file, all whole rows
        self._pending: deque[tuple[int | None, bytes]] = deque()  # (frame, its rows) to write
        self._pending_bytes = 0
        self._retry_at = -float("inf")
        self._delay = RETRY_S
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._open(append)

    # -- state -----------------------------------------------------------------------------
    @property
    def failing(self) -> bool:
        """The last write failed and rows wait for the next try."""
        return self.error is not None

    @property
    def pending_bytes(self) -> int:
        return self._pending_bytes

    def _open(self, append: bool) -> None:
        cont = False
        if append and self.path.exists() and self.path.stat().st_size > 0:
            last, _ = repair_tail(self.path)
            with open(self.path, "rb") as f:
                head = f.readline()
            if head in (HEADER_LINE, OLD_HEADER_LINE):
                cont = True
                if last is None:  # only the header: rotated just before the end
                    last = self._last_rotated()
                self.last_frame = last if self.last_frame is None or last is None \
                    else max(last, self.last_frame)
            elif head:
                aside = self.path.with_name(self.path.name + ".unknown")
                log.warning("%s: not a track file (first line %r): moved to %s, starting a new "
                            "one", self.path, head[:80], aside.name)
                self.path.replace(aside)
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_CLOEXEC", 0)
        if not cont:
            flags |= os.O_TRUNC
        self._fd = os.open(self.path, flags, 0o644)
        self._size = os.fstat(self._fd).st_size
        if not cont:
            self._pending.appendleft((None, HEADER_LINE))
            self._pending_bytes += len(HEADER_LINE)

    def _last_rotated(self) -> int | None:
        older = self.path.with_name(f"{self.path.name}.1")
        if not older.exists():
            return None
        try:
            return repair_tail(older)[0]
        except OSError:
            return None

    # -- writing -----------------------------------------------------------------------------
    def write(self, tracks: Iterable[Track]) -> None:
        """Queue one frame's rows (all of the same frame); written in whole chunks."""
        if self.path is None:
            return
        rows = [(t.frame, _line(t, self.camera)) for t in tracks]
        if not rows:
            return
        data = "".join(r for _, r in rows).encode()
        frame = rows[-1][0]
        self._pending.append((frame, data))
        self._pending_bytes += len(data)
        self.last_frame = frame if self.last_frame is None else max(self.last_frame, frame)
        self._bound()
        if self._pending_bytes >= CHUNK_BYTES or self._due_rotation():
            self.flush()

    def _due_rotation(self) -> bool:
        return self.rotate_bytes is not None and self._size + self._pending_bytes >= self.rotate_bytes

    def _bound(self) -> None:
        """Drop the oldest waiting frames beyond ``max_pending_bytes`` (the file has failed for
        long); the header, if waiting, stays."""
        while self._pending_bytes > self.max_pending_bytes and len(self._pending) > 1:
            i = 1 if self._pending[0][0] is None else 0
            frame, data = self._pending[i]
            del self._pending[i]
            self._pending_bytes -= len(data)
            self.frames_dropped += 1

    def flush(self, force: bool = False) -> bool:
        """Write what waits, whole rows only; ``True`` when nothing waits any more. After a
        failure the next try waits for the backoff (``force``: try now)."""
        if self._fd is None or not self._pending:
            return not self._pending
        if not force and self.clock() < self._retry_at:
            return False
        data = b"".join(d for _, d in self._pending)
        try:
            view = memoryview(data)
            while view:
                n = os.write(self._fd, view)
                view = view[n:]
        except OSError as e:
            self._failed(e)
            return False
        self._size += len(data)
        self._pending.clear()
        self._pending_bytes = 0
        if self.error is not None:
            log.warning("%s: writing again after %d failed tries", self.path, self.failures)
        self.error = None
        self._delay = RETRY_S
        if self.rotate_bytes is not None and self._size >= self.rotate_bytes:
            try:
                self.rotate()
            except OSError as e:
                self._failed(e)
        return True

    def _failed(self, e: OSError) -> None:
        """A write failed: cut the file back to its whole rows, keep the rows, back off."""
        self.failures += 1
        self.error = f"{e.strerror or e} ({errno.errorcode.get(e.errno, e.errno)})"
        try:
            if os.fstat(self._fd).st_size != self._size:
                os.ftruncate(self._fd, self._size)
        except OSError as e2:  # left for repair_tail when the file is next continued
            log.warning("%s: cannot cut a failed write back to byte %d: %s", self.path,
                        self._size, e2.strerror or e2)
        self._retry_at = self.clock() + self._delay
        self._delay = min(self._delay * 2.0, RETRY_MAX_S)

    def rotate(self) -> None:
        """Close the file, shift the older ones up by one, start a new file."""
        if self._fd is None:
            return
        self._close_fd()
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
        """Continue in the file at ``path`` (a new one when it was moved away); what waits is
        written to the old file first if it can be."""
        if self._fd is not None:
            self.flush(force=True)
            rows_left = [p for p in self._pending if p[0] is not None]  # not the old header
            self._close_fd()
            self._pending = deque(rows_left)
            self._pending_bytes = sum(len(d) for _, d in self._pending)
            try:
                self._open(append=True)
            except OSError as e:
                log.warning("%s: cannot reopen: %s", self.path, e.strerror or e)

    def _close_fd(self) -> None:
        if self._fd is not None:
            try:
                os.close(self._fd)
            except OSError:
                pass
            self._fd = None

    def close(self) -> bool:
        """Write what waits (one last try) and close; ``False`` when rows could not be written
        (logged with the count; never raises)."""
        ok = True
        if self._fd is not None:
            ok = self.flush(force=True)
            if not ok:
                frames = sum(1 for f, _ in self._pending if f is not None)
                log.warning("%s: %d frames of tracks could not be written (%s)", self.path,
                            frames, self.error)
            self._close_fd()
        return ok

    def __enter__(self) -> "TrackWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_tracks(path: Path, frames: list[list[Track]], camera: int | None = None) -> None:
    """A whole run's track file at once (the file a camera process writes frame by frame)."""
    with TrackWriter(Path(path), camera=camera) as w:
        for tracks in frames:
            w.write(tracks)
        if not w.flush(force=True):
            raise OSError(f"{path}: cannot write the track file: {w.error}")


def iter_tracks(path: Path, camera: int = 0, bad: list[int] | None = None) -> Iterator[Track]:
    """The rows of a track file in file order, as ``Track`` s (covariances are not stored:
    zeros). ``camera``: the node's own camera, the key of the boxes read (``Track.boxes``);
    files without box columns give ``boxes = None`` (unknown). A file whose first line is not
    a track file's header is a ``ValueError``; a row that cannot be read (a torn line, a stray
    byte) is skipped, and one warning at the end names the file and the lines (also appended
    to ``bad`` when given)."""
    bad = [] if bad is None else bad
    with open(path, newline="", encoding="utf-8", errors="replace") as f:
        first = f.readline()
        head = first.rstrip("\r\n").split(",") if first else None
        if head not in (HEADER, HEADER[:-4]):
            raise ValueError(f"{path}: not a track file (header {head})")
        with_boxes = head == HEADER
        width = len(head)
        for line, text in enumerate(f, start=2):  # the writer never quotes: a comma splits
            row = text.rstrip("\r\n").split(",")
            try:
                if len(row) != width:
                    raise ValueError(f"{len(row)} fields")
                x = np.array([float(v) for v in row[4:10]])
                boxes = None
                if with_boxes:
                    boxes = {} if row[12] == "" else {camera: np.array([float(v) for v in row[12:16]])}
                t = Track((int(row[2]), int(row[3])), int(row[0]), x, np.zeros((6, 6)),
                          row[10] == "1", int(row[11]), boxes)
            except ValueError:
                bad.append(line)
                continue
            yield t
    if bad:
        shown = ", ".join(map(str, bad[:10])) + (f" and {len(bad) - 10} more" if len(bad) > 10 else "")
        log.warning("%s: skipped %d row(s) that are not track rows, line(s) %s", path, len(bad),
                    shown)


def read_tracks(path: Path, frames: int | None = None, camera: int = 0) -> list[list[Track]]:
    """Read a track file back into ``frame -> [Track]`` (``iter_tracks``: a bad row is skipped
    and reported, not fatal)."""
    rows: dict[int, list[Track]] = {}
    for t in iter_tracks(path, camera):
        rows.setdefault(t.frame, []).append(t)
    n = (max(rows) + 1 if rows else 0) if frames is None else frames
    return [rows.get(k, []) for k in range(n)]
