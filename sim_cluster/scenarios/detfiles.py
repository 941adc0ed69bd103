"""Bring your own detections: a scenario read from a det-files directory (kind ``det-files``),
and a scenario written as one (``sim_cluster export-detections``).

The files and ``calibration.json`` are described in :mod:`edge_node.formats.calibration` and
:mod:`edge_node.formats.detfile`, which read and write them for camera processes and for this
module alike. In ``det.txt`` the ``id`` column is ``-1`` in MOTChallenge files; files written by
:func:`export_detections` put the true person id there (``-1`` for false positives), read back
as ``ScenarioData.detection_truth`` (diagnostics only, the tracker never sees it). Without ground
truth files the scenario's ground truth is empty and metrics are undefined.

Frames come on demand (:func:`open_det_files`, what the scenario loader uses): the files are
parsed and validated once into one table each, and a chunk of ``CHUNK_FRAMES`` frames is built
from those tables when it is asked for (descriptors read from the memory-mapped ``.npy``), so
memory does not grow with the number of frames; a camera process (``ScenarioStream.camera``)
builds its own camera's detections only (``focus``). :func:`load_det_files` materialises them.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.formats.calibration import (GT_GROUND, calibration_path, camera_entry,
                                           read_calibration, write_calibration)
from edge_node.formats.detfile import (DetFile, DetFilesError, GroundFile, GtFile, open_det,
                                       open_gt, open_gt_ground, write_det, write_gt,
                                       write_gt_ground)
from edge_node.formats.layouts import ImportOptions, read_layout
from sim_cluster.scenarios.data import CHUNK_FRAMES, Frame, ScenarioData, ScenarioStream
from sim_cluster.scenarios.files import ScenarioError, scenario_table


class DetFilesChunks:
    """The ``chunk`` of a det-files :class:`~sim_cluster.scenarios.data.ScenarioStream`: frames
    ``j * CHUNK_FRAMES ..`` built from every camera's files (edge_node.formats' readers, which
    hold each file's table and find a frame's rows when asked), or from cameras ``cameras``'
    only (:meth:`only`: the others' detections and image ground truth are empty)."""

    def __init__(self, dets: list[DetFile], gts: list[GtFile | None], ground: GroundFile | None,
                 frames: int, cameras: list[int] | None = None):
        self.dets, self.gts, self.ground, self.frames = dets, gts, ground, frames
        self.cameras = cameras

    def only(self, cameras: list[int]) -> DetFilesChunks:
        """The same chunks, cameras ``cameras`` only (the ``focus`` of the stream)."""
        return DetFilesChunks(self.dets, self.gts, self.ground, self.frames, list(cameras))

    def __call__(self, j: int) -> list[Frame]:
        lo = j * CHUNK_FRAMES
        return [self.frame(k) for k in range(lo, min(lo + CHUNK_FRAMES, self.frames))]

    def frame(self, k: int) -> Frame:
        """Frame ``k`` (empty ground truth where a file is missing)."""
        no_boxes = (np.zeros(0, np.int64), np.zeros((0, 4)))
        if self.ground is not None:
            ids, xy, wh = self.ground.truth(k)
        else:
            ids, xy, wh = np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
        mine = [self.cameras is None or c in self.cameras for c in range(len(self.dets))]
        return Frame(
            detections=[d.detections(k) if m else [] for d, m in zip(self.dets, mine)],
            detection_truth=[d.true_ids(k) if m else np.zeros(0, np.int64)
                             for d, m in zip(self.dets, mine)],
            ids=ids, xy=xy, wh=wh,
            boxes=[g.boxes(k) if g is not None and m else no_boxes for g, m in zip(self.gts, mine)])


def open_det_files(directory: str | os.PathLike[str], frames: int | None = None,
                   name: str | None = None, seed: int | None = None,
                   options: ImportOptions | None = None) -> ScenarioStream:
    """A det-files directory (or its ``calibration.json``) as a ``ScenarioStream``: every file
    is opened and validated here, frames are built a chunk at a time when asked.

    A folder without ``calibration.json`` is read as another tool's layout
    (:func:`edge_node.formats.layouts.read_layout`, with the command line's ``options``); its
    notes (what was found, what was assumed) are the stream's ``notes``. ``options`` for a folder
    with ``calibration.json`` are an error: the file declares what they would.

    ``seed`` (for the tracker's own randomness) defaults to the one recorded by the export.
    ``area`` defaults to the extent of the ground truth's positions over the run's frames.
    """
    given = options.given if options is not None else []
    if Path(directory).suffix == ".json" and not Path(directory).is_file():
        raise DetFilesError(f"calibration file not found: {directory}")
    if calibration_path(directory).is_file():
        if given:
            raise DetFilesError(f"{calibration_path(directory)} declares the cameras, units and "
                                f"files: {', '.join(given)} apply to a folder without it "
                                "(another tool's layout)")
        cal = read_calibration(directory)
        notes: tuple[str, ...] = ()
        ground = None
        frames = cal.frame_count() if frames is None else int(frames)
        if frames > 0 and cal.gt_ground.is_file():
            ground = open_gt_ground(cal.gt_ground, frames, cal.bound)
    else:
        imported = read_layout(directory, options, frames)
        cal, ground, notes = imported.calibration, imported.ground, imported.notes
        frames = cal.frame_count() if frames is None else int(frames)
    if frames <= 0:
        raise DetFilesError(f"{cal.path}: no frames (frames={frames})")
    dets = [open_det(f.det, frames, f.descriptors, f.descriptors_required, cal.bound)
            for f in cal.files]
    gts = [open_gt(f.gt, frames, cal.bound) if f.gt.is_file() else None for f in cal.files]
    area = cal.area
    if area is None:
        allxy = ground.positions() if ground is not None else np.zeros((0, 2))
        allxy = allxy if len(allxy) else np.zeros((1, 2))
        area = (float(allxy[:, 0].min()), float(allxy[:, 0].max()),
                float(allxy[:, 1].min()), float(allxy[:, 1].max()))
    chunks = DetFilesChunks(dets, gts, ground, frames)
    return ScenarioStream(
        name=name or str(cal.name if cal.name is not None else cal.path.parent.name),
        cameras=cal.cameras, frames=frames, fps=cal.fps, units_per_metre=cal.units_per_metre,
        chunk=chunks, chunk_frames=CHUNK_FRAMES, focus=chunks.only,
        area=tuple(float(v) for v in area), seed=int((cal.seed or 0) if seed is None else seed),
        notes=notes)


def load_det_files(directory: str | os.PathLike[str], frames: int | None = None,
                   name: str | None = None, seed: int | None = None,
                   options: ImportOptions | None = None) -> ScenarioData:
    """:func:`open_det_files` with every frame in memory (in-process runs, tests)."""
    return open_det_files(directory, frames, name, seed, options).materialise()


def scenario_from_table(raw: dict[str, Any], path: Path, seed: int,
                        frames: int | None) -> ScenarioStream:
    """The scenario loader of kind ``det-files`` (``loader.SCENARIO_KINDS``).

    Top level: ``name``, ``description``, ``seed``, ``frames`` (the ``frames`` argument overrides
    it). ``[source]``: ``kind`` and ``path``, a det-files directory or its ``calibration.json``,
    relative to the scenario file. Errors are ``ScenarioError`` naming the file and field.
    """
    file = Path(path).name
    top = scenario_table(raw, file)
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
        return open_det_files(d, n, name=name, seed=seed)
    except DetFilesError as exc:
        raise ScenarioError(file, None, str(exc)) from None


# -- export -----------------------------------------------------------------------------------------
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
    n = scenario.frames
    entries = []
    for c, cam in enumerate(scenario.cameras):
        dets = [scenario.detections[k][c] for k in range(n)]
        truth = [scenario.detection_truth[k][c]
                 if scenario.detection_truth and len(scenario.detection_truth[k][c]) == len(d)
                 else np.full(len(d), -1) for k, d in enumerate(dets)]
        det_rel, npy_rel, gt_rel = f"c{c}/det.txt", f"c{c}/det.npy", f"c{c}/gt.txt"
        have = write_det(out / det_rel, dets, truth, out / npy_rel, descriptor_dtype)
        write_gt(out / gt_rel, [scenario.truth.boxes[c][k] for k in range(n)])
        entries.append(camera_entry(cam, det_rel, gt_rel, npy_rel if have else None))
    t = scenario.truth
    write_gt_ground(out / GT_GROUND, t.ids[:n], t.xy[:n], t.wh[:n])
    return write_calibration(out, name=scenario.name, frames=n, fps=scenario.fps,
                             units_per_metre=scenario.units_per_metre, area=scenario.area,
                             seed=scenario.seed, cameras=entries)
