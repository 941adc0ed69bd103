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

``steady_allocator`` fixes two of glibc's settings before the first frame. (1) The size above
which a block is its own memory mapping, unmapped when freed (128 KiB): by default glibc raises
it to the size of every larger block freed, up to 32 MiB, and with it the free heap top it keeps
(twice that), so a source's per-chunk arrays of a few MB (100 frames of descriptors) were kept
in the heap after their frame and resident memory swung by ~10 MB between two trims. (2) At most
two arenas: Zenoh's threads decode messages into arenas of their own, and each arena keeps what
the frame loop freed there.

``heap()`` reports glibc's own figures (bytes in use and free in the heap) for the counters file.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc

MMAP_THRESHOLD = 128 * 1024  # bytes: larger blocks are mapped and unmapped on their own
ARENAS = 2
_M_MMAP_THRESHOLD, _M_ARENA_MAX = -3, -8  # glibc's mallopt parameters (malloc.h)

_libc = None
try:
    _name = ctypes.util.find_library("c")
    _libc = ctypes.CDLL(_name) if _name else None
    _trim = getattr(_libc, "malloc_trim", None) if _libc is not None else None
    _mallopt = getattr(_libc, "mallopt", None) if _libc is not None else None
    _mallinfo2 = getattr(_libc, "mallinfo2", None) if _libc is not None else None
except OSError:  # no C library to load: nothing to trim
    _trim = _mallopt = _mallinfo2 = None


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]


if _mallinfo2 is not None:
    _mallinfo2.restype = _MallInfo2


def release_freed_memory() -> bool:
    """Return freed heap pages to the system (glibc ``malloc_trim``); whether anything was."""
    return bool(_trim(0)) if _trim is not None else False


def freeze_startup() -> None:
    """Collect once, then exempt every object alive now from later cyclic collections
    (``gc.freeze``; module docstring). Call it once, before the first frame."""
    gc.collect()
    gc.freeze()


def steady_allocator() -> bool:
    """glibc's mmap threshold fixed at ``MMAP_THRESHOLD`` and at most ``ARENAS`` arenas (module
    docstring); whether both were set (False elsewhere than glibc). Call it once, early: before
    Zenoh starts its threads."""
    if _mallopt is None:
        return False
    return bool(_mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) & bool(_mallopt(_M_ARENA_MAX, ARENAS))


def heap() -> dict[str, float] | None:
    """glibc's heap figures in MB: ``in_use`` (allocated blocks, mapped ones included) and
    ``free`` (held by the allocator, not returned); ``None`` elsewhere."""
    if _mallinfo2 is None:
        return None
    m = _mallinfo2()
    return {"in_use_mb": (m.uordblks + m.hblkhd) / 2**20, "free_mb": m.fordblks / 2**20}
