"""``sim_cluster bench-detectors``: recall and precision of the people detectors on rendered
frames of synthetic scenarios, and their cost per frame.

For each scenario (synthetic presets; ``sim_cluster render`` draws the same frames) and each
camera, frames ``0 .. frames-1`` are rendered; MOG2 (started from the empty scene, as
``sim_cluster up --source video`` runs it, with the camera's geometry) sees every frame, and
every detector is scored on every ``stride``-th frame from ``warmup`` on against the image-plane
ground truth (the people the scenario's visibility model counts as visible in that camera, as
the paper's image evaluation does). A detection matches a person at IoU >= ``iou`` (greedy,
highest score first, one person per detection): recall = matched visible people / visible
people; precision = detections that match anyone in the image (visible, or hidden by the
visibility model but drawn in part: a box on a half-hidden person is no false positive) /
detections.

Variants: ``mog2``; ``ssdlite`` at score thresholds 0.3 and 0.1; ``ssdlite`` with 2 x 2 tiles at
0.3. The speed of the two ssdlite backends (OpenCV DNN and onnxruntime, one thread each) is
timed on the same frames alternately in this run (median of ``rounds`` rounds), so their
ratio is measured on one machine at one load.

Writes ``detectors.json`` (``meta.provenance``: machine and commit) to ``--out``
(default ``docs/results/perception``), which ``sim_cluster report`` renders into the docs.
"""
from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

import numpy as np

from edge_node.perception.detectors import Mog2Detector, SsdliteDetector
from sim_cluster.experiments.provenance import provenance
from sim_cluster.experiments.report import render_detector_backends, render_detectors
from sim_cluster.scenarios.loader import load_scenario
from sim_cluster.scenarios.synthetic.render import renderer_for

DEFAULT_SCENARIOS = "terrace-sim,lab-sim,campus-sim"
RESULT = "detectors.json"


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of every box of ``a`` (n, 4 xywh) with every box of ``b`` (m, 4)."""
    ax0, ay0, ax1, ay1 = a[:, 0, None], a[:, 1, None], (a[:, 0] + a[:, 2])[:, None], (a[:, 1] + a[:, 3])[:, None]
    bx0, by0, bx1, by1 = b[None, :, 0], b[None, :, 1], (b[:, 0] + b[:, 2])[None], (b[:, 1] + b[:, 3])[None]
    iw = np.clip(np.minimum(ax1, bx1) - np.maximum(ax0, bx0), 0, None)
    ih = np.clip(np.minimum(ay1, by1) - np.maximum(ay0, by0), 0, None)
    inter = iw * ih
    union = (a[:, 2] * a[:, 3])[:, None] + (b[:, 2] * b[:, 3])[None] - inter
    return inter / np.maximum(union, 1e-9)


def match(found: list, truth: np.ndarray, iou: float) -> tuple[int, int, int]:
    """``(true positives, detections, people)`` of one image."""
    boxes = np.array([b for b, _ in found], float).reshape(-1, 4)
    scores = np.array([s for _, s in found], float)
    truth = np.asarray(truth, float).reshape(-1, 4)
    if len(boxes) == 0 or len(truth) == 0:
        return 0, len(boxes), len(truth)
    m = _iou(boxes, truth)
    used = np.zeros(len(truth), bool)
    tp = 0
    for i in np.argsort(-scores, kind="stable"):
        j = np.where(used, -1.0, m[i])
        best = int(np.argmax(j))
        if j[best] >= iou:
            used[best] = True
            tp += 1
    return tp, len(boxes), len(truth)


def everyone(cam, xy: np.ndarray, wh: np.ndarray) -> np.ndarray:
    """Image boxes (n, 4) of every person on the ground in front of ``cam`` whose box overlaps
    its image, hidden or not."""
    W, H = cam.image_size
    out = []
    for (x, y), (w, h) in zip(np.asarray(xy, float), np.asarray(wh, float)):
        if not (np.isfinite(x) and np.isfinite(y)) or not cam.in_front(np.array([[x, y]]))[0]:
            continue
        b = cam.cylinder_to_box(np.array([x, y, w, h]))
        if np.all(np.isfinite(b)) and b[0] < W and b[1] < H and b[0] + b[2] > 0 and b[1] + b[3] > 0:
            out.append(b)
    return np.array(out, float).reshape(-1, 4)


def evaluate(scenario: str, frames: int, stride: int, warmup: int, iou: float,
             variants: dict, progress=print) -> dict:
    data = load_scenario(scenario, frames=frames)
    r = renderer_for(scenario, frames=frames)
    counts = {name: [0, 0, 0, 0] for name in ["mog2", *variants]}
    secs = {name: 0.0 for name in counts}
    scored = 0
    for c, cam in enumerate(data.cameras):
        mog = Mog2Detector(camera=cam, units_per_metre=data.units_per_metre,
                           background=r.background(c), learning_rate=0.001)
        for k in range(frames):
            img = r.frame(c, k)
            t = time.perf_counter()
            found = mog.detect(img)
            dt = time.perf_counter() - t
            if k < warmup or (k - warmup) % stride:
                continue
            scored += 1
            truth = data.truth.boxes[c][k][1]
            anyone = everyone(cam, data.truth.xy[k], data.truth.wh[k])
            for name, det in [("mog2", None), *variants.items()]:
                if det is not None:
                    t = time.perf_counter()
                    found = det.detect(img)
                    dt = time.perf_counter() - t
                secs[name] += dt
                tp, _, people = match(found, truth, iou)
                good, n_det, _ = match(found, anyone, iou)
                for i, v in enumerate((tp, n_det, people, good)):
                    counts[name][i] += v
        progress(f"  {scenario} camera {c}: done")
    out = {}
    for name, (tp, n_det, n_people, good) in counts.items():
        out[name] = {"tp": tp, "detections": n_det, "people": n_people, "correct": good,
                     "recall": tp / n_people if n_people else float("nan"),
                     "precision": good / n_det if n_det else float("nan"),
                     "ms_per_frame": 1e3 * secs[name] / max(scored, 1)}
    return {"frames_scored": scored, "cameras": len(data.cameras),
            "image_size": list(data.cameras[0].image_size), "variants": out}


def backend_speed(frames: list[np.ndarray], rounds: int) -> dict:
    """ms per frame of the whole-frame ssdlite on OpenCV DNN and on onnxruntime, one thread
    each, timed alternately (``rounds`` rounds over ``frames``; medians)."""
    dets = {}
    for backend in ("opencv", "onnxruntime"):
        try:
            dets[backend] = SsdliteDetector(backend=backend, threads=1)
        except Exception as e:  # onnxruntime not installed
            dets[backend] = None
            print(f"  {backend}: {e}")
    times = {b: [] for b, d in dets.items() if d is not None}
    boxes = {}
    for b in times:
        boxes[b] = [dets[b].detect(f) for f in frames[:2]]  # warm up
    for _ in range(rounds):
        for b in times:
            t = time.perf_counter()
            for f in frames:
                dets[b].detect(f)
            times[b].append(1e3 * (time.perf_counter() - t) / len(frames))
    res = {b: {"ms_median": statistics.median(v), "ms_min": min(v), "ms_max": max(v)}
           for b, v in times.items()}
    if len(boxes) == 2:  # the same boxes from both
        diff = 0.0
        for x, y in zip(boxes["opencv"], boxes["onnxruntime"]):
            if len(x) != len(y):
                diff = float("inf")
                break
            for (bx, sx), (by, sy) in zip(x, y):
                diff = max(diff, float(np.abs(bx - by).max()), abs(sx - sy))
        res["largest_difference_px"] = diff
        res["ratio_opencv_to_onnxruntime"] = (res["opencv"]["ms_median"]
                                              / res["onnxruntime"]["ms_median"])
    import cv2  # an optional extra (vision): only the perception commands need it
    res["opencv_version"] = cv2.__version__
    try:  # optional (vision extra): its version beside its timing
        import onnxruntime  # optional (vision extra): its version beside its timing
        res["onnxruntime_version"] = onnxruntime.__version__
    except ImportError:
        pass
    return res


def main(args) -> int:
    scenarios = [s.strip() for s in str(args.scenarios).split(",") if s.strip()]
    variants = {
        "ssdlite": SsdliteDetector(score_threshold=0.3),
        "ssdlite@0.1": SsdliteDetector(score_threshold=0.1),
        "ssdlite tiles 2x2": SsdliteDetector(score_threshold=0.3, tiles=2),
    }
    backends = {name: d.backend for name, d in variants.items()}
    say = (lambda *a: None) if args.quiet else print
    res = {"meta": {"provenance": provenance(), "frames": args.frames, "stride": args.stride,
                    "warmup": args.warmup, "iou": args.iou, "backends": backends},
           "scenarios": {}}
    for s in scenarios:
        say(f"{s}: rendering and detecting")
        res["scenarios"][s] = evaluate(s, args.frames, args.stride, args.warmup, args.iou,
                                       variants, say)
    r = renderer_for(scenarios[0], frames=args.frames)
    frames = [r.frame(c, k) for c in range(len(r.cameras)) for k in range(args.warmup, args.frames, 25)][:16]
    say("ssdlite backends, alternately")
    res["backends"] = backend_speed(frames, args.rounds)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / RESULT).write_text(json.dumps(res, indent=2, sort_keys=True) + "\n")
    print(render_detectors(res))
    print(render_detector_backends(res))
    print(f"wrote {out / RESULT}")
    return 0
