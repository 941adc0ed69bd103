"""The seeded synthetic world: people walking on a ground plane seen by calibrated cameras.

Ground units are metres. People are vertical cylinders ``(x, y, w, h)``. They enter from the
area's border (from ``spawn_margin_m`` outside it), walk between random waypoints inside the area
with a bounded turn rate, a light mutual repulsion (they swerve instead of walking through each
other, so paths cross the way crowds do; a step that would make two cylinders overlap further
is not taken) and occasional pauses, and after their stay walk out
through the border and disappear; a replacement enters after a random gap, so about
``concurrent`` people are inside at any time.

Per frame and camera:

* **Boxes.** A person's image box is the silhouette box of their cylinder (the same 16-point
  sampling as :meth:`edge_node.geometry.Camera.cylinder_to_box`: width and top edge), re-anchored
  so that its bottom centre is exactly the image of the cylinder's base centre (the foot point).
  The bottom centre of a ground-truth box therefore maps back through the camera's homography
  onto the person's ground position, the measurement convention of the tracker (paper III-A).
  A camera given only by a homography uses ``cylinder_to_box`` directly (already foot-anchored).
* **Occlusion.** People nearer to the camera (horizontal distance from the camera centre; image
  foot row when the camera has no projection matrix) hide the farther ones: the visible fraction
  is the share of a box's in-image part not covered by any nearer person's box, measured on an
  8 x 16 grid of sample points (resolution 1/128).
* **Ground truth.** Camera ``c`` lists a person when the box is in front of the camera and the
  part of it that is inside the image and unoccluded is at least ``min_visible`` of the box
  (default 0.1: nearly fully hidden or nearly fully outside people are not annotated).
  ``truth.ids[k]`` lists everybody whose box is at least ``min_visible`` inside some camera's
  image, occlusion ignored (an occluded person is still in the monitored area).
* **Detections** come from :func:`sim_cluster.detector_model.detect` for every person whose box
  is in front and at least partly in the image.
* **Calibration errors** (``WorldConfig.calibration``, a scenario's ``[calibration_error]``;
  :mod:`~sim_cluster.scenarios.synthetic.calibration`): everything above uses the TRUE cameras;
  ``ScenarioData.cameras`` are the believed ones, whose ground map is off by a known similarity.
  A bumped camera is projected, from the bump's frame on, through the moved true camera
  (boxes, visibility, occlusion order and image ground truth all from it); only its false
  positives keep the camera before the bump for their sizes (random boxes either way).

All randomness derives from the scenario seed with one independent stream per purpose: people
(``[seed, 1]``), each camera's detector (``[seed, 2, camera]``), appearance identities and views
from the seed itself (:class:`~sim_cluster.appearance.AppearanceModel`). Changing the detector
does not move the people; changing one camera does not change another camera's detections;
changing the false-positive rate does not change any true detection (see
:func:`~sim_cluster.detector_model.detect_frames` for the draw order).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import heapq
import math

import numpy as np

from edge_node.geometry import Camera
from protocol.errors import DmttError
from sim_cluster.scenarios.data import CHUNK_FRAMES, Frame, ScenarioData, ScenarioStream
from sim_cluster.scenarios.synthetic.appearance import AppearanceModel, AppearanceParams
from sim_cluster.scenarios.synthetic.calibration import (CalibrationOffsets, believed_camera,
                                                         moved_camera)
from sim_cluster.scenarios.synthetic.detector_model import (DetectorParams, detect_frames,
                                                            in_image_fraction)

_TAG_PEOPLE = 1
_TAG_DETECT = 2
_RING = 16  # silhouette samples per circle, as Camera.cylinder_to_box
_GRID = (8, 16)  # occlusion sample grid (columns, rows) per box
_SIDESTEPS = tuple(math.radians(a) for a in (0.0, -45.0, 45.0, -90.0, 90.0))


class WorldError(DmttError, ValueError):
    """A world configuration that cannot be simulated."""


@dataclass(frozen=True)
class PeopleParams:
    """How people come, walk and go. Ranges ``(lo, hi)`` are sampled uniformly per person."""

    concurrent: int = 9  # about how many people are inside at once
    initial: int | None = None  # inside at frame 0 (default: concurrent)
    speed_mps: tuple[float, float] = (0.8, 1.5)
    width_m: tuple[float, float] = (0.45, 0.6)
    height_m: tuple[float, float] = (1.55, 1.9)
    stay_s: tuple[float, float] = (15.0, 40.0)  # time inside before heading for an exit
    entry_gap_s: float = 2.0  # mean delay before a replacement enters
    turn_rate_dps: float = 180.0  # maximal heading change
    pause_probability: float = 0.2  # chance to stand still on reaching a waypoint
    pause_s: tuple[float, float] = (1.0, 4.0)
    spawn_margin_m: float = 1.0  # people appear / vanish this far outside the area's border
    waypoint_margin_m: float = 0.5  # waypoints keep this far inside the border
    personal_space_m: float = 0.7  # repulsion radius between people

    def __post_init__(self) -> None:
        if self.concurrent < 0 or (self.initial is not None and self.initial < 0):
            raise WorldError("people counts must be >= 0")
        for name in ("speed_mps", "width_m", "height_m", "stay_s", "pause_s"):
            lo, hi = getattr(self, name)
            if not (0 <= lo <= hi) or not math.isfinite(hi):
                raise WorldError(f"people.{name} must be a range 0 <= lo <= hi, got {(lo, hi)}")
        if self.speed_mps[0] <= 0 or self.width_m[0] <= 0 or self.height_m[0] <= 0:
            raise WorldError("people speeds and sizes must be > 0")
        if self.turn_rate_dps <= 0 or self.entry_gap_s < 0 or not 0 <= self.pause_probability <= 1:
            raise WorldError("people.turn_rate_dps > 0, entry_gap_s >= 0, pause_probability in [0, 1]")

    @property
    def initial_count(self) -> int:
        return self.concurrent if self.initial is None else self.initial


@dataclass(frozen=True)
class WorldConfig:
    """Everything the synthetic world needs (what a ``synthetic`` scenario TOML describes)."""

    name: str
    area: tuple[float, float, float, float]  # xmin, xmax, ymin, ymax (metres)
    cameras: list[Camera]
    frames: int
    fps: float = 25.0
    seed: int = 0
    people: PeopleParams = field(default_factory=PeopleParams)
    detector: DetectorParams = field(default_factory=DetectorParams)
    appearance: AppearanceParams = field(default_factory=AppearanceParams)
    min_visible: float = 0.1  # ground-truth visibility threshold (see module docstring)
    calibration: CalibrationOffsets | None = None  # known registration errors (calibration module)

    def __post_init__(self) -> None:
        xmin, xmax, ymin, ymax = self.area
        if not (xmin < xmax and ymin < ymax):
            raise WorldError(f"area must have xmin < xmax and ymin < ymax, got {self.area}")
        if self.frames < 1 or self.fps <= 0 or not self.cameras:
            raise WorldError("need frames >= 1, fps > 0 and at least one camera")
        if not 0 <= self.min_visible <= 1:
            raise WorldError("min_visible must be in [0, 1]")
        if [c.id for c in self.cameras] != list(range(len(self.cameras))):
            raise WorldError("camera ids must be 0..N-1 in order")
        cal = self.calibration
        if cal is not None:
            if len(cal.shifts) != len(self.cameras) or len(cal.rotations_deg) != len(self.cameras):
                raise WorldError(f"calibration error: one shift and one rotation per camera "
                                 f"({len(self.cameras)}), got {len(cal.shifts)} and "
                                 f"{len(cal.rotations_deg)}")
            if cal.bump is not None and not (0 <= cal.bump.camera < len(self.cameras)
                                             and cal.bump.frame >= 0):
                raise WorldError(f"calibration bump: camera must be in [0, {len(self.cameras) - 1}] "
                                 f"and frame >= 0, got {cal.bump}")


@dataclass
class Trajectories:
    """People's paths: ``xy[k, i]`` ground position of person ``ids[i]`` at frame ``k`` (NaN when
    absent), ``wh[i]`` their cylinder width and height."""

    ids: np.ndarray  # (N,)
    xy: np.ndarray  # (frames, N, 2)
    wh: np.ndarray  # (N, 2)

    @property
    def present(self) -> np.ndarray:
        """``(frames, N)`` whether each person is in the world at each frame."""
        return np.isfinite(self.xy[..., 0])


# -- people ------------------------------------------------------------------------------------


class _Person:
    __slots__ = ("pid", "pos", "heading", "speed", "wh", "target", "leaving", "leave_at",
                 "pause_until", "start", "arrive_r", "stuck")

    def __init__(self, pid: int, pos: np.ndarray, heading: float, speed: float, wh: np.ndarray,
                 start: int, leave_at: int, arrive_r: float):
        self.pid = pid
        self.pos = pos
        self.heading = heading
        self.speed = speed
        self.wh = wh
        self.target = pos
        self.leaving = False
        self.leave_at = leave_at
        self.pause_until = -1
        self.start = start
        self.arrive_r = arrive_r
        self.stuck = 0


def _border_point(area: tuple[float, float, float, float], margin: float,
                  rng: np.random.Generator) -> np.ndarray:
    """A uniform point on the area's border, pushed ``margin`` outward."""
    xmin, xmax, ymin, ymax = area
    w, h = xmax - xmin, ymax - ymin
    s = rng.uniform(0.0, 2 * (w + h))
    if s < w:
        return np.array([xmin + s, ymin - margin])
    s -= w
    if s < h:
        return np.array([xmax + margin, ymin + s])
    s -= h
    if s < w:
        return np.array([xmax - s, ymax + margin])
    s -= w
    return np.array([xmin - margin, ymax - s])


def _waypoint(area: tuple[float, float, float, float], margin: float, rng: np.random.Generator,
              avoid: np.ndarray | None = None) -> np.ndarray:
    xmin, xmax, ymin, ymax = area
    mx = min(margin, 0.45 * (xmax - xmin))
    my = min(margin, 0.45 * (ymax - ymin))
    p = np.array([rng.uniform(xmin + mx, xmax - mx), rng.uniform(ymin + my, ymax - my)])
    if avoid is not None:  # one retry to avoid pointless tiny legs
        if np.hypot(*(p - avoid)) < 0.25 * min(xmax - xmin, ymax - ymin):
            p = np.array([rng.uniform(xmin + mx, xmax - mx), rng.uniform(ymin + my, ymax - my)])
    return p


class PeopleWalk:
    """The people of a world, one frame at a time: :meth:`next` gives frame ``k`` (``ids``,
    ``xy``, ``wh`` of everybody in the world), then walks everybody to frame ``k + 1``.

    Memory holds the people in the world, never the ones who left. Frame ``k`` depends only on
    the generator's seed and ``k``: walking 100 frames gives the first 100 frames of a walk of
    1000 (see the module docstring for the behaviour).
    """

    def __init__(self, area: tuple[float, float, float, float], fps: float, params: PeopleParams,
                 rng: np.random.Generator):
        self.area, self.fps, self.params, self.rng = area, fps, params, rng
        self.k = 0  # the frame next() gives
        self.born = 0  # people so far: ids are 1, 2, ...
        self.active: list[_Person] = []
        self._births: list[tuple[int, int]] = []  # (frame, sequence) heap
        self._seq = 0
        self._max_turn = math.radians(params.turn_rate_dps) / fps
        for _ in range(params.initial_count):
            for _try in range(20):  # initial places without overlaps, when there is room
                pos = _waypoint(area, params.waypoint_margin_m, rng)
                if all(math.hypot(*(pos - q.pos)) > 0.7 for q in self.active):
                    break
            self.active.append(self._new_person(0, pos, inside=True))
        for _ in range(max(0, params.concurrent - params.initial_count)):
            self._schedule(0)

    def _new_person(self, k: int, pos: np.ndarray, inside: bool) -> _Person:
        params, rng, fps = self.params, self.rng, self.fps
        speed = rng.uniform(*params.speed_mps)
        wh = np.array([rng.uniform(*params.width_m), rng.uniform(*params.height_m)])
        stay = rng.uniform(*params.stay_s)
        if inside:  # already inside at the start: an unknown part of the stay is over
            stay *= rng.uniform(0.1, 1.0)
        arrive_r = max(0.6, 2.0 * speed / math.radians(params.turn_rate_dps))
        self.born += 1
        p = _Person(self.born, pos, 0.0, speed, wh, k, k + int(round(stay * fps)), arrive_r)
        p.target = _waypoint(self.area, params.waypoint_margin_m, rng, avoid=pos)
        d = p.target - pos
        p.heading = rng.uniform(-math.pi, math.pi) if inside else math.atan2(d[1], d[0])
        return p

    def _entry_point(self) -> np.ndarray:
        """Where a newcomer appears: a border point, ``spawn_margin_m`` outside the area."""
        return _border_point(self.area, self.params.spawn_margin_m, self.rng)

    def _schedule(self, k: int) -> None:
        gap = self.rng.exponential(self.params.entry_gap_s) if self.params.entry_gap_s > 0 else 0.0
        heapq.heappush(self._births, (k + max(1, int(round(gap * self.fps))), self._seq))
        self._seq += 1

    def next(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ids (n,), xy (n, 2), wh (n, 2))`` of frame ``self.k``; then one step of walking."""
        k = self.k
        while self._births and self._births[0][0] <= k:
            heapq.heappop(self._births)
            self.active.append(self._new_person(k, self._entry_point(), inside=False))
        a = self.active
        frame = (np.array([p.pid for p in a], dtype=np.int64),
                 np.array([p.pos for p in a]).reshape(-1, 2),
                 np.array([p.wh for p in a]).reshape(-1, 2))
        self._step(k)
        self.k = k + 1
        return frame

    def _step(self, k: int) -> None:
        """Frame ``k`` -> ``k + 1``."""
        area, params, rng, fps = self.area, self.params, self.rng, self.fps
        active = self.active
        dt = 1.0 / fps
        max_turn = self._max_turn
        r_rep = params.personal_space_m
        # Repulsion: push away from people inside the personal space, with a sidestep component.
        rep = np.zeros((len(active), 2))
        if len(active) > 1 and r_rep > 0:
            P = np.array([p.pos for p in active])
            diff = P[:, None, :] - P[None, :, :]
            dist = np.hypot(diff[..., 0], diff[..., 1])
            np.fill_diagonal(dist, np.inf)
            wgt = np.clip((r_rep - dist) / r_rep, 0.0, None)
            unit = diff / np.maximum(dist, 1e-9)[..., None]
            side = np.stack([unit[..., 1], -unit[..., 0]], axis=-1)
            rep = np.sum(wgt[..., None] * (unit + 0.5 * side), axis=1) * 2.0
        survivors: list[_Person] = []
        cur = np.array([p.pos for p in active]).reshape(-1, 2)  # live positions: no-overlap rule
        radius = np.array([p.wh[0] / 2.0 for p in active])
        for idx, (p, r) in enumerate(zip(active, rep)):
            if not p.leaving and k >= p.leave_at:
                p.leaving = True
                p.pause_until = -1
                p.target = _border_point(area, params.spawn_margin_m, rng)
            to_t = p.target - p.pos
            dist_t = math.hypot(to_t[0], to_t[1])
            if dist_t < (0.15 if p.leaving else p.arrive_r):
                if p.leaving:
                    continue  # out of the world
                if rng.random() < params.pause_probability:
                    p.pause_until = k + int(round(rng.uniform(*params.pause_s) * fps))
                p.target = _waypoint(area, params.waypoint_margin_m, rng, avoid=p.pos)
                to_t = p.target - p.pos
                dist_t = math.hypot(to_t[0], to_t[1])
            desired = to_t / max(dist_t, 1e-9) + r
            want = math.atan2(desired[1], desired[0])
            dh = (want - p.heading + math.pi) % (2 * math.pi) - math.pi
            p.heading += max(-max_turn, min(max_turn, dh))
            if k >= p.pause_until:
                step = min(p.speed * dt, dist_t) if p.leaving else p.speed * dt
                # Bodies do not overlap: a step may not bring two cylinders closer once they
                # touch. A blocked walker sidesteps (right first), and after a second of being
                # stuck picks another goal.
                d_old = np.hypot(cur[:, 0] - p.pos[0], cur[:, 1] - p.pos[1])
                moved = False
                for turn in _SIDESTEPS:
                    h = p.heading + turn
                    new = p.pos + step * np.array([math.cos(h), math.sin(h)])
                    d_new = np.hypot(cur[:, 0] - new[0], cur[:, 1] - new[1])
                    touch = (d_new < radius + radius[idx]) & (d_new < d_old)
                    touch[idx] = False
                    if not touch.any():
                        p.pos, moved = new, True
                        cur[idx] = new
                        break
                p.stuck = 0 if moved else p.stuck + 1
                if p.stuck > fps:
                    p.stuck = 0
                    p.target = (_border_point(area, params.spawn_margin_m, rng) if p.leaving
                                else _waypoint(area, params.waypoint_margin_m, rng, avoid=p.pos))
            survivors.append(p)
        for _ in range(len(active) - len(survivors)):
            self._schedule(k + 1)
        self.active = survivors

    def skip(self, frames: int) -> None:
        """Walk ``frames`` frames without looking (fast-forward to a later chunk)."""
        for _ in range(frames):
            self.next()


def simulate_people(area: tuple[float, float, float, float], fps: float, frames: int,
                    params: PeopleParams, rng: np.random.Generator) -> Trajectories:
    """Walk people through ``frames`` frames (a :class:`PeopleWalk`, kept whole); deterministic
    given ``rng``."""
    walk = PeopleWalk(area, fps, params, rng)
    return _trajectories([walk.next() for _ in range(frames)])


def _trajectories(steps: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> Trajectories:
    """Frames of a walk as one :class:`Trajectories` over the people seen in them (from frame 0
    that is everybody born: a person is in the frame they are born in)."""
    ids = np.unique(np.concatenate([s[0] for s in steps] + [np.zeros(0, np.int64)]))
    col = {int(p): j for j, p in enumerate(ids)}
    xy = np.full((len(steps), len(ids), 2), np.nan)
    wh = np.zeros((len(ids), 2))
    for k, (pid, pos, size) in enumerate(steps):
        j = [col[int(p)] for p in pid]
        xy[k, j] = pos
        wh[j] = size
    return Trajectories(ids=ids, xy=xy, wh=wh)


# -- projection and occlusion -------------------------------------------------------------------


def project_people(camera: Camera, xy: np.ndarray, wh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image boxes ``(M, 4)`` of cylinders at ground positions ``xy (M, 2)`` with sizes ``wh (M, 2)``,
    and whether each is entirely in front of the camera ``(M,)``.

    Silhouette width and top as :meth:`Camera.cylinder_to_box`; bottom centre at the image of
    the base centre (see the module docstring). Boxes of people not in front are NaN.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    wh = np.asarray(wh, float).reshape(-1, 2)
    M = len(xy)
    boxes = np.full((M, 4), np.nan)
    if M == 0:
        return boxes, np.zeros(0, bool)
    if camera.P is None:
        front = camera.in_front(xy)
        for i in np.flatnonzero(front):
            boxes[i] = camera.cylinder_to_box(np.array([xy[i, 0], xy[i, 1], wh[i, 0], wh[i, 1]]))
        front &= np.all(np.isfinite(boxes), axis=1)
        return boxes, front
    P = camera.P
    ang = np.linspace(0.0, 2 * np.pi, _RING, endpoint=False)
    r = wh[:, 0:1] / 2.0
    rx = xy[:, 0:1] + r * np.cos(ang)  # (M, 16)
    ry = xy[:, 1:2] + r * np.sin(ang)
    # Projective coordinates of base ring (z=0) and top ring (z=h): linear in z.
    base = rx[..., None] * P[:, 0] + ry[..., None] * P[:, 1] + P[:, 3]  # (M, 16, 3)
    top = base + wh[:, 1, None, None] * P[:, 2]
    q = np.concatenate([base, top], axis=1)  # (M, 32, 3)
    foot = xy[:, 0:1] * P[:, 0] + xy[:, 1:2] * P[:, 1] + P[:, 3]  # (M, 3)
    front = np.all(q[..., 2] > 0, axis=1) & (foot[:, 2] > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = q[..., :2] / q[..., 2:3]
        fu = foot[:, 0] / foot[:, 2]
        fv = foot[:, 1] / foot[:, 2]
    u0 = uv[..., 0].min(axis=1)
    u1 = uv[..., 0].max(axis=1)
    v0 = uv[..., 1].min(axis=1)
    w = u1 - u0
    out = np.stack([fu - w / 2.0, v0, w, fv - v0], axis=1)
    front &= np.all(np.isfinite(out), axis=1) & (out[:, 3] > 0)
    boxes[front] = out[front]
    return boxes, front


def visible_fractions_batch(boxes: np.ndarray, depth: np.ndarray,
                            image_size: tuple[int, int]) -> np.ndarray:
    """:func:`visible_fractions` for a batch of independent frames: ``boxes (B, n, 4)``,
    ``depth (B, n)`` -> ``(B, n)``. Padding slots: NaN boxes (never cover anything, get 0)."""
    b = np.asarray(boxes, float)
    B, n = b.shape[:2]
    if n == 0:
        return np.zeros((B, 0))
    W, H = image_size
    valid = np.all(np.isfinite(b), axis=2)
    b = np.where(valid[..., None], b, -1.0)  # a 0-area box outside the image
    bx0, by0 = b[..., 0], b[..., 1]
    bx1, by1 = bx0 + b[..., 2], by0 + b[..., 3]
    x0, x1 = np.clip(bx0, 0, W), np.clip(bx1, 0, W)
    y0, y1 = np.clip(by0, 0, H), np.clip(by1, 0, H)
    empty = (x1 <= x0) | (y1 <= y0) | ~valid
    gx, gy = _GRID
    fx = (np.arange(gx) + 0.5) / gx
    fy = (np.arange(gy) + 0.5) / gy
    px = x0[..., None] + fx * (x1 - x0)[..., None]  # (B, n, gx)
    py = y0[..., None] + fy * (y1 - y0)[..., None]  # (B, n, gy)
    d = np.where(valid, np.asarray(depth, float), np.inf)
    nearer = (d[:, None, :] < d[:, :, None]) & valid[:, None, :]  # [b, i, j]: j nearer than i
    in_x = ((px[..., None] >= bx0[:, None, None, :]) & (px[..., None] < bx1[:, None, None, :])
            & nearer[:, :, None, :])  # (B, n, gx, n)
    in_y = (py[..., None] >= by0[:, None, None, :]) & (py[..., None] < by1[:, None, None, :])
    # covered[b, i, a, c] = any_j in_x[b, i, a, j] & in_y[b, i, c, j], as a batched product.
    hits = np.matmul(in_x.astype(np.float32), np.swapaxes(in_y, -1, -2).astype(np.float32))
    vis = 1.0 - np.mean(hits > 0, axis=(2, 3))
    return np.where(empty, 0.0, vis)


def visible_fractions(boxes: np.ndarray, depth: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Fraction of each box's in-image part that no nearer box covers (``depth``: smaller is
    nearer; equal depths do not occlude each other). Boxes entirely outside the image get 0.
    Measured on an 8 x 16 grid of sample points per box."""
    b = np.asarray(boxes, float).reshape(1, -1, 4)
    return visible_fractions_batch(b, np.asarray(depth, float).reshape(1, -1), image_size)[0]


# -- the whole scenario -------------------------------------------------------------------------
# A world is made a chunk of CHUNK_FRAMES at a time (data.py): one vectorised projection,
# occlusion and detector pass per camera, and the unit of the detector's random streams.


class WorldStream:
    """A world's frames, a chunk at a time (the ``chunk`` of its
    :class:`~sim_cluster.scenarios.data.ScenarioStream`).

    The walkers are simulated in order (one :class:`PeopleWalk`, restarted from frame 0 only
    when an earlier chunk is asked for after a later one); the detector of camera ``c`` draws
    chunk ``j`` from its own generator ``[seed, 2, c, j]``. So frame ``k`` is the same whether a
    run has 100 frames or 100,000, and whether the frames before it were made or skipped.
    """

    def __init__(self, config: WorldConfig, cameras: list[int] | None = None):
        """``cameras``: make these cameras' detections and image ground truth only (a camera
        process needs its own); the others' are empty. Each camera's are the same either way."""
        self.config = config
        self.cameras = cameras
        self.appearance = AppearanceModel(config.appearance, int(config.seed))
        self.walk = self._walk()

    def _walk(self) -> PeopleWalk:
        c = self.config
        return PeopleWalk(c.area, c.fps, c.people,
                          np.random.default_rng([int(c.seed), _TAG_PEOPLE]))

    def __call__(self, j: int) -> list[Frame]:
        k0 = j * CHUNK_FRAMES
        if self.walk.k > k0:
            self.walk = self._walk()
        self.walk.skip(k0 - self.walk.k)
        steps = [self.walk.next() for _ in range(CHUNK_FRAMES)]
        return self._frames(k0, j, _trajectories(steps))

    def _frames(self, k0: int, j: int, traj: Trajectories) -> list[Frame]:
        """Chunk ``j``'s frames from the people's paths over it."""
        return _chunk(self.config, self.appearance, k0, j, traj, self.cameras)


def stream(config: WorldConfig) -> ScenarioStream:
    """The world as a :class:`~sim_cluster.scenarios.data.ScenarioStream` (frames on demand)."""
    cams = config.cameras
    believed = list(cams)
    if config.calibration is not None:  # what the user believes (calibration module)
        believed = [believed_camera(cam, E) for cam, E in zip(cams, config.calibration.errors(cams))]
    return ScenarioStream(name=config.name, cameras=believed, frames=config.frames, fps=config.fps,
                          units_per_metre=1.0, chunk=WorldStream(config),
                          chunk_frames=CHUNK_FRAMES, focus=lambda c: WorldStream(config, c),
                          area=tuple(float(v) for v in config.area), seed=int(config.seed))


def generate(config: WorldConfig) -> ScenarioData:
    """Simulate the world and materialise detections and ground truth (deterministic)."""
    return stream(config).materialise()


def _chunk(config: WorldConfig, appearance: AppearanceModel, k0: int, j: int,
           traj: Trajectories, only: list[int] | None = None) -> list[Frame]:
    """Frames ``k0 .. k0 + F - 1`` (chunk ``j``) of the world, the people's paths ``traj``;
    detections and image ground truth of cameras ``only`` (default all). The frames' world
    truth (``ids``, ``xy``) is the people these cameras see: a camera process projects no other
    camera's view (its detections do not depend on them)."""
    seed = int(config.seed)
    F, N = traj.xy.shape[:2]
    present = traj.present
    cams = config.cameras
    C = len(cams)
    thr = max(config.min_visible, 1e-12)

    # Project everybody in every camera at once: boxes, in-image fraction, depth (C, F, N, ...).
    # A bumped camera is a moved true camera from the bump's frame on (calibration module).
    kk, ii = np.nonzero(present)
    boxes = np.full((C, F, N, 4), np.nan)
    inimg = np.zeros((C, F, N))
    depth = np.full((C, F, N), np.inf)
    bump = config.calibration.bump if config.calibration is not None else None
    for c, cam in enumerate(cams):
        if only is not None and c not in only:
            continue  # a focused chunk: nothing of the other cameras (world truth: these see)
        views = [(cam, None)]
        if bump is not None and bump.camera == c and bump.frame < k0 + F:
            moved = moved_camera(cam, config.calibration.bump_map(cams))
            views = [(cam, kk + k0 < bump.frame), (moved, kk + k0 >= bump.frame)]
        for view, sel in views:
            fk, fi = (kk, ii) if sel is None else (kk[sel], ii[sel])
            b, front = project_people(view, traj.xy[fk, fi], traj.wh[fi])
            fr = np.zeros(len(fk))
            fr[front] = in_image_fraction(b[front], view.image_size)
            boxes[c, fk, fi] = b
            inimg[c, fk, fi] = fr
            centre = view.center()
            if centre is not None:
                depth[c, fk, fi] = np.hypot(traj.xy[fk, fi, 0] - centre[0],
                                            traj.xy[fk, fi, 1] - centre[1])
            else:
                depth[c, fk, fi] = -(b[:, 1] + b[:, 3])  # lower foot row = nearer

    truth_mask = np.any(inimg >= thr, axis=0)  # (F, N)
    frames = blank_frames(traj, truth_mask, C)
    for c, cam in enumerate(cams):
        if only is not None and c not in only:
            continue
        # Candidates: in front and at least partly in the image, in frame order.
        ck, ci = np.nonzero(inimg[c] > 0)
        camera_frames(frames, c, cam, ck, ci, boxes[c, ck, ci], depth[c, ck, ci],
                      inimg[c, ck, ci], traj, config, appearance,
                      np.random.default_rng([seed, _TAG_DETECT, c, j]))
    return frames


def blank_frames(traj: Trajectories, truth_mask: np.ndarray, cameras: int) -> list[Frame]:
    """A chunk's frames with the world's ground truth (the people ``truth_mask (F, N)`` says
    some camera sees) and no camera's detections yet."""
    frames = []
    for k in range(len(truth_mask)):
        sel = np.flatnonzero(truth_mask[k])
        frames.append(Frame(detections=[[] for _ in range(cameras)],
                            detection_truth=[np.zeros(0, np.int64)] * cameras,
                            ids=traj.ids[sel], xy=traj.xy[k, sel], wh=traj.wh[sel],
                            boxes=[(np.zeros(0, np.int64), np.zeros((0, 4)))] * cameras))
    return frames


def camera_frames(frames: list[Frame], c: int, cam: Camera, ck: np.ndarray, ci: np.ndarray,
                  cb: np.ndarray, depth: np.ndarray, inimg: np.ndarray, traj: Trajectories,
                  config: WorldConfig, appearance: AppearanceModel,
                  rng: np.random.Generator) -> None:
    """Camera ``c``'s image ground truth and detections over a chunk, written into ``frames``:
    from its candidates (frame ``ck``, person ``ci``, in frame order; box ``cb``, depth, the
    fraction of the box in the image), occlusion among them per frame, then the detector."""
    F = len(frames)
    thr = max(config.min_visible, 1e-12)
    counts = np.bincount(ck, minlength=F)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(ck)) - starts[ck]
    width = int(counts.max()) if len(counts) else 0
    packed_b = np.full((F, width, 4), np.nan)
    packed_d = np.full((F, width), np.inf)
    packed_b[ck, slot] = cb
    packed_d[ck, slot] = depth
    vis = visible_fractions_batch(packed_b, packed_d, cam.image_size)[ck, slot]
    gt = inimg * vis >= thr
    gk, gids, gboxes = ck[gt], traj.ids[ci[gt]], cb[gt]
    edges = np.searchsorted(gk, np.arange(F + 1))
    per_frame = detect_frames(cam, ck, traj.ids[ci], cb, vis, F, config.detector, appearance, rng)
    for k, (dets, ids) in enumerate(per_frame):
        f = frames[k]
        f.boxes[c] = (gids[edges[k]:edges[k + 1]], gboxes[edges[k]:edges[k + 1]])
        f.detections[c] = dets
        f.detection_truth[c] = ids
