"""What a scenario gives the network: cameras, per-frame detections, and the ground truth.

Two forms of the same thing:

:class:`ScenarioStream`
    frames made on demand, a chunk of ``chunk_frames`` at a time (:meth:`ScenarioStream.frame`).
    Memory does not grow with the number of frames: a camera process replaying one camera of a
    100,000-frame scenario holds one chunk. Frame ``k`` is a function of the scenario, its seed
    and ``k`` only, never of how many frames the run has or which frames were asked before.
:class:`ScenarioData`
    every frame in lists (``stream.materialise()``): what in-process runs and evaluation use.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from edge_node.core.types import Detection
from edge_node.geometry import Camera


@dataclass
class GroundTruth:
    """Ground truth of a scenario, frame by frame.

    ``ids[k]`` (n,) int person ids present in the monitored area at frame ``k`` (inside at least one
    camera's field of view), ``xy[k]`` (n, 2) their ground positions, ``wh[k]`` (n, 2) their
    cylinder width and height (ground units). ``boxes[c][k]`` is ``(ids (m,), boxes (m, 4))``:
    the people visible in camera ``c`` at frame ``k`` with their image boxes (the image-plane
    ground truth the paper evaluates against).
    """

    ids: list[np.ndarray]
    xy: list[np.ndarray]
    wh: list[np.ndarray]
    boxes: list[list[tuple[np.ndarray, np.ndarray]]]


@dataclass
class ScenarioData:
    """A fully materialised scenario: everything needed to run and evaluate a network.

    ``detections[k][c]`` are camera ``c``'s detections at frame ``k``; ``detection_truth[k][c]``
    the person id behind each of them (``-1`` for a false positive), for diagnostics only.
    Ground coordinates are in the scenario's own units; ``units_per_metre`` converts (1.0 for the
    synthetic world, about 30 for EPFL Terrace).
    """

    name: str
    cameras: list[Camera]
    frames: int
    fps: float
    units_per_metre: float
    detections: list[list[list[Detection]]]
    truth: GroundTruth
    detection_truth: list[list[np.ndarray]] = field(default_factory=list)
    area: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0)  # xmin, xmax, ymin, ymax
    seed: int = 0
    #: the cameras' neighbour graph when the scenario has one (a generated layout's lattice;
    #: topology ``layout``), else None
    neighbours: dict[int, tuple[int, ...]] | None = None
    #: one-line notes of the loader on what it found or assumed (another tool's layout)
    notes: tuple[str, ...] = ()

    @property
    def num_cameras(self) -> int:
        return len(self.cameras)

    def frame(self, k: int) -> "Frame":
        """Frame ``k`` as a :class:`Frame` (the interface a :class:`ScenarioStream` shares)."""
        if not 0 <= k < self.frames:
            raise IndexError(f"frame {k} outside 0..{self.frames - 1} of scenario {self.name}")
        t, C = self.truth, self.num_cameras
        return Frame(detections=self.detections[k],
                     detection_truth=(self.detection_truth[k] if self.detection_truth
                                      else [np.zeros(0, np.int64)] * C),
                     ids=t.ids[k], xy=t.xy[k], wh=t.wh[k], boxes=[t.boxes[c][k] for c in range(C)])

    def has_descriptors(self) -> bool:
        """Whether any detection carries an appearance descriptor (a detector with re-id)."""
        return any(d.descriptor is not None for frame in self.detections for cam in frame
                   for d in cam)

    def without_descriptors(self) -> "ScenarioData":
        """The same detections without appearance: what a detector without re-id gives."""
        return replace(self, detections=[[[replace(d, descriptor=None) for d in cam]
                                          for cam in frame] for frame in self.detections])


@dataclass
class Frame:
    """One frame of a scenario, every camera: ``detections[c]`` with the person behind each
    (``detection_truth[c]``, ``-1`` for a false positive), the ground truth ``ids`` / ``xy`` /
    ``wh`` (as :class:`GroundTruth` at one frame) and ``boxes[c] = (ids, boxes)``."""

    detections: list[list[Detection]]
    detection_truth: list[np.ndarray]
    ids: np.ndarray
    xy: np.ndarray
    wh: np.ndarray
    boxes: list[tuple[np.ndarray, np.ndarray]]


#: Frames per chunk of every scenario source that makes its frames in chunks (the synthetic
#: world, EPFL gt-replay, det-files): the unit in which frames are made and held, and the unit
#: of a source's random streams (a camera's detector draws chunk ``j`` from its own generator).
CHUNK_FRAMES = 100

#: ``chunk(j)`` -> frames ``j * chunk_frames .. (j + 1) * chunk_frames - 1`` (all of them, also past
#: the scenario's last frame where the source can make them; :class:`ScenarioStream` truncates).
ChunkMaker = Callable[[int], list[Frame]]


@dataclass
class ScenarioStream:
    """A scenario whose frames are made on demand (see the module docstring).

    ``chunk`` makes one chunk of frames; the stream keeps the last chunk it made, so reading
    frames in order costs one ``chunk`` call per ``chunk_frames`` frames. A source that must
    simulate its way to a frame (the synthetic world's walkers) does so inside ``chunk``.
    """

    name: str
    cameras: list[Camera]
    frames: int
    fps: float
    units_per_metre: float
    chunk: ChunkMaker
    chunk_frames: int
    area: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0)
    seed: int = 0
    #: the cameras' neighbour graph when the scenario has one (ScenarioData.neighbours)
    neighbours: dict[int, tuple[int, ...]] | None = None
    #: one-line notes of the loader on what it found or assumed (another tool's layout)
    notes: tuple[str, ...] = ()
    #: optional: ``focus(cameras)`` -> a chunk maker that makes the detections and image ground
    #: truth of these cameras only (the others' are empty), the same as ``chunk``'s; its world
    #: truth (``Frame.ids``, ``xy``) may cover only the people these cameras see
    focus: Callable[[list[int]], ChunkMaker] | None = field(default=None, repr=False)
    _held: tuple[int, list[Frame]] | None = field(default=None, repr=False)

    @property
    def num_cameras(self) -> int:
        return len(self.cameras)

    def frame(self, k: int) -> Frame:
        """Frame ``k`` (``0 <= k < frames``)."""
        if not 0 <= k < self.frames:
            raise IndexError(f"frame {k} outside 0..{self.frames - 1} of scenario {self.name}")
        j = k // self.chunk_frames
        if self._held is None or self._held[0] != j:
            self._held = (j, self.chunk(j))
        return self._held[1][k - j * self.chunk_frames]

    def __iter__(self) -> Iterator[Frame]:
        return (self.frame(k) for k in range(self.frames))

    def camera(self, c: int) -> Callable[[int], list[Detection]]:
        """Camera ``c``'s detections as ``read(k)``: what a camera process replays (a stream of
        its own that makes camera ``c``'s frames only, where the source can)."""
        s = self if self.focus is None else replace(self, chunk=self.focus([c]), focus=None,
                                                     _held=None)
        return lambda k: s.frame(k).detections[c]

    def first_cameras(self, n: int) -> "ScenarioStream":
        """The same stream seen by cameras ``0..n-1`` only (``sim_cluster up --nodes n``)."""
        if n == self.num_cameras:
            return self
        full = self.chunk

        def chunk(j: int) -> list[Frame]:
            return [replace(f, detections=f.detections[:n], detection_truth=f.detection_truth[:n],
                            boxes=f.boxes[:n]) for f in full(j)]

        nb = None if self.neighbours is None else {
            i: tuple(j for j in self.neighbours[i] if j < n) for i in range(n)}
        return replace(self, cameras=self.cameras[:n], chunk=chunk, focus=None, _held=None,
                       neighbours=nb)

    def materialise(self) -> "ScenarioData":
        """Every frame in lists: the :class:`ScenarioData` of this stream."""
        C = self.num_cameras
        truth = GroundTruth(ids=[], xy=[], wh=[], boxes=[[] for _ in range(C)])
        detections, det_truth = [], []
        for f in self:
            detections.append(f.detections)
            det_truth.append(f.detection_truth)
            truth.ids.append(f.ids)
            truth.xy.append(f.xy)
            truth.wh.append(f.wh)
            for c in range(C):
                truth.boxes[c].append(f.boxes[c])
        return ScenarioData(name=self.name, cameras=list(self.cameras), frames=self.frames,
                            fps=self.fps, units_per_metre=self.units_per_metre,
                            detections=detections, truth=truth, detection_truth=det_truth,
                            area=self.area, seed=self.seed, neighbours=self.neighbours,
                            notes=self.notes)

    @classmethod
    def of(cls, data: "ScenarioData", chunk_frames: int = CHUNK_FRAMES) -> "ScenarioStream":
        """A materialised scenario as a stream (its frames are already in memory)."""
        def chunk(j: int) -> list[Frame]:
            return [data.frame(k) for k in range(j * chunk_frames,
                                                 min((j + 1) * chunk_frames, data.frames))]

        return cls(name=data.name, cameras=list(data.cameras), frames=data.frames, fps=data.fps,
                   units_per_metre=data.units_per_metre, chunk=chunk, chunk_frames=chunk_frames,
                   area=data.area, seed=data.seed, neighbours=data.neighbours, notes=data.notes)
