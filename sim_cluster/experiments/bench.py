"""``sim_cluster bench``: cost of the tracker core and size of its messages.

For T targets walking in a 20 m x 20 m area seen by 5 cameras on a complete graph (so every node
has 4 neighbours), it times ``prepare`` + ``update`` of every node in every frame (the codec is
timed separately) and reports medians, plus the encoded bytes per tracker per frame and per new
tracker's appearance. With ``--cameras`` it is the scale sweep instead
(:mod:`~sim_cluster.experiments.bench_scale`). Times are CPU time of this process (``time.process_time``), not wall
time, so other work on a shared machine inflates them far less; still quote medians and ratios.

The codec line times every message of the measured frames on its own (``CODEC_REPEATS`` calls
each, the mean per call; then the median over messages): ``encode`` of the message as the core
builds it (one ``TrackerBlock``), ``decode``, and per node-frame one encode and one decode per
neighbour; beside them ``encode`` of the same message given as ``TrackerInfo`` objects (what
code that builds messages one tracker at a time pays: the block is made first).
"""
from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import TypeVar

import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from edge_node.core.types import Detection
from edge_node.geometry import Camera
from protocol import FrameMessage, codec
from sim_cluster.experiments import bench_scale
from sim_cluster.experiments.provenance import provenance
from sim_cluster.experiments.run import tracker_config

AREA = 20.0
CODEC_REPEATS = 20
T = TypeVar("T")


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


def _cpu_us(fn, arg, repeats: int = CODEC_REPEATS) -> float:
    """Mean CPU microseconds of ``fn(arg)`` over ``repeats`` calls."""
    t0 = time.process_time()
    for _ in range(repeats):
        fn(arg)
    return 1e6 * (time.process_time() - t0) / repeats


def codec_costs(msgs: list[FrameMessage], neighbours: int) -> dict:
    """Median CPU time per message of encode (from objects, from a block) and decode, the
    node-frame total (one encode, ``neighbours`` decodes) and the median bytes per message."""
    enc, enc_block, dec, size = [], [], [], []
    for m in msgs:
        payload = codec.encode(m)
        by_block = FrameMessage.from_block(m.network, m.sender, m.frame, m.block, m.merges, m.sent_at)
        fresh = [type(m)(m.network, m.sender, m.frame, m.trackers, m.merges, m.sent_at)
                 for _ in range(CODEC_REPEATS)]  # no cached block: the conversion is timed
        it = iter(fresh)
        enc.append(_cpu_us(lambda _: codec.encode(next(it)), None))
        enc_block.append(_cpu_us(codec.encode, by_block))
        dec.append(_cpu_us(codec.decode, payload))
        size.append(len(payload))
    med = {k: statistics.median(v) for k, v in
           (("encode_us", enc), ("encode_block_us", enc_block), ("decode_us", dec), ("bytes", size))}
    med["node_frame_us"] = med["encode_us"] + neighbours * med["decode_us"]
    med["node_frame_block_us"] = med["encode_block_us"] + neighbours * med["decode_us"]
    return med


def warm_frames(frames: int) -> int:
    """Frames the core benchmark leaves out at the start (births, merges)."""
    return frames // 3


def _direct(k: int, call: Callable[[], T]) -> T:
    return call()


def bench_targets(targets: int, neighbours: int = 4, frames: int = 60, seed: int = 0,
                  wrap: Callable[[int, Callable[[], T]], T] = _direct, codec_line: bool = True) -> dict:
    """The core benchmark of ``targets`` targets. ``wrap(k, call)`` runs each node's
    ``prepare`` and ``update`` of frame ``k`` (``call()``); ``bench/core_instructions.py`` passes
    one that lets valgrind count the instructions of the measured frames
    (``k >= warm_frames(frames)``) alone. ``codec_line=False`` skips the codec's separate
    timing (``codec_costs``)."""
    n = neighbours + 1
    cams = [_camera(i, n) for i in range(n)]
    nodes = [CameraNode(c, [j for j in range(n) if j != c.id], TrackerConfig(), "bench")
             for c in cams]
    world, app = _world(targets, frames, seed)
    rng = np.random.default_rng(seed + 1)
    core_ms, codec_ms, per_tracker, trackers_seen = [], [], [], []
    app_bytes = []
    warm = warm_frames(frames)
    measured: list[FrameMessage] = []
    for k in range(frames):
        dets = [_detections(c, world[k], app, rng) for c in cams]
        t_core = 0.0
        msgs, payloads = [], []
        for node, d in zip(nodes, dets):
            t0 = time.process_time()
            msgs.append(wrap(k, partial(node.prepare, k, d)))
            t_core += time.process_time() - t0
        t0 = time.process_time()
        for m in msgs:
            payloads.append(codec.encode(m))
        inbox = [[codec.decode(payloads[j]) for j in range(n) if j != i] for i in range(n)]
        t_codec = time.process_time() - t0
        for node, box in zip(nodes, inbox):
            t0 = time.process_time()
            wrap(k, partial(node.update, box))
            t_core += time.process_time() - t0
        if k >= warm:
            measured += msgs
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
    codec_cost = codec_costs(measured, neighbours) if codec_line else {}
    return {
        "targets": targets,
        "neighbours": neighbours,
        "core_ms_median": statistics.median(core_ms[warm:]),
        "core_ms_p90": float(np.percentile(core_ms[warm:], 90)),
        "codec_ms_median": statistics.median(codec_ms[warm:]),
        "trackers_per_node": statistics.median(trackers_seen[warm:]),
        "bytes_per_tracker": statistics.median(per_tracker) if per_tracker else float("nan"),
        "appearance_bytes_per_new_tracker": statistics.median(app_bytes) if app_bytes else float("nan"),
        **{f"codec_{k}": v for k, v in codec_cost.items()},
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
    rows = []
    for t in targets:
        runs = [bench_targets(t, args.neighbours, args.frames, seed=r) for r in range(args.repeats)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        rows.append({"targets": t, **med,
                     "core_ms_runs": sorted(r["core_ms_median"] for r in runs),
                     "codec_node_frame_us_runs": sorted(r["codec_node_frame_block_us"] for r in runs)})
        print(f"{t:>7} {med['trackers_per_node']:>8.0f} {med['core_ms_median']:>8.2f} "
              f"{med['core_ms_p90']:>7.2f} {med['codec_ms_median']:>8.3f} "
              f"{med['bytes_per_tracker']:>9.1f} {med['appearance_bytes_per_new_tracker']:>12.0f}")
        print(f"{'':>7} codec per message (CPU us, median): encode {med['codec_encode_block_us']:.1f}, "
              f"decode {med['codec_decode_us']:.1f}; per node-frame (1 encode + "
              f"{args.neighbours} decodes) {med['codec_node_frame_block_us']:.1f}; "
              f"{med['codec_bytes']:.0f} bytes per message (encode from TrackerInfo objects "
              f"{med['codec_encode_us']:.1f})")
    if getattr(args, "json", None):  # the data file the docs' benchmark table is rendered from
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        meta = {"provenance": provenance(), "neighbours": args.neighbours, "frames": args.frames,
                "repeats": args.repeats}
        out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=2, sort_keys=True) + "\n")
        print(f"wrote {out}")
    return 0
