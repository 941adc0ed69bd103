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


def write_json_atomic(path: Path, obj: Any) -> None:
    """Write ``obj`` as JSON to ``path`` so that a reader never sees a half-written file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(obj, f, indent=1, sort_keys=True)
        f.write("\n")
    os.replace(tmp, path)


class StatusWriter:
    """Rate-limited ``status_node<id>.json``: ``maybe(obj)`` writes at most every ``interval`` s."""

    def __init__(self, path: Path | None, interval: float = 1.0):
        self.path = path
        self.interval = interval
        self._last = -float("inf")

    def due(self) -> bool:
        return self.path is not None and time.monotonic() - self._last >= self.interval

    def write(self, obj: dict) -> None:
        if self.path is None:
            return
        write_json_atomic(self.path, obj)
        self._last = time.monotonic()


def latency_summary(samples_s: Sequence[float]) -> dict:
    """Median / p99 / mean / max of one-hop latencies (seconds in, milliseconds out)."""
    if not len(samples_s):
        return {"count": 0, "median_ms": None, "p99_ms": None, "mean_ms": None, "max_ms": None,
                "min_ms": None}
    a = np.asarray(samples_s, dtype=float) * 1e3
    return {"count": int(a.size), "median_ms": float(np.median(a)),
            "p99_ms": float(np.percentile(a, 99)), "mean_ms": float(a.mean()),
            "max_ms": float(a.max()), "min_ms": float(a.min())}
