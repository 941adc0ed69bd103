"""Handing freed memory back to the system, and keeping the garbage collector off the frame
path: a camera process runs for months.

Decoded messages are allocated in Zenoh's receiving threads and freed by the frame loop; glibc
keeps what they freed in per-thread arenas and rarely returns it. Bursts (a neighbour's queue
after a freeze, resyncs after a restart) then raise a process's resident memory for good, a few
MB per fault. ``malloc_trim(0)`` returns the free pages of every arena to the system. Elsewhere
(musl, macOS) there is nothing to call and this is a no-op.

Python's cyclic garbage collector now and then traverses every object the process holds; after
its imports (NumPy, SciPy, Zenoh) a camera process holds about 54,000, and one full collection
took 24 ms of CPU (measured), more than half a 25 fps frame, at a moment nobody chooses.
``freeze_startup`` moves everything allocated before the first frame out of the collector's
reach (``gc.freeze``): those objects live as long as the process anyway, and a full collection
afterwards traverses only what the frames allocated.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc

_libc = None
try:
    _name = ctypes.util.find_library("c")
    _libc = ctypes.CDLL(_name) if _name else None
    _trim = getattr(_libc, "malloc_trim", None) if _libc is not None else None
except OSError:  # no C library to load: nothing to trim
    _trim = None


def release_freed_memory() -> bool:
    """Return freed heap pages to the system (glibc ``malloc_trim``); whether anything was."""
    return bool(_trim(0)) if _trim is not None else False


def freeze_startup() -> None:
    """Collect once, then exempt every object alive now from later cyclic collections
    (``gc.freeze``; module docstring). Call it once, before the first frame."""
    gc.collect()
    gc.freeze()
