"""``[source] kind = "scenario"``: a camera process that replays one camera of a simulated
scenario (developer convenience; what ``sim_cluster up`` configures its nodes with).

A plug-in of ``edge_node``'s sources (entry-point group ``dmtt.sources``, declared in
pyproject.toml; the interface is in ``edge_node/runtime/sources.py``): edge_node looks the kind
up by name and never imports the simulator. The scenario is regenerated in the process from its
file and seed, a chunk at a time as the node asks for frames (``ScenarioStream``), so the node
sees exactly the detections of the in-process run and holds one chunk of them. ``[source]``
fields::

    kind = "scenario"
    scenario = "terrace-sim"   # preset name or path (relative to the camera config)
    seed = 0                   # optional: the scenario's own by default
    frames = 200               # optional: the scenario's own by default
    data_root = "..."          # optional: for dataset scenarios (EPFL)
    camera = 0                 # which camera of the scenario        [the node id]
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from edge_node.core.types import Detection

from edge_node.runtime.sources import Source, SourceError
from edge_node.settings import Table
from sim_cluster.scenarios.loader import open_scenario


def parse(t: Table, base: Path) -> dict[str, Any]:
    """The ``[source]`` fields of this kind (``t.finish()`` is the caller's)."""
    name = t.string("scenario")
    if not name:
        raise t.error("scenario", "must be a preset name or a path")
    if "/" in name or name.endswith(".toml"):
        p = Path(name).expanduser()
        name = str(p if p.is_absolute() else base / p)
    return {"scenario": name, "seed": t.integer("seed", None, lo=0),
            "frames": t.integer("frames", None, lo=1),
            "data_root": t.path("data_root", base, None)}


def open(options: dict[str, Any], camera: int, node: int) -> Source:  # noqa: A001 - the plug-in API
    """Camera ``camera`` of the scenario, as node ``node`` (its camera id). A scenario that
    cannot be loaded or has no such camera is a ``SourceError`` naming the field."""
    try:
        data = open_scenario(options["scenario"], seed=options.get("seed"),
                             frames=options.get("frames"), data_root=options.get("data_root"))
    except (ValueError, OSError) as e:
        raise SourceError(f"source.scenario: {e}") from None
    if camera >= data.num_cameras:
        raise SourceError(f"source.camera is {camera}, but scenario {data.name} has "
                          f"{data.num_cameras} cameras (0..{data.num_cameras - 1})")
    cam = replace(data.cameras[camera], id=node)
    read = SeekingCamera(data.camera(camera))
    # the first chunk now, at start-up, before the node joins the network: made at frame 0 it
    # held the node's first message back while its neighbours, past the start-up barrier, waited
    # (on a busy machine long enough to time out on frame 0)
    read(0)
    return Source(cam, data.frames, data.fps, data.units_per_metre, read,
                  f"scenario {data.name} seed {data.seed} camera {camera}", seek=read.seek)


class SeekingCamera:
    """A simulated camera's frames read in order (``read(k)``), and ``seek(k)`` after its node
    skipped ahead (a freeze): the world walks its people to frame ``k`` frame by frame, which
    takes seconds for a skip of minutes (15,000 frames: about 3.4 s of CPU), so the walk runs in
    a thread while the node, level with the network at once, reads ``None`` (no image yet,
    ``Source.seek``) and predicts through. The walk chases the newest frame asked for and hands
    the stream back when it has made that frame's chunk; from there frames are read as before.
    A frame that is read is the same as in a run without a seek (a scenario's frame ``k``
    depends only on its seed and ``k``)."""

    def __init__(self, read: Callable[[int], list[Detection]]):
        self._read = read
        self._lock = threading.Lock()
        self._want = 0  # the newest frame asked for while the walk runs
        self._walker: threading.Thread | None = None
        self._error: BaseException | None = None

    def __call__(self, k: int) -> list[Detection] | None:
        if self._walker is not None:
            if self._walker.is_alive():
                with self._lock:
                    self._want = max(self._want, k)
                return None
            self._walker = None
        if self._error is not None:  # the walk's failure is the reader's (not a silent thread)
            e, self._error = self._error, None
            raise e
        return self._read(k)

    def seek(self, k: int) -> None:
        with self._lock:
            self._want = k if self._walker is None else max(self._want, k)
        if self._walker is None:
            self._walker = threading.Thread(target=self._walk, name="scenario-seek", daemon=True)
            self._walker.start()

    def _walk(self) -> None:
        made = None
        try:
            while True:
                with self._lock:
                    k = self._want
                    if k == made:
                        return
                self._read(k)  # the walk to k's chunk, and the chunk
                made = k
        except BaseException as e:  # noqa: BLE001 - handed to the next read
            self._error = e
