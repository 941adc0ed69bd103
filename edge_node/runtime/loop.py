"""The frame loops of one camera process (DESIGN.md, "Runtime modes").

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

Start-up: the barrier waits up to ``startup_timeout_s`` for every neighbour, then starts with
those that are there (a camera missing at boot costs only its own view; it joins when it comes).
A node whose neighbours were already running when it came (a late boot, a restart) starts at
their frame. A paced node that falls more than ``SKIP_FRAMES`` behind the network (a freeze,
an overload) skips ahead to the network's frame and paces on from there.

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
files are flushed, Zenoh is closed, and the process exits 0.

Exit codes (``edge_node run``)::

    0  all frames done, or stopped by SIGINT / SIGTERM (also during start-up)
    1  unexpected internal error (traceback logged)
    2  bad command line, config, or source files (one line on stderr)
    3  (no longer used: a neighbour missing at start-up is named in a warning, not fatal)
    4  the Zenoh session could not be opened or declared (e.g. port in use, bad zenoh config)
    5  this node's id is already alive on the network (another process holds it)
"""
from __future__ import annotations

import inspect
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from edge_node.core.config import ConfigError
from edge_node.core.node import CameraNode
from edge_node.core.trigger import EventTrigger, TriggerConfig
from edge_node.faults import NO_FAULTS, FaultPlan
from edge_node.formats.tracks import TrackWriter
from edge_node.outbox import Delivery, Outbox, OutboxCounters
from edge_node.runtime import transport as tr
from edge_node.runtime.config import NodeConfig, NodeConfigError
from edge_node.runtime.memory import freeze_startup, heap, release_freed_memory, steady_allocator
from edge_node.runtime.output import (StatusWriter, counters_path, latency_summary, state_path,
                                      status_path, tracks_path, write_json_atomic)
from edge_node.runtime.preflight import preflight
from edge_node.viz import NullSink, SinkError, ground_points, open_node_sink
from protocol.messages import FrameMessage

log = logging.getLogger("edge_node.loop")

SKIP_FRAMES = 2  # a node more frames than this behind its neighbours skips ahead to them
LATE_PACING_S = 1.0  # a paced loop this far behind its clock re-anchors instead of bursting

COUNTERS_INTERVAL_S = 10.0  # while running: the counters file rewritten, freed memory released

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
                 checkpoint: Callable[[], None] | None = None):
        if mode not in ("sync", "async"):
            raise ValueError(f"mode must be 'sync' or 'async', got {mode!r}")
        if mode == "async" and not supports_stale(node):
            raise NodeConfigError(cfg.name, "runtime.mode", "'async' needs a tracker core whose "
                                  "CameraNode.update accepts stale_ok=True; this one does not")
        self.cfg = cfg
        self.rt = cfg.runtime
        self.node = node
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
        self.state_file = state_file  # persists the tracker counter: a restart reuses no id
        self._saved_counter = node.next_counter
        self._prev_alive: set[int] | None = None
        self._resync: set[int] = set()  # neighbours that (re)appeared: send them everything
        trigger = None
        if mode == "async":
            try:
                trigger = EventTrigger(TriggerConfig(self.rt.heartbeat_frames, self.rt.drift_m,
                                                     self.rt.gain_nats),
                                       node.cfg.dt, node.cfg.units_per_metre, node.cfg.kappa,
                                       node.cfg.hold_frames)
            except ConfigError as e:
                raise NodeConfigError(cfg.name, "runtime.heartbeat_frames", e.message) from None
        self.outbox = Outbox(node.id, transport.neighbours, faults, trigger)
        self.stats.wire = self.outbox.counters

    # -- one frame -----------------------------------------------------------------------------
    def _send(self, msg: FrameMessage) -> None:
        """The frame's message through the outbox (trigger, resync, faults, counting)."""
        errors = self.outbox.counters.encode_errors
        resync = self._resync & set(self.transport.neighbours)
        if resync:
            log.info("node %d: frame %d: resync for rejoined neighbour(s) %s",
                     self.node.id, msg.frame, sorted(resync))
        self._publish(self.outbox.send(msg, resync=resync,
                                       resync_message=self.node.resync_message,
                                       sent_at=time.time(),
                                       covariance=self.node.covariances))
        self._resync -= resync
        if self.outbox.counters.encode_errors > errors:
            log.error("node %d: cannot encode our message (%s): not sent", self.node.id,
                      self.outbox.last_error)

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
            write_json_atomic(self.state_file, {"node": self.node.id, "frame": k,
                                                "next_counter": self.node.next_counter})
            self._saved_counter = self.node.next_counter
        if not self.faults.alive(self.node.id, k + 1):
            self.writer.flush()
            log.warning("node %d: fault plan: crashing before frame %d", self.node.id, k + 1)
            logging.shutdown()
            os.kill(os.getpid(), signal.SIGKILL)

    def step_sync(self, k: int, first: bool) -> list:
        timeout = self.rt.startup_timeout_s if first else self.rt.sync_timeout_s
        return self._step(k, lambda: list(self.transport.collect(k, timeout, self.stop).values()),
                          stale_ok=False)

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
        msg = self.node.prepare(k, self._dets)
        t1, c2 = time.perf_counter(), time.thread_time()
        c3, inbox = c2, []
        if self.transport.neighbours:
            self._send(msg)
            c3 = time.thread_time()
            inbox = gather()
        t2, c4 = time.perf_counter(), time.thread_time()
        tracks = self.node.update(inbox, stale_ok=stale_ok)
        t3, c5 = time.perf_counter(), time.thread_time()
        st.prepare_s += t1 - t0
        st.wait_s += t2 - t1
        st.update_s += t3 - t2
        st.cpu_source_s += c1 - c0
        st.cpu_core_s += (c2 - c1) + (c5 - c4)
        st.cpu_send_s += c3 - c2
        return tracks

    # -- the loop ----------------------------------------------------------------------------------
    def run(self) -> LoopStats:
        """Frames from ``first_frame`` on, paced at ``fps`` (0: as fast as possible). A paced
        node that fell behind its neighbours by more than ``SKIP_FRAMES`` (a freeze, an
        overload) skips ahead to the network's frame, as a restarted node joins: the skipped
        frames are predicted through, not processed, and the pacing restarts from there. (An
        unpaced run, an experiment, processes every frame.)"""
        st = self.stats
        fps = self.rt.fps
        t_start = time.monotonic()
        self.write_status("running")
        k, i = st.first_frame, 0
        while k < st.frames_total:
            if self.stop.is_set():
                break
            self._before_frame(k)
            if self.mode == "sync":
                tracks = self.step_sync(k, first=(st.frames_done == 0))
            else:
                tracks = self.step_async(k)
            self.writer.write(tracks)
            if self.sink.enabled:
                self._log_viz(k, tracks)
            self._after_frame(k)
            st.frame = k
            st.frames_done += 1
            st.trackers = len(tracks)
            if self.status.due():
                self.writer.flush()
                self.write_status("running")
                if time.monotonic() - self._checkpoint_at >= COUNTERS_INTERVAL_S:
                    if self.checkpoint is not None:
                        self.checkpoint()
                    release_freed_memory()  # what message bursts left in the heap
                    self._checkpoint_at = time.monotonic()
            if self.reopen.is_set():
                self.reopen.clear()
                self.writer.reopen()
                log.info("node %d: SIGHUP: reopened %s", self.node.id, self.writer.path)
            i += 1
            k += 1
            ahead = self._network_frame() if fps > 0 else None  # unpaced: every frame counts
            if ahead is not None and k + SKIP_FRAMES < ahead < st.frames_total:
                log.warning("node %d: %d frames behind the network: skipping from frame %d to %d",
                            self.node.id, ahead - k, k, ahead)
                st.frames_skipped_behind += ahead - k
                st.catch_ups += 1
                k = ahead
                t_start, i = time.monotonic(), 0  # pace from here on
                continue
            if fps > 0:
                due = t_start + i / fps
                if self.mode == "sync" and ahead is not None and ahead > k:
                    # one or two frames behind the network (fewer than a skip): no pause until
                    # level, then paced from there. Paced at camera rate a node that far behind
                    # stayed behind for good, and its neighbours, no longer waiting for it,
                    # dropped every message it sent as late. (Sync only: in lock-step a
                    # neighbour is ahead only of a node it no longer waits for; async nodes'
                    # clocks drift by a frame either way and would chase each other.)
                    t_start, i = time.monotonic(), 0
                elif time.monotonic() - due > LATE_PACING_S:  # fell behind the clock: re-anchor
                    t_start, i = time.monotonic(), 0
                else:
                    _sleep_until(due, self.stop)
        st.stopped = self.stop.is_set() and k < st.frames_total
        self.writer.flush()
        return st

    def _network_frame(self) -> int | None:
        f = getattr(self.transport, "network_frame", None)
        return None if f is None else f()

    def _log_viz(self, k: int, tracks: list) -> None:
        """The frame to the Rerun sink: tracks, detections on the ground, counters."""
        c = self.transport.counters() if self.transport is not None else {}
        stats = {"active_trackers": len(tracks), "bytes_sent": c.get("bytes_sent", 0),
                 "dropped": sum(sum((c.get(key) or {}).values())
                                for key in ("late", "overflow", "duplicates")),
                 "rejected": sum((c.get("rejected") or {}).values()),
                 "timeouts": sum((c.get("timeouts") or {}).values())}
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
            "rejected": rejected(c, self.node),
            "late": sum(c.get("late", {}).values()),
            "timeouts": sum(c.get("timeouts", {}).values()),
            "frames_skipped": st.frames_skipped,
            "started_at": self.started_at,
            "updated_at": time.time(),
            "finished": phase in ("finished", "stopped"),
            "stopped": st.stopped,
        }
        if self._status_extra:
            d.update(self._status_extra())
        return d

    def write_status(self, phase: str) -> None:
        try:
            self.status.write(self.status_dict(phase))
        except OSError as e:
            log.warning("cannot write status: %s", e)


def rejected(transport_counters: dict, node: CameraNode) -> dict[str, int]:
    """What this node refused, by reason: messages its transport's codec rejected (form) and
    tracker entries and merges its core's screen rejected (meaning, ``core/screen.py``)."""
    out = dict(transport_counters.get("rejected", {}))
    for reason, n in node.stats.rejected.items():
        out[reason] = out.get(reason, 0) + n
    return dict(sorted(out.items()))


def wire_counters(outbox: Outbox) -> dict:
    """The outbox's counters as the node's counters file names them."""
    w, trig = outbox.counters, outbox.trigger
    return {"frames_sent": w.frames_sent, "frames_skipped": w.frames_skipped,
            "tracker_entries": w.tracker_entries, "appearance_entries": w.appearance_entries,
            "appearance_bytes": w.appearance_bytes, "bytes_saved": w.bytes_saved,
            "encode_errors": w.encode_errors,
            "tracker_entries_sent": trig.entries_sent if trig else None,
            "tracker_entries_skipped": trig.entries_skipped if trig else None}


@dataclass
class RunReport:
    exit_code: int
    stats: LoopStats | None
    counters: dict
    tracks_file: Path | None = None


def run_node(cfg: NodeConfig, *, frames: int | None = None, mode: str | None = None,
             transport_factory: Callable[..., Any] | None = None,
             install_signals: bool = True, join: bool = False,
             freeze_gc: bool = False) -> RunReport:
    """Run one camera process to completion. Raises ``NodeConfigError`` / ``SourceError`` for
    bad inputs, ``TransportError`` when Zenoh cannot start and ``DuplicateNodeError`` when its
    id is already alive (the CLI maps them to exit codes); returns a report otherwise. The
    start-up barrier does not fail: after ``startup_timeout_s`` the node starts with the
    neighbours that are there.

    ``join``: this process replaces one that died (or joins a running network): it starts at
    the frame its neighbours are at, not at 0; they see its liveliness come back and resync it
    with all their trackers and galleries. Without ``join`` the same happens when a neighbour
    reports at start-up that it is already running (a late boot). The id counter persists in the output folder
    (``state_node<id>.json``), so a restarted node never reuses an id."""
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
    state_file = state_path(out, cfg.node) if out else None
    node = CameraNode(source.camera, cfg.neighbours, tcfg, cfg.network, node_id=cfg.node,
                      first_counter=ready.first_counter)
    faults = FaultPlan.load(cfg.faults) if cfg.faults is not None else NO_FAULTS
    if mode == "async" and not supports_stale(node):
        raise NodeConfigError(cfg.name, "runtime.mode", "'async' needs a tracker core whose "
                              "CameraNode.update accepts stale_ok=True; this one does not")
    status = StatusWriter(status_path(out, cfg.node) if out else None, cfg.output.status_interval_s)
    factory = transport_factory or tr.ZenohTransport
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
                write_json_atomic(status.path, {
                    "pid": os.getpid(), "node": cfg.node, "network": cfg.network, "mode": mode,
                    "phase": "failed", "finished": False, "exit_code": EXIT_TRANSPORT,
                    "error": str(e), "updated_at": time.time()})
            raise
        writer = None
        loop = None
        sink = NullSink()
        code = EXIT_FAILURE
        error: str | None = None
        try:
            try:
                sink = open_node_sink(cfg, source.camera, source.units_per_metre,
                                      keep_existing=join)
            except SinkError as e:
                raise NodeConfigError(cfg.name, "viz.rerun", str(e)) from None
            o = cfg.output
            writer = TrackWriter(tracks_path(out, cfg.node) if out else None, append=join,
                                 camera=source.camera.id, keep=o.keep,
                                 rotate_bytes=None if o.rotate_mb is None
                                 else int(o.rotate_mb * 1e6))
            loop = FrameLoop(cfg, node, source, transport, mode=mode, frames=total,
                             writer=writer, status=status, stop=shutdown.event,
                             faults=faults, state_file=state_file, sink=sink,
                             reopen=shutdown.reopen,
                             checkpoint=(lambda: write_counters(cfg, loop, node, transport, None))
                             if out is not None else None)
            loop.write_status("starting")
            if cfg.neighbours:
                try:
                    waited = transport.wait_ready(rt.startup_timeout_s, shutdown.event,
                                                  partial=True)
                except tr.StartupError:  # only when interrupted (partial: never a timeout)
                    loop.stats.stopped = True
                    code = EXIT_OK
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
                k0 = None
                if join or running:
                    k0 = transport.wait_first_frame(rt.startup_timeout_s, shutdown.event)
                if k0:
                    loop.stats.first_frame = min(k0, total)
                    log.info("node %d: joining the network at frame %d", cfg.node, k0)
            if freeze_gc:  # a camera process: its start-up objects out of the collector's way
                freeze_startup()
            try:
                stats = loop.run()
            except Exception as e:
                error = f"{type(e).__name__}: {e}"
                raise
            code = EXIT_OK
            log.info("node %d: %s after %d frames (prepare %.2f s, wait %.2f s, update %.2f s)",
                     cfg.node, "stopped" if stats.stopped else "finished", stats.frames_done,
                     stats.prepare_s, stats.wait_s, stats.update_s)
            return RunReport(EXIT_OK, stats, transport.counters(), writer.path)
        finally:
            if writer is not None:
                writer.close()
            counters = {}
            try:
                counters = transport.counters()
                lat = latency_summary(transport.latency_samples())
            except Exception:  # noqa: BLE001 - best effort on the way out
                lat = latency_summary([])
            transport.close()
            if loop is not None:
                phase = ("stopped" if loop.stats.stopped else "finished") if code == EXIT_OK else "failed"
                extra = {"exit_code": code, "error": error}
                try:
                    d = loop.status_dict(phase)
                    d.update(extra)
                    if status.path is not None:
                        write_json_atomic(status.path, d)
                    if out is not None:
                        write_counters(cfg, loop, node, None, code, counters, lat)
                except OSError as e:
                    log.warning("cannot write the exit files: %s", e)
            # the node's own files first: a viewer that cannot be reached holds the close up to
            # FLUSH_TIMEOUT_S, longer than a launcher's SIGTERM grace may wait
            sink.close()
            if sink.url and code == EXIT_OK:  # --rerun serve: keep serving until Ctrl-C
                log.warning("node %d: Rerun web viewer at %s until Ctrl-C", cfg.node, sink.url)
                shutdown.event.wait()


def write_counters(cfg: NodeConfig, loop: FrameLoop, node: CameraNode, transport, code: int | None,
                   counters: dict | None = None, lat: dict | None = None) -> None:
    """``counters_node<id>.json``: rewritten while running (``exit_code`` null) and at exit.
    ``counters`` / ``lat``: the transport's, when it is already closed."""
    if counters is None:
        counters = transport.counters()
        lat = latency_summary(transport.latency_samples())
    st = loop.stats
    write_json_atomic(counters_path(cfg.output.dir, cfg.node), {
        "node": cfg.node, "network": cfg.network, "mode": loop.mode,
        "exit_code": code, "frames_done": st.frames_done,
        "frames_total": st.frames_total, "stopped": st.stopped,
        "startup_s": st.startup_s, "latency": lat, **counters,
        "rejected": rejected(counters, node),
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
        "heap": heap(),  # glibc's in-use and free heap, MB (null elsewhere)
        "node_stats": dict(vars(node.stats)),
    })
