"""``sim_cluster bench``: cost of the tracker core and size of its messages.

For T targets walking in a 20 m x 20 m area seen by 5 cameras on a complete graph (so every node
has 4 neighbours), it times ``prepare`` + ``update`` of every node in every frame (the codec is
timed separately) and reports medians, plus the encoded bytes per tracker per frame and per new
tracker's appearance. With ``--cameras`` it is the scale sweep instead
(:mod:`~sim_cluster.experiments.bench_scale`). Times are CPU time of this process (``time.process_time``), not wall
time, so other work on a shared machine inflates them far less; still quote medians and ratios.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import replace

import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from edge_node.core.types import Detection
from edge_node.geometry import Camera
from protocol import codec
from sim_cluster.experiments import bench_scale
from sim_cluster.experiments.run import tracker_config

AREA = 20.0


def _camera(cid: int, n: int) -> Camera:
    """Cameras around the area, each a linear image->ground map (50 px per metre) offset a
    little per camera: the core's cost does not depend on perspective."""
    off = 0.1 * np.array([np.cos(2 * np.pi * cid / n), np.sin(2 * np.pi * cid / n)])
    G = np.array([[0.02, 0, off[0]], [0, 0.02, off[1]], [0, 0, 1.0]])
    return Camera(cid, (1000, 1000), G)


def _world(targets: int, frames: int, seed: int):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(1, AREA - 1, size=(targets, 2))
    vel = rng.normal(0, 1.0, size=(targets, 2))
    app = rng.normal(size=(targets, 512))
    app /= np.linalg.norm(app, axis=1, keepdims=True)
    out = []
    for _ in range(frames):
        pos = pos + vel / 25.0
        bounce = (pos < 0.5) | (pos > AREA - 0.5)
        vel[bounce] *= -1
        out.append(pos.copy())
    return out, app


def _detections(cam: Camera, xy: np.ndarray, app: np.ndarray, rng) -> list[Detection]:
    uv = cam.to_image(xy)
    dets = []
    for (u, v), a in zip(uv, app):
        if rng.random() < 0.1:  # misses
            continue
        box = np.array([u - 12.5, v - 42.5, 25.0, 42.5]) + rng.normal(0, 1.0, 4)
        d = a + 0.05 * rng.normal(size=a.shape) / np.sqrt(a.size)
        dets.append(Detection(box, d))
    return dets


def bench_targets(targets: int, neighbours: int = 4, frames: int = 60, seed: int = 0) -> dict:
    n = neighbours + 1
    cams = [_camera(i, n) for i in range(n)]
    nodes = [CameraNode(c, [j for j in range(n) if j != c.id], TrackerConfig(), "bench")
             for c in cams]
    world, app = _world(targets, frames, seed)
    rng = np.random.default_rng(seed + 1)
    core_ms, codec_ms, per_tracker, trackers_seen = [], [], [], []
    app_bytes = []
    for k in range(frames):
        dets = [_detections(c, world[k], app, rng) for c in cams]
        t_core = 0.0
        msgs, payloads = [], []
        for node, d in zip(nodes, dets):
            t0 = time.process_time()
            msgs.append(node.prepare(k, d))
            t_core += time.process_time() - t0
        t0 = time.process_time()
        for m in msgs:
            payloads.append(codec.encode(m))
        inbox = [[codec.decode(payloads[j]) for j in range(n) if j != i] for i in range(n)]
        t_codec = time.process_time() - t0
        for node, box in zip(nodes, inbox):
            t0 = time.process_time()
            node.update(box)
            t_core += time.process_time() - t0
        core_ms.append(1000 * t_core / n)
        codec_ms.append(1000 * t_codec / n)
        for m, p in zip(msgs, payloads):
            with_app = [t for t in m.trackers if t.appearance is not None]
            if m.trackers and not with_app:
                header = len(codec.encode(type(m)(m.network, m.sender, m.frame)))
                per_tracker.append((len(p) - header) / len(m.trackers))
            if with_app:
                bare = replace(m, trackers=tuple(replace(t, appearance=None) for t in m.trackers))
                app_bytes.append((len(p) - len(codec.encode(bare))) / len(with_app))
        trackers_seen.append(statistics.mean(len(nd.trackers) for nd in nodes))
    warm = frames // 3  # skip start-up (births, merges)
    return {
        "targets": targets,
        "neighbours": neighbours,
        "core_ms_median": statistics.median(core_ms[warm:]),
        "core_ms_p90": float(np.percentile(core_ms[warm:], 90)),
        "codec_ms_median": statistics.median(codec_ms[warm:]),
        "trackers_per_node": statistics.median(trackers_seen[warm:]),
        "bytes_per_tracker": statistics.median(per_tracker) if per_tracker else float("nan"),
        "appearance_bytes_per_new_tracker": statistics.median(app_bytes) if app_bytes else float("nan"),
    }


def main(args) -> int:
    """``sim_cluster bench``: the core benchmark, or with ``--cameras`` the scale sweep
    (:mod:`sim_cluster.experiments.bench_scale`)."""
    if getattr(args, "cameras", None):
        cfg = tracker_config(args.config, args.tracker_config)
        return bench_scale.main(args, cfg)
    args.frames = args.frames or 60
    targets = [int(t) for t in str(args.targets).split(",") if t.strip()]
    print(f"prepare+update per node per frame, {args.neighbours} neighbours, "
          f"{args.frames} frames, median of {args.repeats} repeats")
    print(f"{'targets':>7} {'trackers':>8} {'core ms':>8} {'p90 ms':>7} {'codec ms':>8} "
          f"{'B/tracker':>9} {'B/appearance':>12}")
    for t in targets:
        runs = [bench_targets(t, args.neighbours, args.frames, seed=r) for r in range(args.repeats)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(f"{t:>7} {med['trackers_per_node']:>8.0f} {med['core_ms_median']:>8.2f} "
              f"{med['core_ms_p90']:>7.2f} {med['codec_ms_median']:>8.3f} "
              f"{med['bytes_per_tracker']:>9.1f} {med['appearance_bytes_per_new_tracker']:>12.0f}")
    return 0
