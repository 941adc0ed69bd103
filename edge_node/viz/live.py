"""A streaming Rerun sink fed from a thread of its own, so that tracking never waits on a viewer.

Rerun buffers what it streams to a viewer that it cannot reach (``connect`` to an address
nothing listens on, a viewer closed during the run), and once that buffer is full its ``log``
blocks the caller until there is room again. Called from a camera process's frame loop, that
stopped the node: streaming to nowhere, two nodes stopped tracking after about 9,100 frames
(``tests/test_viz.py``). A :class:`LiveSink` hands each call to a logging thread through a
bounded queue; when the thread is stuck the queue fills and the frames it cannot take are
dropped and counted (``dropped``, in the node's counters as ``viz_dropped``). A saved recording
(``save``) is not wrapped: a file takes every frame.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

log = logging.getLogger(__name__)

LIVE_QUEUE = 256  # calls waiting for the logging thread (a few seconds of frames)


def _forwarded(name: str):
    """A sink method of ``LiveSink``: the call, queued for the logging thread."""
    def call(self, *args, **kwargs) -> None:
        self._put(name, args, kwargs)
    call.__name__ = name
    return call


class LiveSink:
    """``sink`` (a ``RerunSink``) behind a queue of ``depth`` calls and one logging thread.
    ``close`` waits up to ``timeout`` s for the queue to drain, then closes ``sink`` (whose own
    flush is bounded too)."""

    enabled = True

    def __init__(self, sink: Any, *, depth: int = LIVE_QUEUE, timeout: float = 5.0):
        self.sink = sink
        self.spec = sink.spec
        self.url = getattr(sink, "url", None)
        self.timeout = timeout
        self.dropped = 0  # calls not delivered: the queue was full
        self.failed = 0  # calls the sink raised on (logged once)
        self._q: queue.Queue = queue.Queue(depth)
        self._thread = threading.Thread(target=self._run, name="rerun-sink", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            name, args, kwargs = item
            try:
                getattr(self.sink, name)(*args, **kwargs)
            except Exception as e:  # noqa: BLE001 - a viewer's trouble is not the node's
                self.failed += 1
                if self.failed == 1:
                    log.warning("Rerun (%s): %s failed: %s (further failures are counted)",
                                self.spec, name, e)

    def _put(self, name: str, args: tuple, kwargs: dict) -> None:
        try:
            self._q.put_nowait((name, args, kwargs))
        except queue.Full:
            self.dropped += 1

    log_world = _forwarded("log_world")
    log_cameras = _forwarded("log_cameras")
    log_truth = _forwarded("log_truth")
    log_frame = _forwarded("log_frame")
    log_disagreement = _forwarded("log_disagreement")
    log_image = _forwarded("log_image")

    def close(self) -> bool:
        """Drain (up to ``timeout``), close the sink; never raises. ``False`` when something
        was not delivered (a warning says what)."""
        deadline = time.monotonic() + self.timeout
        try:
            self._q.put(None, timeout=self.timeout)
        except queue.Full:
            pass
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive():  # stuck in Rerun: its sink cannot be closed from here
            log.warning("Rerun (%s): the viewer took nothing for %.0f s; %d calls dropped, "
                        "the rest not delivered", self.spec, self.timeout, self.dropped)
            return False
        ok = self.sink.close()
        if self.dropped:
            log.warning("Rerun (%s): %d calls dropped while the viewer did not keep up",
                        self.spec, self.dropped)
        return ok and not self.dropped and not self.failed
