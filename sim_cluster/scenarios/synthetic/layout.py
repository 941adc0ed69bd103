"""Generated camera layouts for scale experiments: a corridor or a grid of N cameras, with the
same density of people per camera at every N and people who walk across many cameras' views.

A scenario with a ``[layout]`` table (presets ``corridor`` and ``grid``; the names
``corridor-<N>`` and ``grid-<N>`` pick the camera count) has no ``[area]`` or ``[[cameras]]``:

**Cameras.** The ground is a lattice of ``rows x cols`` square cells of ``cell_m`` metres
(a corridor is one row: ``cell_m`` wide, ``N * cell_m`` long; a grid is ``rows`` rows of
``cameras / rows``, ``rows`` by default the integer square root of N: 16 is 4 x 4, 15 is 3 x 5). Camera ``r * cols + c`` watches cell ``(r, c)``: it stands ``back_m``
south of the cell's south edge at ``height_m``, looks north at the cell's centre with a
horizontal field of view of ``fov_deg``, and its view reaches into the cells east, west and
north of its own (about 1.4 cells wide, 1.8 cells deep with the defaults), so every camera's
view overlaps the views of its lattice neighbours (``tests/test_layout.py`` measures it). The
scenario's neighbour graph (``ScenarioStream.neighbours``, topology ``layout``) is the lattice:
a chain for a corridor, 4-neighbours for a grid.

**People** (:class:`LayoutWalk`). About ``people_per_camera * N`` people are in the world at
once (the issue's figure: 25 people per 4 cameras). A person appears at a uniformly random
place (a door), walks a trip of ``trip_m`` metres made of legs of ``leg_m`` metres each, in a
direction that wanders ``heading_jitter_deg`` either way of their travel direction (along the
corridor in a corridor, any direction in a grid) and turns back at the layout's walls, and at
the end of the trip leaves (through a door) where they are; a replacement appears after an
exponential gap of mean ``entry_gap_s``. Uniform entries and exits keep the density uniform
along the layout; trips of up to 120 m cross up to 15 cameras. Turning, repulsion, the
no-overlap rule and pauses are those of :class:`~sim_cluster.scenarios.synthetic.world.PeopleWalk`,
with neighbours found in a window of the people sorted by x (the cost of a frame grows with
the people, not with their square).

**Frames** (:class:`LayoutWorldStream`) are made like the plain world's, a chunk at a time,
with the same detector, appearance, occlusion and ground-truth rules and random streams, but
each camera projects only the people inside its view's ground bounds (its footprint and the
ground between it and the camera, plus a margin): the people a camera cannot see are never
projected, so a chunk costs ``O(people)``, not ``O(cameras x people)``, and a 256-camera
scenario opens in a fraction of a second. The bounds hold every person whose box reaches into
the image (a test compares with projecting everybody into every camera).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from edge_node.geometry import Camera
from sim_cluster.network.topology import Adjacency, lattice
from sim_cluster.scenarios.data import CHUNK_FRAMES, Frame, ScenarioStream
from sim_cluster.scenarios.synthetic.appearance import AppearanceModel
from sim_cluster.scenarios.synthetic.detector_model import in_image_fraction
from sim_cluster.scenarios.synthetic.pose import camera_from_pose, look_at_angles
from sim_cluster.scenarios.synthetic.world import (_SIDESTEPS, _TAG_DETECT, _TAG_PEOPLE,
                                                   PeopleParams,
                                                   PeopleWalk, Trajectories, WorldConfig,
                                                   WorldError, WorldStream, _Person,
                                                   blank_frames, camera_frames, project_people)

KINDS = ("corridor", "grid")
_VIEW_MARGIN_M = 1.5  # beyond a view's ground bounds: half a person's width and their lean
_NEIGHBOUR_WINDOW_M = 1.0  # people closer than this in x are candidates for repulsion / touch


class LayoutError(WorldError):
    """A layout that cannot be built (a grid whose camera count is not rows x cols, ...)."""


@dataclass(frozen=True)
class LayoutParams:
    """A generated layout (see the module docstring); lengths in metres."""

    kind: str = "corridor"
    cameras: int = 16
    rows: int | None = None  # grid: rows of cameras (default: isqrt(cameras), which must divide it)
    cell_m: float = 8.0
    height_m: float = 6.0
    back_m: float = 1.0
    fov_deg: float = 70.0
    image_size: tuple[int, int] = (360, 288)
    people_per_camera: float = 6.25
    trip_m: tuple[float, float] = (8.0, 120.0)
    leg_m: tuple[float, float] = (4.0, 16.0)
    heading_jitter_deg: float = 45.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise LayoutError(f"layout kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.cameras < 1:
            raise LayoutError(f"a layout needs at least one camera, got {self.cameras}")
        rows, cols = self.shape
        if rows * cols != self.cameras:
            raise LayoutError(f"a grid of {self.cameras} cameras needs rows that divide it (by "
                              f"default its integer square root), got rows = {rows}")
        if min(self.cell_m, self.height_m, self.people_per_camera + 1e-12) <= 0:
            raise LayoutError("cell_m, height_m must be > 0 and people_per_camera >= 0")

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the lattice."""
        if self.kind == "corridor":
            return 1, self.cameras
        rows = self.rows if self.rows is not None else math.isqrt(self.cameras)
        return rows, max(1, self.cameras // max(rows, 1))

    @property
    def area(self) -> tuple[float, float, float, float]:
        rows, cols = self.shape
        return (0.0, cols * self.cell_m, 0.0, rows * self.cell_m)

    @property
    def people(self) -> int:
        """People in the world at once: ``people_per_camera`` per camera."""
        return int(round(self.people_per_camera * self.cameras))


def layout_cameras(p: LayoutParams, fps: float = 25.0) -> list[Camera]:
    """The layout's cameras, ``r * cols + c`` watching cell ``(r, c)`` (module docstring)."""
    rows, cols = p.shape
    s = p.cell_m
    cams = []
    for r in range(rows):
        for c in range(cols):
            x = (c + 0.5) * s
            pos = np.array([x, r * s - p.back_m, p.height_m])
            yaw, pitch = look_at_angles(pos, np.array([x, (r + 0.5) * s, 0.0]))
            cam = camera_from_pose(r * cols + c, p.image_size, pos, yaw, pitch,
                                   fov_deg=p.fov_deg, fps=fps)
            if len(cam.footprint()) < 18:  # every image border point must reach the ground
                raise LayoutError(f"camera {cam.id} sees the horizon: raise height_m or lower "
                                  f"fov_deg (pitch {pitch:.0f} deg)")
            cams.append(cam)
    return cams


def layout_neighbours(p: LayoutParams) -> Adjacency:
    """The layout's neighbour graph: the lattice of its cameras."""
    return lattice(*p.shape)


def view_bounds(camera: Camera, margin: float = _VIEW_MARGIN_M) -> tuple[float, float, float, float]:
    """``(xmin, xmax, ymin, ymax)`` on the ground holding every person whose box can reach into
    ``camera``'s image: its footprint and the ground between it and the camera, plus ``margin``
    (people are at most as tall as the camera is high)."""
    pts = np.vstack([camera.footprint(), camera.center()[None, :2]])
    lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
    return (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))


# -- people ------------------------------------------------------------------------------------


class _Walker(_Person):
    __slots__ = ("direction", "trip_left")


class LayoutWalk(PeopleWalk):
    """:class:`~sim_cluster.scenarios.synthetic.world.PeopleWalk` on a layout: people appear
    anywhere, walk a trip of legs along their travel direction, and leave where it ends
    (module docstring). Same interface and the same guarantees: memory holds the people in
    the world, frame ``k`` depends only on the generator's seed and ``k``."""

    def __init__(self, layout: LayoutParams, fps: float, params: PeopleParams,
                 rng: np.random.Generator):
        self.layout = layout
        self.area, self.fps, self.params, self.rng = layout.area, fps, params, rng
        self.k = 0
        self.born = 0
        self.active: list[_Person] = []
        self._births: list[tuple[int, int]] = []
        self._seq = 0
        self._max_turn = math.radians(params.turn_rate_dps) / fps
        placed = np.zeros((0, 2))
        for _ in range(params.initial_count):
            for _try in range(20):  # initial places without overlaps, when there is room
                pos = self._entry_point()
                if not len(placed) or np.min(np.hypot(*(placed - pos).T)) > 0.7:
                    break
            placed = np.vstack([placed, pos])
            self.active.append(self._new_person(0, pos, inside=True))
        for _ in range(max(0, params.concurrent - params.initial_count)):
            self._schedule(0)

    def _entry_point(self) -> np.ndarray:
        """A uniformly random place inside the layout (a door)."""
        xmin, xmax, ymin, ymax = self.area
        m = min(self.params.waypoint_margin_m, 0.45 * (ymax - ymin), 0.45 * (xmax - xmin))
        return np.array([self.rng.uniform(xmin + m, xmax - m), self.rng.uniform(ymin + m, ymax - m)])

    def _new_person(self, k: int, pos: np.ndarray, inside: bool) -> _Person:
        params, rng, lay = self.params, self.rng, self.layout
        speed = rng.uniform(*params.speed_mps)
        wh = np.array([rng.uniform(*params.width_m), rng.uniform(*params.height_m)])
        trip = rng.uniform(*lay.trip_m)
        if inside:  # already walking at the start: an unknown part of the trip is over
            trip *= rng.uniform(0.1, 1.0)
        if lay.shape[0] == 1:  # a corridor: along it, either way
            direction = (0.0 if rng.random() < 0.5 else math.pi)
        else:
            direction = rng.uniform(-math.pi, math.pi)
        arrive_r = max(0.6, 2.0 * speed / math.radians(params.turn_rate_dps))
        self.born += 1
        p = _Walker(self.born, pos, 0.0, speed, wh, k, -1, arrive_r)
        p.direction, p.trip_left = direction, trip
        p.target = self._leg(p)
        d = p.target - pos
        p.heading = math.atan2(d[1], d[0])
        return p

    def _leg(self, p: _Walker) -> np.ndarray:
        """The next waypoint: ``leg_m`` along the travel direction, give or take the jitter;
        a wall turns the travel direction back (mirrored)."""
        rng, lay = self.rng, self.layout
        jitter = math.radians(lay.heading_jitter_deg)
        phi = p.direction + rng.uniform(-jitter, jitter)
        length = rng.uniform(*lay.leg_m)
        t = p.pos + length * np.array([math.cos(phi), math.sin(phi)])
        xmin, xmax, ymin, ymax = self.area
        m = self.params.waypoint_margin_m
        lo = np.array([xmin + min(m, 0.45 * (xmax - xmin)), ymin + min(m, 0.45 * (ymax - ymin))])
        hi = np.array([xmax - (lo[0] - xmin), ymax - (lo[1] - ymin)])
        for axis in (0, 1):
            if t[axis] < lo[axis] or t[axis] > hi[axis]:
                edge = lo[axis] if t[axis] < lo[axis] else hi[axis]
                t[axis] = 2 * edge - t[axis]
                p.direction = (math.pi - p.direction) if axis == 0 else -p.direction
        return np.clip(t, lo, hi)

    def _step(self, k: int) -> None:
        """Frame ``k`` -> ``k + 1`` (PeopleWalk's rules, neighbours from an x-sorted window)."""
        params, rng, fps = self.params, self.rng, self.fps
        active = self.active
        dt = 1.0 / fps
        max_turn = self._max_turn
        r_rep = params.personal_space_m
        P = np.array([p.pos for p in active]).reshape(-1, 2)  # start-of-frame places
        cur = P.copy()  # live places: the no-overlap rule
        radius = np.array([p.wh[0] / 2.0 for p in active])
        order = np.argsort(P[:, 0], kind="stable")
        xs = P[order, 0]
        window = max(r_rep, _NEIGHBOUR_WINDOW_M)
        lo_i = np.searchsorted(xs, P[:, 0] - window, side="left")
        hi_i = np.searchsorted(xs, P[:, 0] + window, side="right")
        survivors: list[_Person] = []
        for idx, p in enumerate(active):
            if p.trip_left <= 0:
                continue  # out through a door
            nb = order[lo_i[idx]:hi_i[idx]]
            nb = nb[nb != idx]
            rep = np.zeros(2)
            if len(nb) and r_rep > 0:
                diff = P[idx] - P[nb]
                dist = np.hypot(diff[:, 0], diff[:, 1])
                wgt = np.clip((r_rep - dist) / r_rep, 0.0, None)
                unit = diff / np.maximum(dist, 1e-9)[:, None]
                side = np.stack([unit[:, 1], -unit[:, 0]], axis=1)
                rep = np.sum(wgt[:, None] * (unit + 0.5 * side), axis=0) * 2.0
            to_t = p.target - p.pos
            dist_t = math.hypot(to_t[0], to_t[1])
            if dist_t < p.arrive_r:
                if rng.random() < params.pause_probability:
                    p.pause_until = k + int(round(rng.uniform(*params.pause_s) * fps))
                p.target = self._leg(p)
                to_t = p.target - p.pos
                dist_t = math.hypot(to_t[0], to_t[1])
            desired = to_t / max(dist_t, 1e-9) + rep
            want = math.atan2(desired[1], desired[0])
            dh = (want - p.heading + math.pi) % (2 * math.pi) - math.pi
            p.heading += max(-max_turn, min(max_turn, dh))
            if k >= p.pause_until:
                step = p.speed * dt
                d_old = np.hypot(cur[nb, 0] - p.pos[0], cur[nb, 1] - p.pos[1])
                moved = False
                for turn in _SIDESTEPS:
                    h = p.heading + turn
                    new = p.pos + step * np.array([math.cos(h), math.sin(h)])
                    d_new = np.hypot(cur[nb, 0] - new[0], cur[nb, 1] - new[1])
                    if not np.any((d_new < radius[nb] + radius[idx]) & (d_new < d_old)):
                        p.pos, moved = new, True
                        cur[idx] = new
                        p.trip_left -= step
                        break
                p.stuck = 0 if moved else p.stuck + 1
                if p.stuck > fps:
                    p.stuck = 0
                    p.target = self._leg(p)
            survivors.append(p)
        for _ in range(len(active) - len(survivors)):
            self._schedule(k + 1)
        self.active = survivors


# -- frames ------------------------------------------------------------------------------------


class LayoutWorldStream(WorldStream):
    """A layout world's frames, a chunk at a time (module docstring): the people of a
    :class:`LayoutWalk`, each camera projecting only the people inside its view's bounds."""

    def __init__(self, config: WorldConfig, layout: LayoutParams, cameras: list[int] | None = None):
        self.layout = layout
        self.bounds = [view_bounds(c) for c in config.cameras]
        super().__init__(config, cameras)

    def _walk(self) -> PeopleWalk:
        c = self.config
        return LayoutWalk(self.layout, c.fps, c.people,
                          np.random.default_rng([int(c.seed), _TAG_PEOPLE]))

    def _frames(self, k0: int, j: int, traj: Trajectories) -> list[Frame]:
        return regional_chunk(self.config, self.bounds, self.appearance, k0, j, traj, self.cameras)


def layout_stream(config: WorldConfig, layout: LayoutParams) -> ScenarioStream:
    """A layout world as a :class:`~sim_cluster.scenarios.data.ScenarioStream`, its neighbour
    graph the layout's lattice."""
    if config.calibration is not None:
        raise LayoutError("a layout scenario has no [calibration_error] (its cameras are exact)")
    return ScenarioStream(name=config.name, cameras=list(config.cameras), frames=config.frames,
                          fps=config.fps, units_per_metre=1.0,
                          chunk=LayoutWorldStream(config, layout), chunk_frames=CHUNK_FRAMES,
                          focus=lambda c: LayoutWorldStream(config, layout, c),
                          area=tuple(float(v) for v in config.area), seed=int(config.seed),
                          neighbours=layout_neighbours(layout))


def regional_chunk(config: WorldConfig, bounds: list[tuple[float, float, float, float]],
                   appearance: AppearanceModel, k0: int, j: int, traj: Trajectories,
                   only: list[int] | None = None) -> list[Frame]:
    """Frames ``k0 .. k0 + F - 1`` (chunk ``j``) of a world whose camera ``c`` can only see
    people inside ``bounds[c]``: ``world._chunk``'s frames (same rules, same random streams),
    projecting each camera's candidates only. No calibration errors (exact cameras). With
    ``only``, as ``world._chunk``: the world truth is the people those cameras see."""
    seed = int(config.seed)
    F, N = traj.xy.shape[:2]
    cams = config.cameras
    C = len(cams)
    thr = max(config.min_visible, 1e-12)
    kk, ii = np.nonzero(traj.present)  # row-major: frame, then person (world.camera_frames' order)
    xy = traj.xy[kk, ii]
    truth_mask = np.zeros((F, N), bool)
    seen = []  # per camera: (frame, person, box, in-image fraction, depth) of its candidates
    for c, cam in enumerate(cams):
        if only is not None and c not in only:
            seen.append(None)  # a focused chunk: the other cameras' views are not projected
            continue
        x0, x1, y0, y1 = bounds[c]
        sel = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
        fk, fi = kk[sel], ii[sel]
        b, front = project_people(cam, traj.xy[fk, fi], traj.wh[fi])
        fr = np.zeros(len(fk))
        fr[front] = in_image_fraction(b[front], cam.image_size)
        centre = cam.center()
        depth = np.hypot(traj.xy[fk, fi, 0] - centre[0], traj.xy[fk, fi, 1] - centre[1])
        truth_mask[fk[fr >= thr], fi[fr >= thr]] = True
        keep = fr > 0
        seen.append((fk[keep], fi[keep], b[keep], fr[keep], depth[keep]))
    frames = blank_frames(traj, truth_mask, C)
    for c, cam in enumerate(cams):
        if only is not None and c not in only:
            continue
        ck, ci, cb, fr, depth = seen[c]
        camera_frames(frames, c, cam, ck, ci, cb, depth, fr, traj, config, appearance,
                      np.random.default_rng([seed, _TAG_DETECT, c, j]))
    return frames
