"""Where a camera process gets its detections: the :class:`Source` interface and its kinds.

A source is this node's camera and a callable ``source(k) -> [Detection]`` over frames
``0..frames-1`` (plus ``fps``, ``units_per_metre`` and a one-line ``description``). Kinds
(``[source] kind`` of a camera config), each making or reading a frame when it is asked for, so
a node's memory does not grow with the number of frames of its run:

``det-file``
    one camera of a det-files directory, read with :mod:`edge_node.formats`, the reader the
    simulator uses too: the very same ``Detection`` objects (boxes float64 as parsed from
    det.txt, descriptors float32 from the ``.npy``, all-NaN rows = no descriptor, NaN
    confidence = 1.0), so a multi-process run equals the in-process reference run on the files.
    Frame ``k``'s detections are built when it is read: the node holds det.txt's table and a
    memory map of the descriptors, not a list of detections per frame.
``video`` | ``images`` | ``epfl`` | ``camera``
    frames through a detector and re-id (``edge_node/perception``; a ``FrameDetections``).
plug-ins
    any other kind is looked up by name in the entry-point group ``dmtt.sources``
    (:data:`PLUGIN_GROUP`). ``sim_cluster`` registers ``scenario`` there (a developer's node that
    replays one camera of a simulated scenario, ``sim_cluster/scenarios/replay.py``), so this
    package never imports the simulator; on a camera box without it, that kind is a clear
    :class:`SourceError`. A plug-in is an object with::

        parse(table: edge_node.settings.Table, base: Path) -> dict
            # its own [source] fields, validated (relative paths against base); the config
            # keeps them as SourceSettings.options and finishes the table
        open(options: dict, camera: int, node: int) -> Source
            # at start-up: camera index ``camera`` of the source, as node ``node``
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol

from edge_node.core.types import Detection
from edge_node.formats.calibration import read_calibration
from edge_node.formats.detfile import DetFilesError, open_det
from edge_node.geometry import Camera
from edge_node.perception import PerceptionError
from edge_node.perception.frames import FRAME_KINDS
from edge_node.perception.pipeline import open_frame_source
from edge_node.settings import Table
from protocol.errors import DmttError

PLUGIN_GROUP = "dmtt.sources"


class SourceError(DmttError, ValueError):
    """A source that cannot be opened: unreadable files, or a kind nobody installed. A plug-in
    starts its message with the field at fault (``source.camera is 42, but ...``);
    :func:`open_source` puts the config's file name in front."""


@dataclass
class Source:
    """This node's camera and its detections per frame ``0..frames-1``: ``read(k)``, called
    with increasing ``k`` (frames may be skipped, never revisited in a normal run), makes or
    reads frame ``k`` on demand, so a source need not hold a run's frames in memory. After a
    skip the loop calls ``seek`` (when the source has one) with the frame it skipped to."""

    camera: Camera
    frames: int
    fps: float
    units_per_metre: float
    #: frame ``k``'s detections; ``None``: the camera has no image for ``k`` yet (after a seek)
    read: Callable[[int], list[Detection] | None]
    description: str = ""
    #: optional: the node skipped ahead to frame ``k`` (a catch-up after a freeze). A source
    #: that must make its way there (a simulated world walking its people frame by frame) may
    #: do so in the background and answer ``None`` until it is there: those frames have no
    #: image, as a camera's frames dropped while it was busy, and the node predicts through
    #: them. A camera serves its current frame and needs no seek.
    seek: Callable[[int], None] | None = None
    #: frames read that had no image yet (``read`` gave ``None``)
    frames_without_image: int = 0

    def __call__(self, k: int) -> list[Detection]:
        if not 0 <= k < self.frames:
            return []
        dets = self.read(k)
        if dets is None:
            self.frames_without_image += 1
            return []
        return dets


class SourcePlugin(Protocol):
    """A source kind provided by another package (entry-point group ``dmtt.sources``)."""

    def parse(self, table: Table, base: Path) -> dict[str, Any]: ...

    def open(self, options: dict[str, Any], camera: int, node: int) -> Source: ...


def plugin_kinds() -> list[str]:
    """The source kinds installed as plug-ins."""
    return sorted({ep.name for ep in entry_points(group=PLUGIN_GROUP)})


def source_plugin(kind: str) -> SourcePlugin:
    """The plug-in registered for ``kind``; :class:`SourceError` when none is installed or it
    cannot be loaded."""
    found = [ep for ep in entry_points(group=PLUGIN_GROUP) if ep.name == kind]
    if not found:
        raise SourceError(f"source kind {kind!r} is not installed: no package registers it in the "
                          f"entry-point group {PLUGIN_GROUP!r} ('scenario' comes with sim_cluster; "
                          f"installed: {', '.join(plugin_kinds()) or 'none'})")
    try:
        return found[0].load()
    except Exception as e:  # noqa: BLE001 - a broken plug-in is the user's setup, say which
        raise SourceError(f"source kind {kind!r}: its plug-in {found[0].value} cannot be loaded "
                          f"({type(e).__name__}: {e})") from None


# -- det-files --------------------------------------------------------------------------------------
def load_det_file_camera(calibration: Path, index: int, node: int,
                         frames: int | None = None) -> Source:
    """Camera ``index`` of a det-files directory, as node ``node`` (its camera id): the same
    ``Detection`` objects the simulator's det-files loader builds (edge_node.formats), made
    when ``read(k)`` asks for frame ``k`` (the files are validated here, at start-up)."""
    try:
        cal = read_calibration(calibration)
        if index >= len(cal.cameras):
            raise SourceError(f"source.camera is {index}, but {cal.path} has {len(cal.cameras)} "
                              f"cameras (0..{len(cal.cameras) - 1})")
        n = cal.frame_count()
        n = n if frames is None else min(n, frames)
        if n <= 0:
            raise SourceError(f"source.path: {cal.path}: no frames")
        f = cal.files[index]
        det = open_det(f.det, n, f.descriptors, f.descriptors_required, cal.bound)
    except DetFilesError as e:
        raise SourceError(f"source.path: {e}") from None
    cam = replace(cal.cameras[index], id=node)
    return Source(cam, n, cal.fps, cal.units_per_metre, det.detections,
                  f"det-file {calibration} camera {index}")


def open_source(cfg) -> Source:
    """The source a ``NodeConfig`` names; ``[camera]`` overrides its calibration. Anything that
    cannot be opened is a :class:`SourceError` starting with the config's file name (then the
    field, where the source kind knows it: ``cam0.toml: source.camera is 42, but ...``)."""
    try:
        return _open_source(cfg)
    except SourceError as e:
        raise SourceError(f"{cfg.name}: {e}") from None


def _open_source(cfg) -> Source:
    s = cfg.source
    if s.kind in FRAME_KINDS:  # frames -> edge_node/perception
        try:  # detector, re-id weights and frames are all opened here, at start-up
            return open_frame_source(cfg)  # its camera is [camera] (or EPFL's homographies)
        except PerceptionError as e:
            raise SourceError(str(e)) from None
    if s.kind == "det-file":
        src = load_det_file_camera(s.path, s.camera, cfg.node)
    else:
        src = source_plugin(s.kind).open(dict(s.options), s.camera, cfg.node)
    if cfg.camera is not None:
        src.camera = cfg.camera.camera(cfg.node)
        src.fps = cfg.camera.fps
        if cfg.camera.units_per_metre is not None:
            src.units_per_metre = cfg.camera.units_per_metre
    return src
