"""Perception timings on this CPU: detector and re-id milliseconds per frame, and the frame rate
one node sustains from a video (detector + re-id + the tracker core, no network).

    python -m sim_cluster.experiments.bench_perception [--frames 100] [--out runs/bench-perception]

Frames are terrace-sim's, rendered (360 x 288, about 6 people per camera). OSNet runs with
random weights (its speed does not depend on them), saved and loaded as a torchreid checkpoint.
HOG is timed when this OpenCV has it (OpenCV 4.x or opencv-contrib 5.x). Prints a Markdown table
and writes ``perception.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from edge_node.perception.detectors import HogDetector, Mog2Detector, hog_available
from edge_node.perception.frames import VideoFile
from edge_node.perception.pipeline import Perception
from edge_node.perception.reid import HistogramReid, OsnetReid
from sim_cluster.scenarios.loader import load_scenario
from sim_cluster.scenarios.synthetic.render import render_scenario, renderer_for


def _ms(fn, frames, repeat: int = 1) -> float:
    t = time.perf_counter()
    for _ in range(repeat):
        for f in frames:
            fn(f)
    return 1e3 * (time.perf_counter() - t) / (repeat * len(frames))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim_cluster.experiments.bench_perception", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--scenario", default="terrace-sim")
    p.add_argument("--out", default="runs/bench-perception")
    args = p.parse_args(argv)

    import cv2  # OpenCV and torch are optional extras (vision, reid): only this benchmark
    import torch  # (times them) needs them, so `sim_cluster` imports neither

    from edge_node.perception.osnet import osnet  # imports torch

    n = args.frames
    data = load_scenario(args.scenario, frames=n)
    r = renderer_for(args.scenario, frames=n)
    cam = data.cameras[0]
    frames = [r.frame(0, k) for k in range(n)]
    rows: list[tuple[str, str, float]] = []
    res: dict = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                 "torch_threads": torch.get_num_threads(), "opencv": cv2.__version__,
                 "frames": n, "image_size": list(cam.image_size)}

    # -- detectors --------------------------------------------------------------------------------
    mog = Mog2Detector(camera=cam, background=r.background(0), learning_rate=0.001)
    found = [mog.detect(f) for f in frames[:5]]
    ms = _ms(mog.detect, frames[5:])
    boxes_per_frame = [np.array([b for b, _ in mog.detect(f)]).reshape(-1, 4) for f in frames]
    rows.append(("detector", "MOG2 (+ morphology, geometry split)", ms))
    if hog_available():
        hog = HogDetector()
        rows.append(("detector", "HOG (upscale 2, stride 8)", _ms(hog.detect, frames[:20])))
        hog4 = HogDetector(win_stride=4)
        rows.append(("detector", "HOG (upscale 2, stride 4)", _ms(hog4.detect, frames[:10])))
    else:
        rows.append(("detector", f"HOG: not in OpenCV {cv2.__version__} (opencv-contrib has it)",
                     float("nan")))
    del found

    # -- re-id on 8 boxes per frame -------------------------------------------------------------------
    rng = np.random.default_rng(0)
    eight = []
    for f, b in zip(frames, boxes_per_frame):
        b = list(b)
        while len(b) < 8:  # pad with person-sized boxes where there are fewer people
            x, y = rng.uniform(0, cam.image_size[0] - 30), rng.uniform(60, cam.image_size[1] - 90)
            b.append(np.array([x, y, 28.0, 80.0]))
        eight.append((f, np.array(b[:8])))
    hist = HistogramReid()
    rows.append(("re-id, 8 boxes", "colour histogram", _ms(lambda fb: hist.extract(*fb), eight)))
    with tempfile.TemporaryDirectory() as tmp:
        for variant in ("x0_25", "x1_0"):
            path = Path(tmp) / f"osnet_{variant}.pth"
            torch.save({"state_dict": {"module." + k: v for k, v in osnet(variant).state_dict().items()}},
                       path)
            for threads in (1, os.cpu_count() or 1):
                reid = OsnetReid(variant, weights=path, threads=threads)
                reid.extract(*eight[0])
                ms = _ms(lambda fb: reid.extract(*fb), eight[: max(5, n // 10)])
                rows.append(("re-id, 8 boxes", f"OSNet {variant} ({threads} thread"
                             f"{'s' if threads > 1 else ''}, 256x128)", ms))
        torch.set_num_threads(res["torch_threads"])

        # -- node frame rate from a video ---------------------------------------------------------------
        vid = Path(tmp) / "video"
        info = render_scenario(args.scenario, vid, frames=n, cameras=[0])
        for name, reid_kind in (("MOG2 + histogram", "histogram"), ("MOG2 + OSNet x0_25", "x0_25")):
            det = Mog2Detector(camera=cam, background=info["cameras"]["0"]["background"],
                               learning_rate=0.001)
            reid = (HistogramReid() if reid_kind == "histogram"
                    else OsnetReid(reid_kind, weights=Path(tmp) / f"osnet_{reid_kind}.pth", threads=1))
            perc = Perception(det, reid, camera=cam, foot_offset_m=0.2)
            node = CameraNode(cam, (), TrackerConfig.for_ablation("dkf+lda+dtm"), "bench", node_id=0)
            src = VideoFile(info["cameras"]["0"]["frames"])
            t = time.perf_counter()
            k = 0
            for f in src:
                node.prepare(k, perc.process(f.image))
                node.update([])
                k += 1
            dt = time.perf_counter() - t
            src.close()
            rows.append(("node from video", f"{name} + tracker (1 thread)", 1e3 * dt / k))
            res.setdefault("node_fps", {})[name] = k / dt
    res["rows"] = [{"what": a, "backend": b, "ms_per_frame": c} for a, b, c in rows]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "perception.json").write_text(json.dumps(res, indent=2))
    print(f"CPU: {res['cpu']}, {res['cores']} cores; OpenCV {res['opencv']}; "
          f"{res['image_size'][0]}x{res['image_size'][1]} frames of {args.scenario}")
    print("| stage | backend | ms / frame | frames / s |")
    print("| --- | --- | ---: | ---: |")
    for a, b, c in rows:
        fps = "" if not np.isfinite(c) else f"{1e3 / c:.0f}"
        print(f"| {a} | {b} | {'-' if not np.isfinite(c) else f'{c:.1f}'} | {fps} |")
    print(f"wrote {out / 'perception.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
