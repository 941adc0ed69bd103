"""The frame loops of one camera process (``docs``: README, "A real cluster"; the runtime
modes below).

``sync``
    for each frame ``k``: ``dets = source(k)``; ``msg = node.prepare(k, dets)``; stamp ``sent_at``,
    encode once, publish on every outgoing link; wait until the inbox holds frame-``k`` messages
    from every neighbour that is currently alive, up to ``sync_timeout_s`` (the first frame waits
    up to ``startup_timeout_s``: neighbours may still be in their own start-up barrier); a
    neighbour whose liveliness is lost is no longer waited for, a late message is dropped for
    that frame (and counted); a neighbour that misses the timeout is not waited for again until
    one of its messages arrives in time (one frozen box costs its neighbours one timeout);
    ``node.update(messages of frame k)``; write the tracks. With every neighbour alive and in
    time this is exactly sim_cluster's in-process reference run.

Start-up: the barrier waits up to ``startup_timeout_s`` (5 s) for the node's own neighbours,
then starts with those that are there (a camera missing at boot costs only its own view; it
joins when it comes). A paced node's first frame waits for its neighbours' messages no longer
than any frame (``sync_timeout_s``), and for a neighbour that has sent nothing yet no longer
than ``BOOT_GRACE_S`` (nodes that boot together pass their barriers within milliseconds of each
other): a neighbour still in its own barrier (waiting for a camera that is not up) does not
hold up nodes that do not border the missing camera; it catches up when it starts, and its
neighbours resync it. An unpaced run (an experiment: every frame counts) waits up to
``startup_timeout_s`` at its first frame, so that its nodes start together. A node whose
neighbours were already running when it came (a late boot, a restart) starts at their frame.

Catch-up: a paced node that falls more than ``SKIP_FRAMES`` behind the network (a freeze of
any length, an overload) skips ahead to the network's frame, as the transport hears it from its
neighbours (``network_frame``: the least of the fresh neighbours' newest frames, so one lying
neighbour cannot fling it ahead, and never farther than the wall clock allows since the node
was last level with the network: ``PLAUSIBLE_RATE``), and paces on from there. A skip of at
most ``kappa`` frames predicts the trackers through; a longer one starts the tracker core
afresh as a restarted node does (its id counter kept), and its neighbours, seeing its frames
jump, resync it with their trackers and galleries (``edge_node.outbox``). Status phase
``catching up`` until it is level again. The source is told where the node went
(``Source.seek``): a simulated camera walks its world there in the background while the node
runs on level with the network, its frames without an image until the walk arrives (counted,
``frames_without_image``); a camera serves its current frame.

Health: the status file says ``starting``, ``running``, ``catching up``, ``degraded`` (output
failing: the node tracks and sends on, retries its files with a backoff and logs the failure
once per ``LOG_INTERVAL_S``), ``stalled`` (written by a watchdog thread when no frame completed
for ``stall_after_s``; ``sim_cluster status`` also calls a node stalled whose status file has
not been updated for that long, as a frozen process cannot write), and at exit ``finished``,
``stopped`` or ``failed``. The status, counters and id-counter files have their disk space
reserved (``output.ReservedJson``) so that they are written even on a full disk.

``async`` (event-triggered)
    never waits. Each frame: ``prepare``; the outbox's ``EventTrigger`` keeps the tracker
    entries the neighbours need (withheld measurement information worth more than
    ``gain_nats``, appearance, a tracker whose ``x_bar`` drifted more than ``drift_m`` from what
    they extrapolate, a changed ``ell``, a per-tracker heartbeat) plus merges, or says to stay
    silent; a message is sent at least every ``heartbeat_frames``. Bytes saved against sending the full message every frame are counted.
    Then ``node.update(arrived,
    stale_ok=True)`` with every message received since the last frame with frame ``<= k`` (a
    neighbour's later frames wait until we get there). The core remembers each neighbour's newest
    entry per tracker, predicts it forward, uses its ``u, U`` once and only within
    ``staleness_frames``, holds ``ell`` for ``hold_frames`` and then ages it, and ignores
    duplicates and reordered messages.

Shutdown: SIGINT / SIGTERM set a flag; the current frame is finished (a sync wait is cut short),
files are flushed, Zenoh is closed, and the process exits 0. Every exit, an internal error
included, closes the Zenoh session (its liveliness token withdrawn) first, then writes the exit
files and closes the track file and the Rerun sink; no step's failure skips another.

Exit codes (``edge_node run``)::

    0  all frames done, or stopped by SIGINT / SIGTERM (also during start-up)
    1  unexpected internal error (traceback logged)
    2  bad command line, config, or source files (one line on stderr)
    4  the Zenoh session could not be opened or declared (e.g. port in use, bad zenoh config)
    5  this node's id is already alive on the network (another process holds it)
"""
from __future__ import annotations

import inspect
import logging
import math
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from edge_node.core.config import ConfigError
from edge_node.core.node import CameraNode, NodeStats
from edge_node.core.trigger import TriggerConfig
from edge_node.driver import FrameDriver
from edge_node.faults import NO_FAULTS, FaultPlan
from edge_node.formats.tracks import TrackWriter
from edge_node.outbox import Delivery, Outbox, OutboxCounters
from edge_node.runtime import transport as tr
from edge_node.runtime.config import NodeConfig, NodeConfigError
from edge_node.runtime.inbox import FRESH_S
from edge_node.runtime.memory import freeze_startup, heap, release_freed_memory, steady_allocator
from edge_node.runtime.output import (ReservedJson, StatusWriter, clean_temporaries,
                                      counters_path, latency_summary, state_path, status_path,
                                      tracks_path, write_json_atomic)
from edge_node.runtime.preflight import preflight
from edge_node.viz import NullSink, SinkError, ground_points, open_node_sink
from protocol.messages import FrameMessage

log = logging.getLogger("edge_node.loop")

SKIP_FRAMES = 2  # a node more frames than this behind its neighbours skips ahead to them
LATE_PACING_S = 2.0  # a paced loop this far behind its clock re-anchors instead of bursting

BOOT_GRACE_S = 0.5  # a paced first frame waits this long for a neighbour that sent nothing yet
PLAUSIBLE_RATE = 1.5  # the network's frame is believed up to this many times camera rate ...
PLAUSIBLE_SLACK_S = 1.0  # ... plus this many seconds of frames, since the node was last level
STOOD_STILL_S = 1.0  # a frame that took longer: the node stood still (a freeze, an overload) ...
COUNTERS_INTERVAL_S = 10.0  # while running: the counters file rewritten, freed memory released
LOG_INTERVAL_S = 10.0  # a failing output is logged at most once per this many seconds
WATCHDOG_POLL_S = 0.25

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_TRANSPORT = 4
EXIT_DUPLICATE = 5


class Shutdown:
    """SIGINT / SIGTERM -> ``event`` (finish the frame, then stop); SIGHUP -> ``reopen`` (start
    new output files after a log rotator moved them). Restores the old handlers."""

    def __init__(self, install: bool = True):
        self.event = threading.Event()
        self.reopen = threading.Event()
        self.signal: int | None = None
        self._old: dict[int, Any] = {}
        self._install = install and threading.current_thread() is threading.main_thread()

    def _handler(self, signum, frame) -> None:
        if self.event.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt  # a second Ctrl-C: stop now
        self.signal = signum
        self.event.set()
        log.warning("signal %s: finishing the current frame, then stopping",
                    signal.Signals(signum).name)

    def __enter__(self) -> "Shutdown":
        if self._install:
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handler)
            self._old[signal.SIGHUP] = signal.signal(signal.SIGHUP, lambda *_: self.reopen.set())
        return self

    def __exit__(self, *exc) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)


@dataclass
class LoopStats:
    mode: str
    frames_total: int
    first_frame: int = 0
    frame: int | None = None  # last frame completed
    frames_done: int = 0
    trackers: int = 0
    stopped: bool = False
    startup_s: float | None = None
    wire: OutboxCounters = field(default_factory=OutboxCounters)  # what the outbox sent
    prepare_s: float = 0.0
    wait_s: float = 0.0
    update_s: float = 0.0
    frames_skipped_behind: int = 0  # frames skipped to catch up with the network
    catch_ups: int = 0  # times it skipped ahead
    core_restarts: int = 0  # skips longer than kappa: the tracker core started afresh
    implausible_frames: int = 0  # network frames heard farther ahead than the clock allows
    output_failures: int = 0  # failed writes of the track, status, counters or state files
    cpu_at_first_frame: float | None = None  # time.process_time() when the first frame began
    thread_at_first_frame: float | None = None  # time.thread_time() then (the loop's thread)
    # CPU time of the frame loop's own thread, by step (time.thread_time): the detector or
    # scenario source, the core (prepare + update), sending (encode + publish); the rest of
    # that thread writes tracks and status and waits; the process's other threads are Zenoh's
    # (its callbacks decode the neighbours' messages: the transport's receive_cpu_s)
    cpu_source_s: float = 0.0
    cpu_core_s: float = 0.0
    cpu_send_s: float = 0.0

    @property
    def frames_sent(self) -> int:  # frames whose message was published
        return self.wire.frames_sent

    @property
    def frames_skipped(self) -> int:  # async: frames whose message was not sent
        return self.wire.frames_skipped

    @property
    def bytes_saved(self) -> int:  # async: bytes not sent against full messages (all links)
        return self.wire.bytes_saved


def supports_stale(node: CameraNode) -> bool:
    """Whether this core's ``update`` takes ``stale_ok`` (async mode needs it)."""
    try:
        return "stale_ok" in inspect.signature(node.update).parameters
    except (TypeError, ValueError):
        return False


def _sleep_until(t: float, stop: threading.Event) -> None:
    while not stop.is_set():
        dt = t - time.monotonic()
        if dt <= 0:
            return
        stop.wait(min(dt, 0.1))


def fresh_core(node: CameraNode) -> CameraNode:
    """A restarted copy of ``node``: same cameras, neighbours, configuration and network, an
    empty state, the id counter where ``node`` left it (no id is reused)."""
    return CameraNode(node.cameras, node.neighbours, node.cfg, node.network, node_id=node.id,
                      first_counter=node.next_counter)


class FrameLoop:
    """Drives one ``CameraNode`` over a source and a transport (any object with the
    ``ZenohTransport`` members ``neighbours``, ``publish``, ``collect``, ``drain``,
    ``alive_neighbours``, ``counters``; tests pass fakes)."""

    def __init__(self, cfg: NodeConfig, node: CameraNode, source: Callable[[int], Any],
                 transport, *, mode: str, frames: int, writer: TrackWriter | None = None,
                 status: StatusWriter | None = None, stop: threading.Event | None = None,
                 first_frame: int = 0, status_extra: Callable[[], dict] | None = None,
                 faults: FaultPlan = NO_FAULTS, state_file: Path | None = None,
                 sink: Any = None, reopen: threading.Event | None = None,
                 checkpoint: Callable[[], None] | None = None,
                 restart_core: Callable[[CameraNode], CameraNode] = fresh_core):
        if mode not in ("sync", "async"):
            raise ValueError(f"mode must be 'sync' or 'async', got {mode!r}")
        if mode == "async" and not supports_stale(node):
            raise NodeConfigError(cfg.name, "runtime.mode", "'async' needs a tracker core whose "
                                  "CameraNode.update accepts stale_ok=True; this one does not")
        self.cfg = cfg
        self.rt = cfg.runtime
        self.source = source
        self.transport = transport
        self.mode = mode
        self.writer = writer or TrackWriter(None)
        self.status = status or StatusWriter(None)
        self.stop = stop or threading.Event()
        self.stats = LoopStats(mode, frames, first_frame)
        self.started_at = time.time()
        self._status_extra = status_extra
        self.sink = sink or NullSink()  # edge_node.viz: Rerun logging, a no-op when off
        self.reopen = reopen or threading.Event()  # set: start new output files (SIGHUP)
        self.checkpoint = checkpoint  # writes the counters file (every COUNTERS_INTERVAL_S)
        self._checkpoint_at = time.monotonic()
        self._dets: list = []  # this frame's detections (for the sink)
        self.faults = faults
        self.restart_core = restart_core
        self.retired = NodeStats()  # the counters of earlier cores (restarted after long skips)
        self.state_file = None if state_file is None else ReservedJson(state_file)
        self._saved_counter = node.next_counter
        self._prev_alive: set[int] | None = None
        self._resync: set[int] = set()  # neighbours that (re)appeared: send them everything
        self.phase = "starting"
        self.progress_at = time.monotonic()  # when the last frame completed (the watchdog)
        self._catching_up = False
        self._level = (first_frame, time.monotonic())  # (frame, when) last level with the network
        self._output_error: dict[str, str] = {}  # file kind -> why its last write failed
        self._trust_seen: dict[int, str] = {}  # each neighbour's trust state last logged
        self._relocks_seen: dict[int, int] = {}  # each camera's re-locks last logged
        self._logged_at: dict[str, float] = {}
        self._last_status: dict | None = None
        self.driver = self._new_driver(node)
        self.stats.wire = self.outbox.counters

    def _new_driver(self, node: CameraNode, counters: OutboxCounters | None = None) -> FrameDriver:
        """The node's frame driver (``edge_node.driver``, the in-process network's too)."""
        try:
            trigger = TriggerConfig(self.rt.heartbeat_frames, self.rt.drift_m, self.rt.gain_nats) \
                if self.mode == "async" else None
            return FrameDriver(node, self.transport.neighbours, self.faults, trigger, counters)
        except ConfigError as e:
            raise NodeConfigError(self.cfg.name, "runtime.heartbeat_frames", e.message) from None

    @property
    def node(self) -> CameraNode:
        return self.driver.node

    @property
    def outbox(self) -> Outbox:
        return self.driver.outbox

    @property
    def node_stats(self) -> NodeStats:
        """The core's counters over every core of this process (restarts after long skips)."""
        return self.retired.add(self.node.stats)

    # -- one frame -----------------------------------------------------------------------------
    def _send(self, msg: FrameMessage) -> None:
        """The frame's message through the driver's outbox (trigger, resync, faults, counting)."""
        errors, cut = self.outbox.counters.encode_errors, self.outbox.counters.trackers_cut
        self.driver.rejoined(self._resync)
        self._resync = set()
        deliveries, resync = self.driver.send(msg, sent_at=time.time())
        if resync:
            log.info("node %d: frame %d: resync for rejoined neighbour(s) %s",
                     self.node.id, msg.frame, sorted(resync))
        self._publish(deliveries)
        if self.outbox.counters.encode_errors > errors:
            self._say("encode", logging.ERROR, f"node {self.node.id}: cannot encode our message "
                      f"({self.outbox.last_error}): not sent")
        if self.outbox.counters.trackers_cut > cut:
            self._say("cut", logging.WARNING, f"node {self.node.id}: frame {msg.frame}: our "
                      f"message was over the wire's limits: {self.outbox.last_error}")

    def _publish(self, deliveries: list[Delivery]) -> None:
        """Hand deliveries to the transport: one call for all links when every neighbour gets
        the same bytes, else one put per link."""
        links = sorted(self.transport.neighbours)
        if deliveries and len({p for _, p in deliveries}) == 1 \
                and sorted(d for d, _ in deliveries) == links:
            self.transport.publish(deliveries[0][1])
            return
        for dst, p in deliveries:
            self.transport.publish_to(dst, p)

    def _before_frame(self, k: int) -> None:
        """Delayed (fault-injected) messages now due; neighbours that came back get a resync."""
        if self.stats.cpu_at_first_frame is None:
            self.stats.cpu_at_first_frame = time.process_time()
            self.stats.thread_at_first_frame = time.thread_time()
        self._publish(self.outbox.due(k))
        alive_now = getattr(self.transport, "alive_neighbours", None)
        if alive_now is None:
            return
        alive = set(alive_now())
        if self._prev_alive is not None:
            self._resync |= alive - self._prev_alive
        self._prev_alive = alive

    def _after_frame(self, k: int) -> None:
        """Persist the id counter when it moved; crash here if the fault plan says so."""
        if self.state_file is not None and self.node.next_counter != self._saved_counter:
            if self._write("state", lambda: self.state_file.write(
                    {"node": self.node.id, "frame": k, "next_counter": self.node.next_counter})):
                self._saved_counter = self.node.next_counter
        if not self.faults.alive(self.node.id, k + 1):
            self.writer.flush(force=True)
            log.warning("node %d: fault plan: crashing before frame %d", self.node.id, k + 1)
            logging.shutdown()
            os.kill(os.getpid(), signal.SIGKILL)

    def step_sync(self, k: int, first: bool) -> list:
        # the first frame of an unpaced run waits for the neighbours' start-ups (every frame
        # counts); a paced node does not wait for a neighbour still in its own start-up
        # (module docstring)
        if first and self.rt.fps > 0:
            def gather():
                return list(self.transport.collect(k, self.rt.sync_timeout_s, self.stop,
                                                   silent_grace=BOOT_GRACE_S).values())
        else:
            timeout = self.rt.startup_timeout_s if first else self.rt.sync_timeout_s

            def gather():
                return list(self.transport.collect(k, timeout, self.stop).values())
        return self._step(k, gather, stale_ok=False)

    def step_async(self, k: int) -> list:
        return self._step(k, lambda: self.transport.drain(k), stale_ok=True)

    def _step(self, k: int, gather: Callable[[], list], stale_ok: bool) -> list:
        """One frame: detections, ``prepare``, the message out, the neighbours' in (``gather``:
        sync waits for frame ``k``'s, async takes what has come), ``update``. Keeps the wall
        time of source + prepare, waiting and update, and the loop thread's CPU by step
        (``LoopStats``)."""
        st = self.stats
        t0, c0 = time.perf_counter(), time.thread_time()
        self._dets = self.source(k)
        c1 = time.thread_time()
        msg = self.driver.prepare(k, self._dets)
        t1, c2 = time.perf_counter(), time.thread_time()
        c3, inbox = c2, []
        if self.transport.neighbours:
            self._send(msg)
            c3 = time.thread_time()
            inbox = gather()
        t2, c4 = time.perf_counter(), time.thread_time()
        # (a neighbour whose frames jumped is resynced at the next send: Outbox.heard)
        tracks = self.driver.receive(k, inbox, stale_ok=stale_ok)
        t3, c5 = time.perf_counter(), time.thread_time()
        st.prepare_s += t1 - t0
        st.wait_s += t2 - t1
        st.update_s += t3 - t2
        st.cpu_source_s += c1 - c0
        st.cpu_core_s += (c2 - c1) + (c5 - c4)
        st.cpu_send_s += c3 - c2
        return tracks

    # -- output that may fail --------------------------------------------------------------------
    def _say(self, key: str, level: int, msg: str) -> None:
        """Log ``msg`` at most once per ``LOG_INTERVAL_S`` for ``key``."""
        now = time.monotonic()
        if now - self._logged_at.get(key, -float("inf")) >= LOG_INTERVAL_S:
            self._logged_at[key] = now
            log.log(level, "%s", msg)

    def _write(self, kind: str, write: Callable[[], Any]) -> bool:
        """Run one file write; a failure is counted, remembered (``degraded``) and logged once
        per interval, never raised."""
        try:
            write()
        except OSError as e:
            self.stats.output_failures += 1
            self._output_error[kind] = f"{e.strerror or e}"
            self._say(f"out:{kind}", logging.WARNING, f"node {self.node.id}: cannot write its "
                      f"{kind} file: {e.strerror or e}; tracking goes on (status: degraded)")
            return False
        if self._output_error.pop(kind, None) is not None:
            log.warning("node %d: its %s file is written again", self.node.id, kind)
        return True

    @property
    def output_errors(self) -> dict[str, str]:
        """Which of the node's files fail now, and why (empty: none)."""
        out = dict(self._output_error)
        if self.writer.failing:
            out["tracks"] = self.writer.error
        return out

    def _log_trust(self, k: int) -> None:
        """Each change of a neighbour's trust state, logged once (``edge_node/core/trust.py``)."""
        for n, t in self.node.stats.trust.items():
            if self._trust_seen.get(n, "trusted") != t["state"]:
                level = logging.INFO if t["state"] == "trusted" else logging.WARNING
                why = f" ({t['reason']})" if t["state"] != "trusted" and t.get("reason") else ""
                log.log(level, "node %d: frame %d: neighbour %d is %s%s", self.node.id, k, n,
                        t["state"], why)
            self._trust_seen[n] = t["state"]

    def _log_relocks(self, k: int) -> None:
        """Each re-lock of a camera's registration (R7, ``edge_node/core/registration.py``),
        logged once: the camera was knocked, or its calibration jumped."""
        for cam, reg in self.node.registrations.items():
            if reg.relocks > self._relocks_seen.get(cam, 0):
                dx, dy = reg.last_jump.tolist()
                log.warning("node %d: frame %d: camera %d re-locked: its ground map had jumped "
                            "%.2f m (%.2f, %.2f); knocked?", self.node.id, k, cam,
                            math.hypot(dx, dy), -dx, -dy)
            self._relocks_seen[cam] = reg.relocks  # (a restarted core counts from 0 again)

    def _output(self, k: int, tracks: list) -> None:
        self._log_trust(k)
        self._log_relocks(k)
        self.writer.write(tracks)
        if self.writer.failing:
            self._say("out:tracks", logging.WARNING, f"node {self.node.id}: cannot write "
                      f"{self.writer.path}: {self.writer.error}; {self.writer.pending_bytes} "
                      f"bytes of tracks wait in memory, retried with a backoff (status: degraded)")
        if self.sink.enabled:
            self._log_viz(k, tracks)

    # -- the loop ----------------------------------------------------------------------------------
    def current_phase(self) -> str:
        if self._catching_up:
            return "catching up"
        return "degraded" if self.output_errors else "running"

    def run(self) -> LoopStats:
        """Frames from ``first_frame`` on, paced at ``fps`` (0: as fast as possible). A paced
        node that fell behind its neighbours by more than ``SKIP_FRAMES`` (a freeze of any
        length, an overload) skips ahead to the network's frame (module docstring, catch-up)
        and paces on from there. (An unpaced run, an experiment, processes every frame.)"""
        st = self.stats
        fps = self.rt.fps
        t_start = time.monotonic()
        self._level = (st.first_frame, t_start)
        self.write_status("running")
        k, i = st.first_frame, 0
        last_at, hold = t_start, 0.0  # end of the previous frame; no "level" before ``hold``
        with Watchdog(self):
            while k < st.frames_total:
                if self.stop.is_set():
                    break
                self._before_frame(k)
                if self.mode == "sync":
                    tracks = self.step_sync(k, first=(st.frames_done == 0))
                else:
                    tracks = self.step_async(k)
                self._output(k, tracks)
                self._after_frame(k)
                st.frame = k
                st.frames_done += 1
                st.trackers = len(tracks)
                self.progress_at = time.monotonic()
                phase = self.current_phase()
                if self.status.due() or phase != self.phase:
                    self.writer.flush()
                    self.write_status(phase)
                    if time.monotonic() - self._checkpoint_at >= COUNTERS_INTERVAL_S:
                        if self.checkpoint is not None:
                            self._write("counters", self.checkpoint)
                        release_freed_memory()  # what message bursts left in the heap
                        self._checkpoint_at = time.monotonic()
                if self.reopen.is_set():
                    self.reopen.clear()
                    self.writer.reopen()
                    log.info("node %d: SIGHUP: reopened %s", self.node.id, self.writer.path)
                i += 1
                k += 1
                ahead = self._network_frame() if fps > 0 else None  # unpaced: every frame counts
                now = time.monotonic()
                if now - last_at > STOOD_STILL_S:
                    # ... and what it hears in the next FRESH_S may be news from before, queued
                    # while it stood still and fresh only by its arrival: it must not count as
                    # "level with the network" (after a 7 s freeze the queued frame-77 messages
                    # made the node level at 77 just then, and the network's true frame 428, a
                    # moment later, was refused as farther than the clock allows)
                    hold = now + FRESH_S
                last_at = now
                if ahead is not None and k + SKIP_FRAMES < ahead < st.frames_total:
                    if self._plausible(ahead, now, fps):
                        self._skip(k, ahead)
                        k = ahead
                        t_start, i = time.monotonic(), 0  # pace from here on
                        continue
                if ahead is not None and ahead <= k and now >= hold:  # (no fresh neighbour:
                    self._level = (k, now)  # nothing learnt)
                if ahead is None or ahead <= k:
                    if self._catching_up:
                        self._catching_up = False
                        log.info("node %d: level with the network again at frame %d",
                                 self.node.id, k)
                if fps > 0:
                    due = t_start + i / fps
                    lead = self._network_lead() if self.mode == "sync" else None
                    if self.mode == "sync" and ((ahead is not None and ahead > k) or
                                                (lead is not None and k < lead <= k + fps)):
                        # one or two frames behind the network (fewer than a skip): no pause until
                        # level, then paced from there. Paced at camera rate a node that far behind
                        # stayed behind for good, and its neighbours, no longer waiting for it,
                        # dropped every message it sent as late. Behind the most advanced
                        # neighbour (lead) too, by up to a second of frames: level with the least
                        # advanced one, a node paced at camera rate stayed 2-3 frames behind the
                        # other, which took it for lagging and never waited for it again (after a
                        # 2-minute freeze: 2.7 s to be within a frame). (Sync only: in lock-step a
                        # neighbour is ahead only of a node it no longer waits for; async nodes'
                        # clocks drift by a frame either way and would chase each other.)
                        t_start, i = time.monotonic(), 0
                    elif time.monotonic() - due > LATE_PACING_S:  # fell behind the clock: re-anchor
                        t_start, i = time.monotonic(), 0
                    else:
                        _sleep_until(due, self.stop)
        st.stopped = self.stop.is_set() and k < st.frames_total
        self.writer.flush(force=True)
        return st

    def _plausible(self, ahead: int, now: float, fps: float) -> bool:
        """Whether the network can be at frame ``ahead``: no farther than ``PLAUSIBLE_RATE``
        times camera rate (plus ``PLAUSIBLE_SLACK_S``) from where this node was last level
        with it. A frame beyond is a lie or a broken clock: counted, not followed."""
        frame, at = self._level
        limit = frame + (now - at + PLAUSIBLE_SLACK_S) * fps * PLAUSIBLE_RATE
        if ahead <= limit:
            return True
        self.stats.implausible_frames += 1
        self._say("implausible", logging.WARNING, f"node {self.node.id}: a neighbour says the "
                  f"network is at frame {ahead}, farther than the clock allows ({limit:.0f}): "
                  "not followed")
        return False

    def _skip(self, k: int, ahead: int) -> None:
        """Skip from frame ``k`` to the network's frame ``ahead`` (module docstring)."""
        st = self.stats
        gap = ahead - k
        restart = gap > self.node.cfg.kappa
        log.warning("node %d: %d frames behind the network: skipping from frame %d to %d%s",
                    self.node.id, gap, k, ahead,
                    " (the tracker core starts afresh; the neighbours resync it)" if restart else "")
        st.frames_skipped_behind += gap
        st.catch_ups += 1
        if restart:
            self.retired = self.retired.add(self.node.stats)
            self.driver = self._new_driver(self.restart_core(self.node), self.outbox.counters)
            st.core_restarts += 1
        skip_to = getattr(self.transport, "skip_to", None)
        if skip_to is not None:
            skip_to(ahead)
        seek = getattr(self.source, "seek", None)
        if seek is not None:  # a simulated camera walks there in the background (Source.seek)
            seek(ahead)
        self._catching_up = True
        if self.phase != "catching up":
            self.write_status("catching up")

    def _network_frame(self) -> int | None:
        f = getattr(self.transport, "network_frame", None)
        return None if f is None else f()

    def _network_lead(self) -> int | None:
        f = getattr(self.transport, "network_lead", None)
        return None if f is None else f()

    def _log_viz(self, k: int, tracks: list) -> None:
        """The frame to the Rerun sink: tracks, detections on the ground, counters."""
        c = self.transport.counters() if self.transport is not None else {}
        stats = {"active_trackers": len(tracks), "bytes_sent": c.get("bytes_sent", 0),
                 "dropped": sum(sum((c.get(key) or {}).values())
                                for key in ("late", "overflow", "duplicates")),
                 "rejected": sum((c.get("rejected") or {}).values()),
                 "timeouts": sum((c.get("timeouts") or {}).values()),
                 **{f"neighbours_{state}": sum(t["state"] == state
                                               for t in self.node.stats.trust.values())
                    for state in ("suspect", "quarantined")}}
        self.sink.log_frame(k, tracks, measurements_xy=ground_points(self.node.cameras[0],
                                                                     self._dets),
                            stats=stats, wall_time=time.time())

    def status_dict(self, phase: str) -> dict:
        st = self.stats
        c = self.transport.counters() if self.transport is not None else {}
        d = {
            "pid": os.getpid(),
            "node": self.node.id,
            "network": self.cfg.network,
            "mode": self.mode,
            "phase": phase,
            "frame": st.frame,
            "frames_done": st.frames_done,
            "frames_total": st.frames_total,
            "trackers": st.trackers,
            "neighbours": list(self.cfg.neighbours),
            "alive_neighbours": c.get("alive_neighbours", []),
            "bytes_sent": c.get("bytes_sent", 0),
            "messages_sent": c.get("messages_sent", 0),
            "messages_received": c.get("messages_received", 0),
            "rejected": rejected(c, self.node_stats),
            "late": sum(c.get("late", {}).values()),
            "timeouts": sum(c.get("timeouts", {}).values()),
            "frames_skipped": st.frames_skipped,
            "catch_ups": st.catch_ups,
            "frames_skipped_behind": st.frames_skipped_behind,
            "core_restarts": st.core_restarts,
            # each neighbour's trust state (trusted, suspect, quarantined; core/trust.py)
            "trust": {str(n): t["state"] for n, t in self.node.stats.trust.items()},
            # why each distrusted neighbour is (inconsistent, lagging, merges, refuted)
            "trust_reason": {str(n): t.get("reason") for n, t in self.node.stats.trust.items()
                             if t["state"] != "trusted"},
            # how often each camera's registration re-locked after a jump (R7, core/registration.py)
            "relocks": {str(c): r.relocks for c, r in self.node.registrations.items()},
            "output_errors": self.output_errors,
            "output_failures": st.output_failures,
            "stall_after_s": self.rt.stall_after_s,
            "started_at": self.started_at,
            "updated_at": time.time(),
            "finished": phase in ("finished", "stopped"),
            "stopped": st.stopped,
        }
        if self._status_extra:
            d.update(self._status_extra())
        return d

    def write_status(self, phase: str, **extra) -> None:
        """The status file now, in ``phase`` (a failure: counted and logged, never raised)."""
        d = self.status_dict(phase)
        d.update(extra)
        self.phase = phase
        self._last_status = d
        self._write("status", lambda: self.status.write(d))

    def stalled_status(self, since: float) -> dict | None:
        """The last status written, as ``stalled`` since ``since`` (monotonic): what the
        watchdog writes from its thread (it must not read the core while the loop runs it)."""
        if self._last_status is None:
            return None
        d = dict(self._last_status)
        d.update(phase="stalled", updated_at=time.time(),
                 stalled_for_s=round(time.monotonic() - since, 1))
        return d


class Watchdog:
    """A thread that writes status ``stalled`` when the loop completed no frame for
    ``stall_after_s`` (an overload, a hang inside a frame), and nothing else. A frozen process
    (SIGSTOP) cannot write at all: ``sim_cluster status`` judges its status file's age."""

    def __init__(self, loop: FrameLoop):
        self.loop = loop
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="watchdog", daemon=True)

    def __enter__(self) -> "Watchdog":
        if self.loop.status.path is not None:
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def _run(self) -> None:
        loop, after = self.loop, self.loop.rt.stall_after_s
        said_at = None
        while not self._stop.wait(WATCHDOG_POLL_S):
            since = loop.progress_at
            if time.monotonic() - since < after or loop.stop.is_set():
                said_at = None
                continue
            if said_at == since:
                continue  # said for this stall; the loop says 'running' when it moves again
            d = loop.stalled_status(since)
            if d is None:
                continue
            try:
                loop.status.write(d)
                said_at = since
                log.warning("node %d: stalled: no frame completed for %.1f s (frame %s)",
                            loop.node.id, time.monotonic() - since, d.get("frame"))
                loop.phase = "stalled"
            except OSError:
                pass


def rejected(transport_counters: dict, node_stats: NodeStats) -> dict[str, int]:
    """What this node refused, by reason: messages its transport's codec rejected (form) and
    tracker entries and merges its core's screen rejected (meaning, ``core/screen.py``)."""
    out = dict(transport_counters.get("rejected", {}))
    for reason, n in node_stats.rejected.items():
        out[reason] = out.get(reason, 0) + n
    return dict(sorted(out.items()))


def wire_counters(outbox: Outbox) -> dict:
    """The outbox's counters as the node's counters file names them."""
    w, trig = outbox.counters, outbox.trigger
    return {"frames_sent": w.frames_sent, "frames_skipped": w.frames_skipped,
            "tracker_entries": w.tracker_entries, "appearance_entries": w.appearance_entries,
            "appearance_bytes": w.appearance_bytes, "bytes_saved": w.bytes_saved,
            "encode_errors": w.encode_errors, "trackers_cut": w.trackers_cut,
            "resyncs": w.resyncs,
            "tracker_entries_sent": trig.entries_sent if trig else None,
            "tracker_entries_skipped": trig.entries_skipped if trig else None}


@dataclass
class RunReport:
    exit_code: int
    stats: LoopStats | None
    counters: dict
    tracks_file: Path | None = None


def _continue_at(writer: TrackWriter, k0: int | None, total: int) -> int | None:
    """Where a node that continues its track file starts: the network's frame ``k0`` (a join),
    but never at a frame the file already holds; ``None``: from frame 0."""
    if writer.last_frame is None:
        return k0
    return max(k0 or 0, writer.last_frame + 1)


def run_node(cfg: NodeConfig, *, frames: int | None = None, mode: str | None = None,
             transport_factory: Callable[..., Any] | None = None,
             install_signals: bool = True, join: bool = False,
             freeze_gc: bool = False,
             before_network: Callable[[], Any] | None = None) -> RunReport:
    """Run one camera process to completion. Raises ``NodeConfigError`` / ``SourceError`` for
    bad inputs, ``TransportError`` when Zenoh cannot start and ``DuplicateNodeError`` when its
    id is already alive (the CLI maps them to exit codes); returns a report otherwise. The
    start-up barrier does not fail: after ``startup_timeout_s`` the node starts with the
    neighbours that are there.

    ``join``: this process replaces one that died (or joins a running network): it starts at
    the frame its neighbours are at, not at 0, and never at a frame its track file already
    holds (a node restarted after its run ended has nothing to do); its neighbours see its
    liveliness come back and resync it with all their trackers and galleries. Without ``join``
    the same happens when a neighbour reports at start-up that it is already running (a late
    boot). The id counter persists in the output folder (``state_node<id>.json``), so a
    restarted node never reuses an id.

    ``before_network``: called once the source is open and before Zenoh is (the CLI waits there
    for its warm-up imports), so the node joins the network ready to run its first frame.

    Every way out (the end, a signal, an internal error) closes the transport first (the
    liveliness token goes: the node is not 'alive' while it writes its exit files), then writes
    the status and counters files, closes the track file and the Rerun sink; a failure of one
    step is logged and the next steps run (module docstring)."""
    if mode is not None or frames is not None:
        changes = {}
        if mode is not None:
            changes["mode"] = mode
        if frames is not None:
            changes["frames"] = frames
        cfg = cfg.with_runtime(**changes)
    rt = cfg.runtime
    mode = rt.mode
    if freeze_gc:  # a camera process: glibc's settings for months of frames, before any thread
        steady_allocator()
    ready = preflight(cfg)  # the checks `edge_node check` runs: source, tracker, id counter
    source, tcfg = ready.source, ready.tracker
    total = source.frames if rt.frames is None else min(source.frames, rt.frames)
    out = cfg.output.dir
    if out is not None:
        for tmp in clean_temporaries(out, cfg.node):
            log.info("node %d: removed %s (a write an earlier life left)", cfg.node, tmp.name)
    state_file = state_path(out, cfg.node) if out else None
    node = CameraNode(source.camera, cfg.neighbours, tcfg, cfg.network, node_id=cfg.node,
                      first_counter=ready.first_counter)
    faults = FaultPlan.load(cfg.faults) if cfg.faults is not None else NO_FAULTS
    if mode == "async" and not supports_stale(node):
        raise NodeConfigError(cfg.name, "runtime.mode", "'async' needs a tracker core whose "
                              "CameraNode.update accepts stale_ok=True; this one does not")
    status = StatusWriter(status_path(out, cfg.node) if out else None, cfg.output.status_interval_s)
    factory = transport_factory or tr.ZenohTransport
    if before_network is not None:
        before_network()
    z = cfg.zenoh
    log.info("node %d (%s, network %s): %d frames from %s; neighbours %s; listen %s connect %s",
             cfg.node, mode, cfg.network, total, source.description, list(cfg.neighbours),
             list(z.listen), list(z.connect))
    with Shutdown(install_signals) as shutdown:
        try:
            transport = factory(cfg.network, cfg.node, cfg.neighbours, z.listen, z.connect,
                                z.scouting, z.config_file, gossip=z.gossip, lease_ms=z.lease_ms,
                                shared_memory=z.shared_memory)
        except tr.TransportError as e:
            # an id already alive: its status file belongs to the process that holds the id
            if status.path is not None and not isinstance(e, tr.DuplicateNodeError):
                try:
                    write_json_atomic(status.path, {
                        "pid": os.getpid(), "node": cfg.node, "network": cfg.network,
                        "mode": mode, "phase": "failed", "finished": False,
                        "exit_code": EXIT_TRANSPORT, "error": str(e), "updated_at": time.time()})
                except OSError as e2:
                    log.warning("cannot write the status file: %s", e2)
            raise
        run = _Run(cfg, node, transport, status, join)
        try:
            return run.go(source, total, faults, state_file, shutdown, freeze_gc)
        finally:
            run.close(shutdown)


class _Run:
    """One run of a node inside its Zenoh session: the parts ``run_node``'s way out must close,
    each closed on its own (``close``)."""

    def __init__(self, cfg: NodeConfig, node: CameraNode, transport, status: StatusWriter,
                 join: bool):
        self.cfg, self.node, self.transport, self.status, self.join = cfg, node, transport, status, join
        self.writer: TrackWriter | None = None
        self.loop: FrameLoop | None = None
        self.sink: Any = NullSink()
        self.code = EXIT_FAILURE
        self.error: str | None = None

    def go(self, source, total: int, faults: FaultPlan, state_file: Path | None,
           shutdown: Shutdown, freeze_gc: bool) -> RunReport:
        cfg, rt, transport, out = self.cfg, self.cfg.runtime, self.transport, self.cfg.output.dir
        try:
            try:
                self.sink = open_node_sink(cfg, source.camera, source.units_per_metre,
                                           keep_existing=self.join)
            except SinkError as e:
                raise NodeConfigError(cfg.name, "viz.rerun", str(e)) from None
            o = cfg.output
            self.writer = writer = TrackWriter(
                tracks_path(out, cfg.node) if out else None, append=self.join,
                camera=source.camera.id, keep=o.keep,
                rotate_bytes=None if o.rotate_mb is None else int(o.rotate_mb * 1e6))
            self.loop = loop = FrameLoop(
                cfg, self.node, source, transport, mode=rt.mode, frames=total, writer=writer,
                status=self.status, stop=shutdown.event, faults=faults, state_file=state_file,
                sink=self.sink, reopen=shutdown.reopen,
                checkpoint=(lambda: write_counters(cfg, loop, transport, None))
                if out is not None else None)
            loop.write_status("starting")
            if writer.last_frame is not None and writer.last_frame + 1 >= total:
                log.warning("node %d: nothing to do: its track file already holds the run's "
                            "last frame (%d)", cfg.node, total - 1)
                loop.stats.first_frame = total
                self.code = EXIT_OK
                return RunReport(EXIT_OK, loop.stats, transport.counters(), writer.path)
            k0 = None
            if cfg.neighbours:
                try:
                    waited = transport.wait_ready(rt.startup_timeout_s, shutdown.event,
                                                  partial=True)
                except tr.StartupError:  # only when interrupted (partial: never a timeout)
                    loop.stats.stopped = True
                    self.code = EXIT_OK
                    return RunReport(EXIT_OK, loop.stats, transport.counters(), writer.path)
                loop.stats.startup_s = waited
                missing = transport.not_ready() if hasattr(transport, "not_ready") else {}
                if missing:
                    log.warning("node %d: starting without neighbour(s) %s after %.1f s (%s); "
                                "they join when they come up", cfg.node, sorted(missing), waited,
                                "; ".join(f"{n}: {', '.join(w)}" for n, w in sorted(missing.items())))
                else:
                    log.info("node %d: neighbours ready after %.3f s", cfg.node, waited)
                # a network that ran before this node came (a restart, a late boot): start at
                # its frame, not at 0; at a common boot every neighbour is still at no frame
                running = getattr(transport, "running_at_start", {})
                if self.join or running:
                    k0 = transport.wait_first_frame(rt.startup_timeout_s, shutdown.event)
            k0 = _continue_at(writer, k0, total)
            if k0:
                loop.stats.first_frame = min(k0, total)
                log.info("node %d: joining the network at frame %d", cfg.node, k0)
            if freeze_gc:  # a camera process: its start-up objects out of the collector's way
                freeze_startup()
            try:
                stats = loop.run()
            except Exception as e:
                self.error = f"{type(e).__name__}: {e}"
                raise
            self.code = EXIT_OK
            log.info("node %d: %s after %d frames (prepare %.2f s, wait %.2f s, update %.2f s)",
                     cfg.node, "stopped" if stats.stopped else "finished", stats.frames_done,
                     stats.prepare_s, stats.wait_s, stats.update_s)
            return RunReport(EXIT_OK, stats, transport.counters(), writer.path)
        except BaseException as e:
            if self.error is None and not isinstance(e, (NodeConfigError, KeyboardInterrupt)):
                self.error = f"{type(e).__name__}: {e}"
            raise

    def close(self, shutdown: Shutdown) -> None:
        """The way out, each step on its own: the transport (liveliness withdrawn), the exit
        files, the track file, the Rerun sink. A step that fails is logged; none is skipped."""
        counters: dict = {}
        lat = latency_summary([])
        steps: list[tuple[str, Callable[[], Any]]] = []

        def snapshot() -> None:
            nonlocal counters, lat
            counters = self.transport.counters()
            lat = latency_summary(self.transport.latency_samples())

        steps.append(("read the wire counters", snapshot))
        steps.append(("close the Zenoh session", self.transport.close))
        if self.writer is not None:
            steps.append(("close the track file", self._close_writer))
        if self.loop is not None:
            steps.append(("write the exit files", lambda: self._exit_files(counters, lat)))
        steps.append(("close the Rerun sink", self.sink.close))
        for what, step in steps:
            try:
                step()
            except Exception as e:  # noqa: BLE001 - one failing step must not skip the others
                log.warning("node %d: cannot %s: %s: %s", self.cfg.node, what,
                            type(e).__name__, e)
        # --rerun serve: keep serving until Ctrl-C
        if getattr(self.sink, "url", None) and self.code == EXIT_OK:
            log.warning("node %d: Rerun web viewer at %s until Ctrl-C", self.cfg.node, self.sink.url)
            shutdown.event.wait()

    def _close_writer(self) -> None:
        if not self.writer.close() and self.loop is not None:
            self.loop.stats.output_failures += 1

    def _exit_files(self, counters: dict, lat: dict) -> None:
        loop = self.loop
        code = self.code
        phase = ("stopped" if loop.stats.stopped else "finished") if code == EXIT_OK else "failed"
        try:
            loop.write_status(phase, exit_code=code, error=self.error)
        finally:
            if self.cfg.output.dir is not None:
                write_counters(self.cfg, loop, None, code, counters, lat)


def write_counters(cfg: NodeConfig, loop: FrameLoop, transport, code: int | None,
                   counters: dict | None = None, lat: dict | None = None) -> None:
    """``counters_node<id>.json``: rewritten while running (``exit_code`` null) and at exit.
    ``counters`` / ``lat``: the transport's, when it is already closed."""
    if counters is None:
        counters = transport.counters()
        lat = latency_summary(transport.latency_samples())
    st = loop.stats
    node_stats = loop.node_stats
    ReservedJson(counters_path(cfg.output.dir, cfg.node)).write({
        "node": cfg.node, "network": cfg.network, "mode": loop.mode,
        "exit_code": code, "frames_done": st.frames_done,
        "frames_total": st.frames_total, "stopped": st.stopped,
        "startup_s": st.startup_s, "latency": lat, **counters,
        "rejected": rejected(counters, node_stats),
        # per neighbour: trust state, frames suspect and quarantined (edge_node/core/trust.py)
        "trust": {str(n): t for n, t in node_stats.trust.items()},
        **wire_counters(loop.outbox),
        "viz_dropped": getattr(loop.sink, "dropped", 0),  # Rerun calls a stuck viewer cost
        "timing_s": {"prepare": st.prepare_s, "wait": st.wait_s, "update": st.update_s},
        # CPU of the whole process (all its threads: Zenoh's too), and since its first frame
        "cpu_s": {"process": time.process_time(),
                  "frames": None if st.cpu_at_first_frame is None
                  else time.process_time() - st.cpu_at_first_frame,
                  # the frame loop's thread since its first frame, and by step (LoopStats)
                  "loop": None if st.thread_at_first_frame is None
                  else time.thread_time() - st.thread_at_first_frame,
                  "source": st.cpu_source_s, "core": st.cpu_core_s, "send": st.cpu_send_s},
        "rotations": loop.writer.rotations,
        "catch_up": {"catch_ups": st.catch_ups, "frames_skipped": st.frames_skipped_behind,
                     "core_restarts": st.core_restarts,
                     "implausible_frames": st.implausible_frames,
                     # frames the camera had no image for yet after a skip (Source.seek)
                     "frames_without_image": getattr(loop.source, "frames_without_image", 0)},
        "output": {"failures": st.output_failures + loop.writer.failures,
                   "errors": loop.output_errors,
                   "track_frames_dropped": loop.writer.frames_dropped,
                   "track_write_failures": loop.writer.failures},
        "heap": heap(),  # glibc's in-use and free heap, MB (null elsewhere)
        "node_stats": dict(vars(node_stats)),
    })
