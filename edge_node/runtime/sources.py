"""Where a camera process gets its detections: one camera of a det-files directory, or (for
developers) one camera of a sim_cluster scenario played back.

Det-files are read with :mod:`edge_node.formats`, the reader the simulator uses too: the very
same ``Detection`` objects (boxes float64 as parsed from det.txt, descriptors float32 from the
``.npy``, all-NaN rows = no descriptor, NaN confidence = 1.0), so a multi-process run equals the
in-process reference run on the same files.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from edge_node.core.types import Detection
from edge_node.formats.calibration import read_calibration
from edge_node.formats.detfile import DetFilesError, read_det
from edge_node.geometry import Camera
from edge_node.runtime.config import NodeConfig, NodeConfigError


class SourceError(ValueError):
    """Detection files that cannot be read; the message names the file."""


@dataclass
class Source:
    """This node's camera and its detections per frame ``0..frames-1``."""

    camera: Camera
    frames: int
    fps: float
    units_per_metre: float
    detections: list[list[Detection]]
    description: str = ""

    def __call__(self, k: int) -> list[Detection]:
        return self.detections[k] if 0 <= k < len(self.detections) else []


# -- det-files --------------------------------------------------------------------------------------
def load_det_file_camera(calibration: Path, index: int, node: int,
                         frames: int | None = None) -> Source:
    """Camera ``index`` of a det-files directory, as node ``node`` (its camera id): the same
    ``Detection`` objects the simulator's det-files loader builds (edge_node.formats)."""
    try:
        cal = read_calibration(calibration)
        if index >= len(cal.cameras):
            raise SourceError(f"{cal.path}: has {len(cal.cameras)} cameras, no camera index {index}")
        n = cal.frame_count()
        n = n if frames is None else min(n, frames)
        if n <= 0:
            raise SourceError(f"{cal.path}: no frames")
        f = cal.files[index]
        dets, _ = read_det(f.det, n, f.descriptors, f.descriptors_required)
    except DetFilesError as e:
        raise SourceError(str(e)) from None
    cam = replace(cal.cameras[index], id=node)
    return Source(cam, n, cal.fps, cal.units_per_metre, dets,
                  f"det-file {calibration} camera {index}")


# -- scenario (developer convenience) -------------------------------------------------------------
def load_scenario_camera(name: str, index: int, node: int, seed: int | None, frames: int | None,
                         data_root: Path | None) -> Source:
    """Camera ``index`` of a sim_cluster scenario; imports sim_cluster lazily (edge_node does not
    depend on it)."""
    try:
        from sim_cluster.scenario import load_scenario
    except ImportError as e:  # a camera box without the simulator installed
        raise SourceError(f"source kind 'scenario' needs the sim_cluster package ({e})") from None
    try:
        data = load_scenario(name, seed=seed, frames=frames, data_root=data_root)
    except (ValueError, OSError) as e:
        raise SourceError(str(e)) from None
    if index >= data.num_cameras:
        raise SourceError(f"scenario {data.name} has {data.num_cameras} cameras, no camera {index}")
    dets = [data.detections[k][index] for k in range(data.frames)]
    cam = replace(data.cameras[index], id=node)
    return Source(cam, data.frames, data.fps, data.units_per_metre, dets,
                  f"scenario {data.name} seed {data.seed} camera {index}")


def open_source(cfg: NodeConfig) -> Source:
    """The source the config names; ``[camera]`` overrides its calibration."""
    s = cfg.source
    if s.kind == "det-file":
        src = load_det_file_camera(s.path, s.camera, cfg.node)
    elif s.kind == "scenario":
        src = load_scenario_camera(s.scenario, s.camera, cfg.node, s.seed, s.frames, s.data_root)
    elif s.kind in ("video", "images", "epfl", "camera"):  # frames -> edge_node/perception
        from edge_node.perception import PerceptionError
        from edge_node.perception.pipeline import open_frame_source

        try:  # detector, re-id weights and frames are all opened here, at start-up
            return open_frame_source(cfg)  # its camera is [camera] (or EPFL's homographies)
        except PerceptionError as e:
            raise SourceError(str(e)) from None
    else:  # pragma: no cover - the config validated it
        raise NodeConfigError(cfg.name, "source.kind", f"unknown kind {s.kind!r}")
    if cfg.camera is not None:
        src.camera = cfg.camera.camera(cfg.node)
        src.fps = cfg.camera.fps
        if cfg.camera.units_per_metre is not None:
            src.units_per_metre = cfg.camera.units_per_metre
    return src
