"""What a camera process writes: its tracks, a live status file, and wire counters at exit.

Files in ``[output] dir`` (node-suffixed so several nodes can share one directory)::

    tracks_node<id>.csv     frame,id,camera,counter,x,y,w,h,vx,vy,observed,ell, written by
                            ``edge_node.formats.tracks.TrackWriter`` (the simulator's format too)
    status_node<id>.json    rewritten atomically about once per second and at exit
    counters_node<id>.json  written at exit: bytes / messages per link, receive counts, rejected
                            messages by reason, one-hop latency (send time ``sent_at`` to receipt),
                            CPU time: ``cpu_s`` (the process's; since its first frame; its frame
                            loop thread's, in all and by step: source, core, send) and
                            ``receive_cpu_s`` (Zenoh's callback threads in the node's code)
"""
from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


def tracks_path(out_dir: Path, node: int) -> Path:
    return Path(out_dir) / f"tracks_node{node}.csv"


def status_path(out_dir: Path, node: int) -> Path:
    return Path(out_dir) / f"status_node{node}.json"


def state_path(out_dir: Path, node: int) -> Path:
    """What must survive a restart: the node's tracker id counter."""
    return Path(out_dir) / f"state_node{node}.json"


def counters_path(out_dir: Path, node: int) -> Path:
    return Path(out_dir) / f"counters_node{node}.json"


def _json_bytes(obj: Any) -> bytes:
    return (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode()


def write_json_atomic(path: Path, obj: Any) -> None:
    """Write ``obj`` as JSON to ``path`` so that a reader never sees a half-written file. A
    write that fails (a full disk) removes its temporary file and raises ``OSError``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(_json_bytes(obj))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def clean_temporaries(out_dir: Path, node: int) -> list[Path]:
    """Remove the temporaries that writes of node ``node``'s files left in ``out_dir`` (a
    process killed between writing one and renaming it); returns what was removed."""
    gone = []
    for name in (f"status_node{node}.json", f"counters_node{node}.json", f"state_node{node}.json"):
        for tmp in Path(out_dir).glob(f".{name}.*.tmp"):
            try:
                tmp.unlink()
                gone.append(tmp)
            except OSError:
                pass
    return gone


class ReservedJson:
    """A small JSON file replaced atomically whose disk space is reserved while there is some,
    so that it can still be written when the disk is full: a node's status, counters and id
    counter must say ``degraded`` (and keep its ids) exactly when its other output fails.

    Two inodes of ``reserve`` bytes take turns: the new content, padded with spaces to
    ``reserve`` bytes (JSON allows trailing white space), overwrites the spare's reserved blocks
    in place, the spare is renamed over ``path`` (atomic), and the inode it replaced, kept by a
    hard link, becomes the next spare. Content longer than ``reserve``, or a file system
    without hard links or ``posix_fallocate``, falls back to :func:`write_json_atomic`."""

    def __init__(self, path: Path, reserve: int = 16 * 1024):
        self.path = Path(path)
        self.reserve = reserve
        self.spare = self.path.with_name(f".{self.path.name}.spare")
        self._prev = self.path.with_name(f".{self.path.name}.prev")

    def _ensure_spare(self) -> bool:
        try:
            if self.spare.exists() and self.spare.stat().st_size >= self.reserve:
                return True
            fd = os.open(self.spare, os.O_WRONLY | os.O_CREAT, 0o644)
            try:
                os.posix_fallocate(fd, 0, self.reserve)
            finally:
                os.close(fd)
            return True
        except (OSError, AttributeError):
            self.spare.unlink(missing_ok=True)
            return False

    def write(self, obj: Any) -> None:
        """Replace the file's content by ``obj``; ``OSError`` when it cannot be written."""
        data = _json_bytes(obj)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if len(data) > self.reserve or not self._ensure_spare():
            write_json_atomic(self.path, obj)
            return
        fd = os.open(self.spare, os.O_WRONLY)
        try:
            os.pwrite(fd, data + b" " * (self.reserve - len(data)), 0)
        finally:
            os.close(fd)
        kept = False
        if self.path.exists():
            try:
                self._prev.unlink(missing_ok=True)
                os.link(self.path, self._prev)
                kept = True
            except OSError:
                pass
        os.replace(self.spare, self.path)
        if kept:
            os.replace(self._prev, self.spare)
        else:
            self._ensure_spare()

    def remove_spare(self) -> None:
        """Give the reserved space back (the node is done with the file)."""
        for p in (self.spare, self._prev):
            try:
                p.unlink(missing_ok=True)
            except OSError:
                pass


class StatusWriter:
    """Rate-limited ``status_node<id>.json``: :meth:`due` says when the interval has passed,
    :meth:`write` writes (reserved space: :class:`ReservedJson`) and raises ``OSError`` when it
    cannot. Thread-safe: the watchdog writes ``stalled`` from its own thread."""

    def __init__(self, path: Path | None, interval: float = 1.0):
        self.path = path
        self.interval = interval
        self._last = -float("inf")
        self._file = ReservedJson(path) if path is not None else None
        self._lock = threading.Lock()

    def due(self) -> bool:
        return self.path is not None and time.monotonic() - self._last >= self.interval

    def write(self, obj: dict) -> None:
        if self._file is None:
            return
        with self._lock:
            self._last = time.monotonic()
            self._file.write(obj)


def latency_summary(samples_s: Sequence[float]) -> dict:
    """Median / p99 / mean / max of one-hop latencies (seconds in, milliseconds out)."""
    if not len(samples_s):
        return {"count": 0, "median_ms": None, "p99_ms": None, "mean_ms": None, "max_ms": None,
                "min_ms": None}
    a = np.asarray(samples_s, dtype=float) * 1e3
    return {"count": int(a.size), "median_ms": float(np.median(a)),
            "p99_ms": float(np.percentile(a, 99)), "mean_ms": float(a.mean()),
            "max_ms": float(a.max()), "min_ms": float(a.min())}
