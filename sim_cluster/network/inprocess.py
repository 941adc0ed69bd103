"""The in-process network: N ``CameraNode`` cores driven frame by frame in one process.

Every message really goes through the wire codec and the same sending path as a camera process
(``edge_node.outbox.Outbox``: event trigger, resync, fault plan, byte counting); each receiver
decodes (and validates) what arrives. This is the reference run that the multi-process
deployment must reproduce.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import msgpack
import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode, NodeStats
from edge_node.core.trigger import TriggerConfig, check_heartbeat
from edge_node.driver import FrameDriver
from edge_node.faults import NO_FAULTS, FaultPlan
from edge_node.outbox import Outbox, OutboxCounters
from edge_node.core.types import Track
from protocol import codec
from protocol.messages import FrameMessage
from sim_cluster.scenarios.data import ScenarioData
from sim_cluster.network.topology import Adjacency

CENTRALIZED = "centralized"


@dataclass
class WireCounters:
    """Bytes actually encoded, per directed link, and what they carried: the network-wide sum
    of every node's ``OutboxCounters``."""

    bytes_per_link: dict[tuple[int, int], int] = field(default_factory=dict)
    messages: int = 0
    tracker_entries: int = 0  # (tracker, link, frame) triples sent
    appearance_entries: int = 0  # trackers sent with their appearance, per link
    appearance_bytes: int = 0  # bytes of those appearance fields, per link

    @classmethod
    def of(cls, outboxes: dict[int, OutboxCounters]) -> "WireCounters":
        w = cls()
        for src, c in sorted(outboxes.items()):
            for dst, b in sorted(c.bytes_per_link.items()):
                w.bytes_per_link[(src, dst)] = b
            w.messages += c.messages
            w.tracker_entries += c.tracker_entries
            w.appearance_entries += c.appearance_entries
            w.appearance_bytes += c.appearance_bytes
        return w

    @property
    def total_bytes(self) -> int:
        return sum(self.bytes_per_link.values())


@dataclass
class RunResult:
    scenario: str
    topology: str
    config: str
    seed: int
    frames: int
    adjacency: Adjacency | None
    tracks: dict[int, list[list[Track]]]  # node -> frame -> tracks
    wire: WireCounters
    stats: dict[int, NodeStats]
    data: ScenarioData | None = None
    mode: str = "sync"
    sends: dict[int, tuple[int, int]] = field(default_factory=dict)  # async: entries (sent, skipped)
    # node -> {camera: Registration} at the end of the run (registration on)
    registration: dict[int, dict] = field(default_factory=dict)
    # node -> frame -> {camera: Registration}: a copy after every frame, when asked for
    registration_history: dict[int, list[dict]] = field(default_factory=dict)
    # node -> what it measured of its re-id at the end of the run (reidquality.summary)
    reid: dict[int, dict] = field(default_factory=dict)

    def bandwidth(self) -> dict:
        """Measured bandwidth, beside nothing assumed: bytes the codec produced."""
        w, f = self.wire, max(self.frames, 1)
        non_app = w.total_bytes - w.appearance_bytes
        return {
            "bytes_per_frame": w.total_bytes / f,
            "bytes_per_tracker_frame": (non_app / w.tracker_entries) if w.tracker_entries else 0.0,
            "appearance_bytes_per_new_tracker":
                (w.appearance_bytes / w.appearance_entries) if w.appearance_entries else 0.0,
            "per_link": {f"{s}->{d}": b / f for (s, d), b in sorted(w.bytes_per_link.items())},
            "messages": w.messages,
        }

    def registration_summary(self) -> dict:
        """Each camera's registration correction at the end of the run: translation at its
        reference point (m), rotation (degrees), scale, foot-point offset (m)."""
        upm = self.data.units_per_metre if self.data is not None else 1.0
        out = {}
        for n, regs in sorted(self.registration.items()):
            if regs:
                out[str(n)] = {str(c): r.summary(upm) for c, r in sorted(regs.items())}
        return out

    def summary(self) -> dict:
        ids = {str(n): len({t.id for frame in fr for t in frame}) for n, fr in self.tracks.items()}
        return {
            "scenario": self.scenario,
            "topology": self.topology,
            "config": self.config,
            "seed": self.seed,
            "frames": self.frames,
            "nodes": len(self.tracks),
            "bandwidth": self.bandwidth(),
            "tracks": {"ids_per_node": ids},
            "manager": {str(n): vars(s) for n, s in sorted(self.stats.items())},
            "mode": self.mode,
            "registration": self.registration_summary(),
            "reid": {str(n): r for n, r in sorted(self.reid.items())},
        }


def raw_detection_bytes(detections, camera_id: int, frame: int) -> bytes:
    """What a camera would send a central server per frame: its boxes (float32) and
    descriptors (float16), msgpack-framed. Used to count the centralized baseline's bandwidth."""
    boxes = np.asarray([d.box for d in detections], dtype=np.float32).reshape(-1, 4)
    descs = [d.descriptor for d in detections if d.descriptor is not None]
    desc = np.asarray(descs, dtype=np.float16).tobytes() if descs else b""
    return msgpack.packb([camera_id, frame, boxes.tobytes(), desc], use_bin_type=True)


def run_network(data: ScenarioData, adjacency: Adjacency | str, cfg: TrackerConfig, *,
                topology_name: str | None = None, network: str = "sim",
                frames: int | None = None, mode: str = "sync",
                faults: FaultPlan = NO_FAULTS, trigger: TriggerConfig | None = None,
                progress: Callable[[int, int], None] | None = None,
                registration_history: bool = False,
                on_frame: Callable[[int, dict[int, list[Track]]], None] | None = None,
                probe: Callable[[int, int, float, CameraNode], None] | None = None
                ) -> RunResult:
    """Run ``data`` (a ``ScenarioData`` or a ``ScenarioStream``) through the network
    ``adjacency`` (or ``"centralized"``) with ``cfg``.

    ``mode="sync"``: every node fuses its neighbours' frame-``k`` messages at frame ``k`` (a
    message that arrives late is useless, as in the synchronous runtime). ``mode="async"``: the
    event-triggered variant: a node sends only when ``EventTrigger`` says so, and fuses each
    neighbour's latest message whatever its frame. ``faults`` loses, delays, duplicates and cuts
    messages and crashes / restarts nodes, deterministically from its seed.
    ``registration_history``: keep a copy of every camera's registration after every frame
    (``RunResult.registration_history``; memory grows with the frames); the final state is
    always in ``RunResult.registration``. ``on_frame(k, {node: tracks})``: each frame's tracks go
    there instead of into ``RunResult.tracks`` (a long run over a stream holds no history).
    ``probe(k, node, cpu_s, camera_node)``: after each live node's frame ``k``, the CPU time
    (``time.process_time``) its ``prepare`` and ``update`` took, and the node itself (what a
    benchmark reads: trackers held, ...).
    """
    if mode not in ("sync", "async"):
        raise ValueError(f"mode must be 'sync' or 'async', got {mode!r}")
    frames = data.frames if frames is None else min(frames, data.frames)
    cfg = cfg.with_(fps=data.fps, units_per_metre=data.units_per_metre)
    if adjacency == CENTRALIZED:
        return _run_centralized(data, cfg, frames, progress, on_frame)
    n = data.num_cameras
    if sorted(adjacency) != list(range(n)):
        raise ValueError(f"topology has nodes {sorted(adjacency)}, scenario has cameras 0..{n - 1}")
    trigger = trigger or TriggerConfig()
    if mode == "async":
        check_heartbeat(trigger, cfg.kappa, cfg.hold_frames)

    def fresh(i: int, first_counter: int = 0) -> FrameDriver:
        node = CameraNode(data.cameras[i], adjacency[i], cfg, network, first_counter=first_counter)
        return FrameDriver(node, adjacency[i], faults, trigger if mode == "async" else None)

    drivers: dict[int, FrameDriver | None] = {i: fresh(i) for i in range(n)}
    retired: dict[int, NodeStats] = {}  # counters of a node's earlier lives (before a crash)
    retired_wire: dict[int, OutboxCounters] = {}
    retired_sends: dict[int, tuple[int, int]] = {}
    next_counter: dict[int, int] = {}  # a restarted node never reuses an id
    resync: dict[int, set[int]] = {i: set() for i in range(n)}  # sender -> rejoined neighbours
    tracks: dict[int, list[list[Track]]] = {i: [] for i in range(n)}
    history: dict[int, list[dict]] = {i: [] for i in range(n)} if registration_history else {}
    for k in range(frames):
        for i in range(n):  # crashes and restarts
            d = drivers[i]
            if not faults.alive(i, k) and d is not None:
                next_counter[i] = d.node.next_counter
                retired[i] = _add_stats(retired.get(i), d.node.stats)
                retired_wire[i] = retired_wire.get(i, OutboxCounters()).add(d.outbox.counters)
                retired_sends[i] = _sends(d.outbox, retired_sends.get(i))
                drivers[i] = None  # what the dead process held (late messages) is gone
            elif faults.alive(i, k) and d is None:  # a fresh process with an empty state
                drivers[i] = fresh(i, next_counter.get(i, 0))
                for j in adjacency[i]:  # its neighbours see it come back and resync it
                    resync[j].add(i)
        arrived: dict[int, list[FrameMessage]] = {i: [] for i in range(n)}
        cpu: dict[int, float] = {}  # probe: each node's prepare time this frame
        dets = data.frame(k).detections
        for i, d in drivers.items():
            if d is None:
                continue
            deliveries = d.due(k)
            t0 = time.process_time() if probe else 0.0
            msg = d.prepare(k, dets[i])
            if probe:
                cpu[i] = time.process_time() - t0
            d.rejoined(resync[i])
            resync[i].clear()
            deliveries += d.send(msg, live={j for j in adjacency[i] if drivers[j] is not None})[0]
            for dst, payload in deliveries:
                if drivers[dst] is not None:  # a dead process receives nothing
                    arrived[dst].append(codec.decode(payload, expect_network=network,
                                                     expect_sender=i,
                                                     allowed_senders=adjacency[dst]))
        now: dict[int, list[Track]] = {}
        for i, d in drivers.items():
            if d is None:
                now[i] = []
                continue
            t0 = time.process_time() if probe else 0.0
            now[i] = d.receive(k, arrived[i], stale_ok=mode == "async")
            if probe:
                probe(k, i, cpu[i] + time.process_time() - t0, d.node)
            if registration_history:
                history[i].append({c: r.snapshot() for c, r in d.node.registrations.items()})
        if on_frame is not None:
            on_frame(k, now)
        else:
            for i in range(n):
                tracks[i].append(now[i])
        if progress:
            progress(k + 1, frames)
    stats = {i: _add_stats(retired.get(i), drivers[i].node.stats if drivers[i] else None)
             for i in range(n)}
    wire = WireCounters.of({i: retired_wire.get(i, OutboxCounters()).add(
        drivers[i].outbox.counters if drivers[i] else OutboxCounters()) for i in range(n)})
    result = RunResult(data.name, topology_name or "custom", cfg.ablation, data.seed, frames,
                       adjacency, tracks, wire, stats, data, mode=mode,
                       sends={i: _sends(drivers[i].outbox if drivers[i] else None,
                                        retired_sends.get(i)) for i in range(n)},
                       registration={i: dict(drivers[i].node.registrations) for i in range(n)
                                     if drivers[i] is not None},
                       registration_history=history,
                       reid={i: q.summary() for i in range(n) if drivers[i] is not None
                             and (q := getattr(drivers[i].node.associate, "quality", None))})
    return result


def _sends(ob: Outbox | None, before: tuple[int, int] | None) -> tuple[int, int]:
    """Event-triggered: tracker entries (sent, withheld) over every life of a node."""
    a = (ob.trigger.entries_sent, ob.trigger.entries_skipped) if ob and ob.trigger else (0, 0)
    b = before or (0, 0)
    return (a[0] + b[0], a[1] + b[1])


def _add_stats(a: NodeStats | None, b: NodeStats | None) -> NodeStats:
    if a is None or b is None:
        return a or b or NodeStats()
    return a.add(b)


def _run_centralized(data: ScenarioData, cfg: TrackerConfig, frames: int, progress,
                     on_frame=None) -> RunResult:
    """One tracker fed every camera's detections (same LDA, manager and parameters); its
    bandwidth is every camera's raw detections sent to it."""
    central = CameraNode(data.cameras, (), cfg, "central", node_id=0)
    wire = WireCounters()
    out: list[list[Track]] = []
    for k in range(frames):
        frame = data.frame(k).detections
        dets = {c.id: frame[c.id] for c in data.cameras}
        for c in data.cameras:
            payload = raw_detection_bytes(dets[c.id], c.id, k)
            wire.bytes_per_link[(c.id, -1)] = wire.bytes_per_link.get((c.id, -1), 0) + len(payload)
            wire.messages += 1
        central.prepare(k, dets)
        tracks = central.update(())
        if on_frame is not None:
            on_frame(k, {c.id: tracks for c in data.cameras})
        else:
            out.append(tracks)
        if progress:
            progress(k + 1, frames)
    tracks = {c.id: out for c in data.cameras}  # every camera is served by the one tracker
    return RunResult(data.name, CENTRALIZED, cfg.ablation, data.seed, frames, None, tracks, wire,
                     {0: central.stats}, data)
