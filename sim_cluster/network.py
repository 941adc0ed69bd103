"""The in-process network: N ``CameraNode`` cores driven frame by frame in one process.

Every message really goes through the wire codec: each node's message is encoded once per frame,
its bytes are counted on every outgoing link and decoded (and validated) by every receiver. This
is the reference run that the multi-process deployment must reproduce.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import msgpack
import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode, NodeStats
from edge_node.core.types import Track
from protocol import codec
from protocol.messages import FrameMessage
from sim_cluster.data import ScenarioData
from sim_cluster.topology import Adjacency, links

CENTRALIZED = "centralized"


@dataclass
class WireCounters:
    """Bytes actually encoded, per directed link, and what they carried."""

    bytes_per_link: dict[tuple[int, int], int] = field(default_factory=dict)
    messages: int = 0
    tracker_entries: int = 0  # (tracker, link, frame) triples sent
    appearance_entries: int = 0  # trackers sent with their appearance, per link
    appearance_bytes: int = 0  # bytes of those appearance fields, per link

    def add(self, src: int, dst: int, payload: bytes, msg: FrameMessage, app_bytes: int) -> None:
        self.bytes_per_link[(src, dst)] = self.bytes_per_link.get((src, dst), 0) + len(payload)
        self.messages += 1
        self.tracker_entries += len(msg.trackers)
        self.appearance_entries += sum(t.appearance is not None for t in msg.trackers)
        self.appearance_bytes += app_bytes

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
        }


def _appearance_bytes(msg: FrameMessage, payload: bytes) -> int:
    if not any(t.appearance is not None for t in msg.trackers):
        return 0
    bare = replace(msg, trackers=tuple(replace(t, appearance=None) for t in msg.trackers))
    return len(payload) - len(codec.encode(bare))


def raw_detection_bytes(detections, camera_id: int, frame: int) -> bytes:
    """What a camera would send a central server per frame: its boxes (float32) and
    descriptors (float16), msgpack-framed. Used to count the centralized baseline's bandwidth."""
    boxes = np.asarray([d.box for d in detections], dtype=np.float32).reshape(-1, 4)
    descs = [d.descriptor for d in detections if d.descriptor is not None]
    desc = np.asarray(descs, dtype=np.float16).tobytes() if descs else b""
    return msgpack.packb([camera_id, frame, boxes.tobytes(), desc], use_bin_type=True)


def run_network(data: ScenarioData, adjacency: Adjacency | str, cfg: TrackerConfig, *,
                topology_name: str | None = None, network: str = "sim",
                frames: int | None = None,
                progress: Callable[[int, int], None] | None = None) -> RunResult:
    """Run ``data`` through the network ``adjacency`` (or ``"centralized"``) with ``cfg``."""
    frames = data.frames if frames is None else min(frames, data.frames)
    cfg = cfg.with_(fps=data.fps, units_per_metre=data.units_per_metre)
    if adjacency == CENTRALIZED:
        return _run_centralized(data, cfg, frames, progress)
    n = data.num_cameras
    if sorted(adjacency) != list(range(n)):
        raise ValueError(f"topology has nodes {sorted(adjacency)}, scenario has cameras 0..{n - 1}")
    nodes = {i: CameraNode(data.cameras[i], adjacency[i], cfg, network) for i in range(n)}
    tracks: dict[int, list[list[Track]]] = {i: [] for i in range(n)}
    wire = WireCounters()
    edges = links(adjacency)
    for k in range(frames):
        payloads: dict[int, tuple[FrameMessage, bytes, int]] = {}
        for i, node in nodes.items():
            msg = node.prepare(k, data.detections[k][i])
            payload = codec.encode(msg)
            payloads[i] = (msg, payload, _appearance_bytes(msg, payload) if adjacency[i] else 0)
        inbox: dict[int, list[FrameMessage]] = {i: [] for i in nodes}
        for src, dst in edges:
            msg, payload, app = payloads[src]
            wire.add(src, dst, payload, msg, app)
            inbox[dst].append(codec.decode(payload, expect_network=network, expect_sender=src,
                                           allowed_senders=adjacency[dst]))
        for i, node in nodes.items():
            tracks[i].append(node.update(inbox[i]))
        if progress:
            progress(k + 1, frames)
    return RunResult(data.name, topology_name or "custom", cfg.ablation, data.seed, frames,
                     adjacency, tracks, wire, {i: n.stats for i, n in nodes.items()}, data)


def _run_centralized(data: ScenarioData, cfg: TrackerConfig, frames: int, progress) -> RunResult:
    """One tracker fed every camera's detections (same LDA, manager and parameters); its
    bandwidth is every camera's raw detections sent to it."""
    central = CameraNode(data.cameras, (), cfg, "central", node_id=0)
    wire = WireCounters()
    out: list[list[Track]] = []
    for k in range(frames):
        dets = {c.id: data.detections[k][c.id] for c in data.cameras}
        for c in data.cameras:
            payload = raw_detection_bytes(dets[c.id], c.id, k)
            wire.bytes_per_link[(c.id, -1)] = wire.bytes_per_link.get((c.id, -1), 0) + len(payload)
            wire.messages += 1
        central.prepare(k, dets)
        out.append(central.update(()))
        if progress:
            progress(k + 1, frames)
    tracks = {c.id: out for c in data.cameras}  # every camera is served by the one tracker
    return RunResult(data.name, CENTRALIZED, cfg.ablation, data.seed, frames, None, tracks, wire,
                     {0: central.stats}, data)
