"""Bring your own detections: a scenario read from MOTChallenge-style files (kind ``det-files``).

A det-files directory::

    calibration.json       cameras, frame count, fps, units per metre (below)
    c0/det.txt             camera 0's detections, MOTChallenge: frame,id,x,y,w,h,conf,-1,-1,-1
    c0/det.npy             optional: (rows, D) descriptors, row i for det.txt's data row i
    c0/gt.txt              optional: image ground truth, MOTChallenge: frame,id,x,y,w,h,consider,class,vis
    c1/...
    gt_ground.csv          optional: ground truth on the ground: frame,id,x,y,w,h (ground units)

Frames are 1-based in every text file (MOTChallenge); scenario frame ``k`` is file frame ``k + 1``.
Boxes are pixels, top-left corner and size. In ``det.txt`` the ``id`` column is ``-1`` in
MOTChallenge files; files written by :func:`export_detections` put the true person id there (``-1``
for false positives), read back as ``ScenarioData.detection_truth`` (diagnostics only, the tracker
never sees it). In ``gt.txt`` rows with ``consider = 0`` or a class other than 1 (pedestrian) are
skipped, as MOTChallenge evaluation does. ``gt_ground.csv`` may start with ``#`` comment lines.

``calibration.json``::

    {"name": "...", "frames": 1000, "fps": 25.0, "units_per_metre": 30.0,
     "area": [xmin, xmax, ymin, ymax],            # optional
     "gt_ground": "gt_ground.csv",                 # optional, this default
     "cameras": [{"id": 0, "image_size": [360, 288], "G": [[...], [...], [...]],
                  "pixel_scale": 1.0, "P": null,   # P optional (3x4)
                  "det": "c0/det.txt", "descriptors": "c0/det.npy", "gt": "c0/gt.txt"}]}

Paths are relative to ``calibration.json``; the per-camera file entries default to the layout above.
``frames`` defaults to the last frame in any file. Without ground truth files the scenario's
ground truth is empty and metrics are undefined.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.detfile import (DetFilesError, camera_from_entry, last_frame, read_det, read_gt,
                               read_gt_ground)
from sim_cluster.data import GroundTruth, ScenarioData

CALIBRATION = "calibration.json"
GT_GROUND = "gt_ground.csv"
BOX_FMT = "%.4f"  # 1e-4 px: round trips well inside 1e-3 px


def load_det_files(directory: str | os.PathLike[str], frames: int | None = None,
                   name: str | None = None, seed: int | None = None) -> ScenarioData:
    """Read a det-files directory (or its ``calibration.json``) into a ``ScenarioData``.

    ``seed`` (for the tracker's own randomness) defaults to the one recorded by the export.
    """
    p = Path(directory)
    cal = p if p.is_file() else p / CALIBRATION
    if not cal.is_file():
        raise DetFilesError(f"calibration file not found: {cal}")
    try:
        doc = json.loads(cal.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise DetFilesError(f"{cal}: not valid JSON ({exc})") from exc
    base = cal.parent
    fps = float(doc.get("fps", 25.0))
    entries = doc.get("cameras")
    if not isinstance(entries, list) or not entries:
        raise DetFilesError(f"{cal}: 'cameras' must be a non-empty list")
    cams = [camera_from_entry(c, e, cal, fps) for c, e in enumerate(entries)]
    files = []
    for c, e in enumerate(entries):
        det_rel = e.get("det", f"c{c}/det.txt")
        npy_rel = e.get("descriptors", str(Path(det_rel).with_suffix(".npy")))
        files.append((base / det_rel, base / npy_rel, base / e.get("gt", f"c{c}/gt.txt"),
                      "descriptors" in e))
    gt_ground = base / doc.get("gt_ground", GT_GROUND)
    if frames is None:
        frames = doc.get("frames")
    if frames is None:
        frames = max([last_frame(f) for fs in files for f in (fs[0], fs[2])]
                     + [last_frame(gt_ground)])
    frames = int(frames)
    if frames <= 0:
        raise DetFilesError(f"{cal}: no frames (frames={frames})")
    per_cam = [read_det(det, frames, npy, req) for det, npy, _, req in files]
    detections = [[per_cam[c][0][k] for c in range(len(cams))] for k in range(frames)]
    det_truth = [[per_cam[c][1][k] for c in range(len(cams))] for k in range(frames)]
    empty = (np.zeros(0, np.int64), np.zeros((0, 4)))
    boxes = [read_gt(gt, frames) if gt.is_file() else [empty] * frames for _, _, gt, _ in files]
    if gt_ground.is_file():
        ids, xy, wh = read_gt_ground(gt_ground, frames)
    else:
        ids = [np.zeros(0, np.int64)] * frames
        xy = wh = [np.zeros((0, 2))] * frames
    upm = float(doc.get("units_per_metre", 1.0))
    if upm <= 0:
        raise DetFilesError(f"{cal}: units_per_metre must be positive, got {upm}")
    area = doc.get("area")
    if area is None:
        allxy = np.vstack([a for a in xy if len(a)] or [np.zeros((1, 2))])
        area = (float(allxy[:, 0].min()), float(allxy[:, 0].max()),
                float(allxy[:, 1].min()), float(allxy[:, 1].max()))
    return ScenarioData(
        name=name or str(doc.get("name", base.name)), cameras=cams, frames=frames, fps=fps,
        units_per_metre=upm, detections=detections,
        truth=GroundTruth(ids=ids, xy=xy, wh=wh, boxes=boxes), detection_truth=det_truth,
        area=tuple(float(v) for v in area), seed=int(doc.get("seed", 0) if seed is None else seed))


def scenario_from_table(raw: dict[str, Any], path: Path, seed: int,
                        frames: int | None) -> ScenarioData:
    """Registry entry for ``[source] kind = "det-files"`` (``SCENARIO_KINDS["det-files"]``).

    Top level: ``name``, ``description``, ``seed``, ``frames`` (the ``frames`` argument overrides
    it). ``[source]``: ``kind`` and ``path``, a det-files directory or its ``calibration.json``,
    relative to the scenario file. Errors are ``ScenarioError`` naming the file and field.
    """
    from sim_cluster.scenario import ScenarioError, Table  # lazy: no import cycle

    file = Path(path).name
    top = Table(raw, file)
    name = top.string("name", None)
    top.string("description", "")
    top.integer("seed", 0, lo=0)
    n = top.integer("frames", None, lo=1)
    n = frames if frames is not None else n
    src = top.table("source")
    src.string("kind")
    d = Path(src.string("path")).expanduser()
    src.finish()
    top.finish()
    if not d.is_absolute():
        d = Path(path).parent / d
    try:
        return load_det_files(d, n, name=name, seed=seed)
    except DetFilesError as exc:
        raise ScenarioError(file, None, str(exc)) from None


# -- export -----------------------------------------------------------------------------------------
def _write_rows(path: Path, rows: list[str], header: str | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", encoding="utf-8", newline="\n") as fh:
        if header:
            fh.write(header + "\n")
        fh.write("\n".join(rows) + ("\n" if rows else ""))


def _f(v: float) -> str:
    return BOX_FMT % float(v)


def export_detections(scenario: ScenarioData, out_dir: str | os.PathLike[str],
                      descriptor_dtype: str = "float16") -> Path:
    """Write ``scenario`` as a det-files directory; returns the ``calibration.json`` path.

    Every camera's detections (boxes to 1e-4 px, scores, true ids), descriptors as ``.npy`` of
    ``descriptor_dtype`` (``float16`` halves the size; ``float32`` for exact copies; no file when
    no detection has one), image ground truth, ground-plane ground truth and calibration.
    Loading the result with :func:`load_det_files` gives back the same detections.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if np.dtype(descriptor_dtype).kind != "f":
        raise DetFilesError(f"descriptor_dtype must be a float type, got {descriptor_dtype!r}")
    n = scenario.frames
    cams_doc = []
    for c, cam in enumerate(scenario.cameras):
        rows, descs, have = [], [], False
        for k in range(n):
            dets = scenario.detections[k][c]
            truth = (scenario.detection_truth[k][c]
                     if scenario.detection_truth and len(scenario.detection_truth[k][c]) == len(dets)
                     else np.full(len(dets), -1))
            for d, tid in zip(dets, truth):
                b = np.asarray(d.box, dtype=float)
                rows.append(f"{k + 1},{int(tid)},{_f(b[0])},{_f(b[1])},{_f(b[2])},{_f(b[3])},"
                            f"{float(d.score):.6g},-1,-1,-1")
                descs.append(d.descriptor)
                have = have or d.descriptor is not None
        det_rel = f"c{c}/det.txt"
        _write_rows(out / det_rel, rows)
        npy_rel = f"c{c}/det.npy"
        if have:
            dim = next(len(x) for x in descs if x is not None)
            arr = np.stack([np.full(dim, np.nan) if x is None else np.asarray(x, float)
                            for x in descs]) if descs else np.zeros((0, dim))
            np.save(out / npy_rel, arr.astype(descriptor_dtype))
        elif (out / npy_rel).exists():
            (out / npy_rel).unlink()
        gt_rows = []
        for k in range(n):
            ids, boxes = scenario.truth.boxes[c][k]
            for i, b in zip(np.asarray(ids).ravel(), np.asarray(boxes, float).reshape(-1, 4)):
                gt_rows.append(f"{k + 1},{int(i)},{_f(b[0])},{_f(b[1])},{_f(b[2])},{_f(b[3])},1,1,1")
        _write_rows(out / f"c{c}/gt.txt", gt_rows)
        entry: dict[str, Any] = {
            "id": cam.id, "image_size": list(cam.image_size), "G": cam.G.tolist(),
            "pixel_scale": cam.pixel_scale, "fps": cam.fps,
            "P": None if cam.P is None else cam.P.tolist(),
            "det": det_rel, "gt": f"c{c}/gt.txt"}
        if have:
            entry["descriptors"] = npy_rel
        cams_doc.append(entry)
    g_rows = []
    t = scenario.truth
    for k in range(n):
        for i, xy, wh in zip(np.asarray(t.ids[k]).ravel(), np.asarray(t.xy[k]).reshape(-1, 2),
                             np.asarray(t.wh[k]).reshape(-1, 2)):
            g_rows.append(f"{k + 1},{int(i)},{xy[0]:.6f},{xy[1]:.6f},{wh[0]:.6f},{wh[1]:.6f}")
    _write_rows(out / GT_GROUND, g_rows, header="# frame,id,x,y,w,h (ground units, 1-based frames)")
    doc = {"name": scenario.name, "frames": n, "fps": scenario.fps,
           "units_per_metre": scenario.units_per_metre, "area": list(scenario.area),
           "seed": scenario.seed, "gt_ground": GT_GROUND, "cameras": cams_doc}
    cal = out / CALIBRATION
    cal.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return cal
