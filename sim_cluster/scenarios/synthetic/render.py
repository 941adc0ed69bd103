"""Rendered synthetic video: each camera's frames of a synthetic scenario.

The people are the scenario's own (``world.simulate_people`` with the same seed stream as
``world.generate``), so tracks from rendered frames are evaluated
against the scenario's ground truth. Per camera:

* **Background**, static: a paved ground (tiles 0.5 m, per-tile brightness, grout lines, a
  low-frequency colour wash; grass beyond the walkable area) warped onto the image through the
  camera's ground homography, and a wall with windows where the image sees no ground. Every
  frame adds Gaussian sensor noise (``noise`` grey levels).
* **People**, upright figures at their projected size: legs, torso, arms and head are 3-D parts
  of the person's cylinder (height ``h``, width ``w``) projected through the camera's ``P``, so a
  figure is as tall and as wide in the image as the cylinder box of the detections; legs and arms
  swing with the distance walked. Each identity has its own colours (shirt, trousers, skin, hair)
  and a shirt pattern (plain, stripes, or two-tone), the same in every camera, so a
  colour-histogram re-id can tell people apart.
* **Occlusion** by painter's order: far to near by horizontal distance from the camera centre,
  the world's own depth order, so whoever hides whom in the detections' visibility model hides
  them in the image.

``render_scenario`` writes ``c<i>.avi`` (MJPG, plays anywhere, written headless) or ``c<i>/`` PNG
folders, the empty scene for MOG2 (``background_c<i>.avi``: two seconds of it through the same
codec, so the model learns the noise and the JPEG artefacts; ``background_c<i>.png`` for PNG
folders) and ``render.json``.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge_node.geometry import Camera
from protocol.errors import DmttError
from sim_cluster.scenarios.files import read_scenario_toml, resolve_scenario_path, scenario_table
from sim_cluster.scenarios.synthetic.schema import parse_synthetic
from sim_cluster.scenarios.synthetic.world import (_TAG_PEOPLE, Trajectories, WorldConfig,
                                                   simulate_people)

_TAG_RENDER = 7
STRIDE_M = 1.4  # distance walked per full gait cycle
SWING_DEG = 24.0  # leg swing amplitude
TEX_PX_PER_M = 40.0


class RenderError(DmttError, ValueError):
    """A scenario or camera that cannot be rendered."""


@dataclass(frozen=True)
class Look:
    shirt: tuple[int, int, int]  # BGR
    shirt2: tuple[int, int, int]  # stripes / two-tone colour
    pattern: str  # "plain" | "stripes" | "twotone"
    trousers: tuple[int, int, int]
    skin: tuple[int, int, int]
    hair: tuple[int, int, int]
    shoes: tuple[int, int, int]


def _hsv_bgr(h: float, s: float, v: float) -> tuple[int, int, int]:
    """HSV (h in [0, 1)) to a BGR uint8 triple."""
    i = int(h * 6.0) % 6
    f = h * 6.0 - math.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    r, g, b = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]
    return int(round(255 * b)), int(round(255 * g)), int(round(255 * r))


def person_look(seed: int, pid: int) -> Look:
    """Deterministic per-identity colours and pattern. Shirt and trousers hues step through the
    colour circle by the golden ratio with the person id (people who are in the scene together,
    whose ids are close, get well separated hues), with a per-scenario offset; saturation,
    brightness, skin, hair and the shirt pattern are drawn per person."""
    rng = np.random.default_rng([int(seed), _TAG_RENDER, int(pid)])
    off = np.random.default_rng([int(seed), _TAG_RENDER]).uniform(size=2)
    golden = 0.6180339887
    h1 = (off[0] + pid * golden) % 1.0
    shirt = _hsv_bgr(h1, rng.uniform(0.6, 0.95), rng.uniform(0.55, 0.95))
    h2 = (h1 + rng.uniform(0.3, 0.7)) % 1.0
    shirt2 = _hsv_bgr(h2, rng.uniform(0.3, 0.9), rng.uniform(0.5, 1.0))
    pattern = str(rng.choice(["plain", "plain", "stripes", "twotone"]))
    ht = (off[1] + pid * golden * golden) % 1.0
    trousers = _hsv_bgr(ht, rng.uniform(0.4, 0.85), rng.uniform(0.3, 0.8))
    skin = _hsv_bgr(rng.uniform(0.03, 0.09), rng.uniform(0.25, 0.6), rng.uniform(0.35, 0.95))
    hair = _hsv_bgr(rng.uniform(0.02, 0.12), rng.uniform(0.2, 0.7), rng.uniform(0.05, 0.6))
    shoes = _hsv_bgr(rng.uniform(), rng.uniform(0.0, 0.4), rng.uniform(0.05, 0.35))
    return Look(shirt, shirt2, pattern, trousers, skin, hair, shoes)


def _cv2():
    try:
        import cv2  # noqa: PLC0415 - OpenCV is optional (the vision extra): only to render
    except ImportError as e:  # pragma: no cover
        raise RenderError(f"rendering needs OpenCV: pip install 'dmtt[vision]' ({e})") from None
    return cv2


# -- background -----------------------------------------------------------------------------------
def ground_texture(area: tuple[float, float, float, float], margin: float, seed: int):
    """A paved-ground texture covering ``area`` +- ``margin`` metres and the ground->texture
    homography (texture pixels per metre ``TEX_PX_PER_M``)."""
    cv2 = _cv2()
    rng = np.random.default_rng([int(seed), _TAG_RENDER, 0])
    xmin, xmax, ymin, ymax = area
    x0, y0 = xmin - margin, ymin - margin
    Wm, Hm = (xmax - xmin) + 2 * margin, (ymax - ymin) + 2 * margin
    s = TEX_PX_PER_M
    W, H = int(math.ceil(Wm * s)), int(math.ceil(Hm * s))
    xs = (np.arange(W) + 0.5) / s + x0
    ys = (np.arange(H) + 0.5) / s + y0
    X, Y = np.meshgrid(xs, ys)
    tile = 0.5
    ti, tj = np.floor(X / tile).astype(int), np.floor(Y / tile).astype(int)
    tile_rand = rng.uniform(-18, 18, (4096,))
    shade = tile_rand[(ti * 73856093 ^ tj * 19349663) % 4096]
    base = np.array([150.0, 160.0, 168.0])  # BGR, light warm grey stone
    img = np.empty((H, W, 3), np.float32)
    img[:] = base
    img += shade[..., None]
    # grout lines
    fx, fy = X / tile - ti, Y / tile - tj
    grout = (fx < 0.04) | (fy < 0.04)
    img[grout] *= 0.72
    # a low-frequency colour wash (weathering)
    low = rng.normal(0, 1, (max(2, H // 40), max(2, W // 40), 3)).astype(np.float32)
    low = cv2.resize(low, (W, H), interpolation=cv2.INTER_CUBIC)
    img += 4.0 * low
    # grass outside the walkable area
    outside = (X < xmin - 0.6) | (X > xmax + 0.6) | (Y < ymin - 0.6) | (Y > ymax + 0.6)
    grass = np.empty_like(img)
    grass[:] = (60.0, 120.0, 85.0)
    grass += rng.normal(0, 14, (H, W, 1)).astype(np.float32) * np.array([0.5, 1.0, 0.6], np.float32)
    img[outside] = grass[outside]
    img += rng.normal(0, 5, (H, W, 1)).astype(np.float32)  # fine grain
    tex = np.clip(img, 0, 255).astype(np.uint8)
    # ground (x, y, 1) -> texture pixel
    T = np.array([[s, 0.0, -x0 * s - 0.5], [0.0, s, -y0 * s - 0.5], [0.0, 0.0, 1.0]])
    return tex, T


def wall_image(size: tuple[int, int], seed: int, cam_id: int) -> np.ndarray:
    """A facade with windows: what the camera sees above and beyond the ground."""
    W, H = size
    rng = np.random.default_rng([int(seed), _TAG_RENDER, 1, int(cam_id)])
    col = np.array(_hsv_bgr(rng.uniform(0.05, 0.12), rng.uniform(0.15, 0.35),
                            rng.uniform(0.55, 0.8)), np.float32)
    img = np.empty((H, W, 3), np.float32)
    img[:] = col
    img *= np.linspace(0.85, 1.05, H, dtype=np.float32)[:, None, None]
    cw, chh = int(rng.integers(28, 44)), int(rng.integers(30, 46))
    for y in range(int(rng.integers(4, 12)), H, chh):
        for x in range(int(rng.integers(2, 20)), W, cw):
            if rng.uniform() < 0.8:
                wcol = np.array(_hsv_bgr(0.58, rng.uniform(0.1, 0.4), rng.uniform(0.2, 0.6)),
                                np.float32)
                img[y:y + int(chh * 0.55), x:x + int(cw * 0.55)] = wcol
    img += rng.normal(0, 4, (H, W, 1)).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def render_background(camera: Camera, area: tuple[float, float, float, float], seed: int,
                      texture=None) -> np.ndarray:
    """The empty scene seen by ``camera``: the ground texture warped through its homography over
    a wall."""
    cv2 = _cv2()
    W, H = camera.image_size
    tex, T = texture if texture is not None else ground_texture(area, 6.0, seed)
    # texture pixel -> image pixel: image <- ground (G_inv, with pixel scale) <- texture (T^-1)
    S = np.diag([1.0 / camera.pixel_scale, 1.0 / camera.pixel_scale, 1.0])
    M = S @ camera.G_inv @ np.linalg.inv(T)
    ground = cv2.warpPerspective(tex, M, (W, H), flags=cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
    valid = cv2.warpPerspective(np.full(tex.shape[:2], 255, np.uint8), M, (W, H),
                                flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                                borderValue=0)
    # Keep only ground in front of the camera (the homography also maps the sky "behind" it).
    uu, vv = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    g = camera.to_ground(np.stack([uu.ravel(), vv.ravel()], axis=1))
    front = camera.in_front(g).reshape(H, W) & np.all(np.isfinite(g), axis=1).reshape(H, W)
    mask = (valid > 0) & front
    out = wall_image((W, H), seed, camera.id)
    out[mask] = ground[mask]
    return out


# -- people -----------------------------------------------------------------------------------------
class _Projector:
    """Pixel positions and pixel sizes of 3-D points for one camera (needs ``P``)."""

    def __init__(self, camera: Camera):
        if camera.P is None:
            raise RenderError(f"camera {camera.id}: rendering needs a projection matrix P "
                              "(a camera given by pose, not by a homography alone)")
        self.P = camera.P
        self.C = camera.center()

    def uv(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        X = np.atleast_2d(X)
        q = np.hstack([X, np.ones((len(X), 1))]) @ self.P.T
        return q[:, :2] / q[:, 2:3], q[:, 2]

    def radius_px(self, X: np.ndarray, r: float) -> np.ndarray:
        """Pixel length of a horizontal segment of length ``r`` at ``X``, perpendicular to the
        line of sight."""
        X = np.atleast_2d(X)
        d = X[:, :2] - self.C[:2]
        n = np.hypot(d[:, 0], d[:, 1])[:, None]
        perp = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.maximum(n, 1e-9)
        Y = X.copy()
        Y[:, :2] += r * perp
        a, _ = self.uv(X)
        b, _ = self.uv(Y)
        return np.hypot(*(b - a).T)


def _fill(img, pts, color, cv2) -> None:
    cv2.fillConvexPoly(img, np.array(pts, np.int32), color, lineType=cv2.LINE_AA, shift=4)


def _quad(img, ua, ub, wa, wb, color, shade: bool, cv2) -> None:
    """A tapered band from pixel ``ua`` (half-width ``wa``) to ``ub`` (``wb``), darker at its
    sides (a lit cylinder). Coordinates in 1/16 px (``shift=4``)."""
    ax, ay, bx, by = float(ua[0]) * 16, float(ua[1]) * 16, float(ub[0]) * 16, float(ub[1]) * 16
    dx, dy = bx - ax, by - ay
    n = math.hypot(dx, dy)
    if n < 1e-3:
        return
    px, py = -dy / n, dx / n
    wa, wb = float(wa) * 16, float(wb) * 16

    def pt(x, y):
        return (int(round(x)), int(round(y)))

    _fill(img, [pt(ax - px * wa, ay - py * wa), pt(ax + px * wa, ay + py * wa),
                pt(bx + px * wb, by + py * wb), pt(bx - px * wb, by - py * wb)], color, cv2)
    if shade and max(wa, wb) > 24:
        dark = tuple(int(c * 0.72) for c in color)
        for s in (-1.0, 1.0):
            _fill(img, [pt(ax + s * px * wa, ay + s * py * wa),
                        pt(ax + s * px * wa * 0.55, ay + s * py * wa * 0.55),
                        pt(bx + s * px * wb * 0.55, by + s * py * wb * 0.55),
                        pt(bx + s * px * wb, by + s * py * wb)], dark, cv2)


def draw_person(img: np.ndarray, proj: _Projector, xy: np.ndarray, wh: np.ndarray,
                heading: float, phase: float, swing: float, look: Look, cv2) -> None:
    """One upright figure: the person's cylinder is ``(xy, w=wh[0], h=wh[1])``. Every part is a
    tapered 3-D segment (endpoints, radii in metres), projected in one batch."""
    w, h = float(wh[0]), float(wh[1])
    fwd = np.array([math.cos(heading), math.sin(heading), 0.0])
    side = np.array([-math.sin(heading), math.cos(heading), 0.0])
    base = np.array([xy[0], xy[1], 0.0])
    up = np.array([0.0, 0.0, 1.0])
    hip_h, sh_h = 0.49 * h, 0.81 * h
    head_r = 0.065 * h
    leg_r = 0.16 * w
    amp = math.radians(SWING_DEG) * swing
    C = proj.C[:2]
    legs, arms = [], []  # (depth, a, b, ra, rb, colour)
    for s, sign in ((-1.0, 1.0), (1.0, -1.0)):
        hip = base + up * hip_h + side * (s * 0.22 * w)
        ang = sign * amp * math.sin(phase)
        foot = hip + hip_h * (-math.cos(ang) * up + math.sin(ang) * fwd)
        foot[2] = max(foot[2], 0.0)
        ankle = foot + up * 0.06 * h
        dh = math.hypot(hip[0] - C[0], hip[1] - C[1])
        legs.append((dh, hip, ankle, leg_r, leg_r * 0.85, look.trousers))
        legs.append((dh - 1e-3, ankle, foot + fwd * 0.05, leg_r * 0.9, leg_r * 0.9, look.shoes))
        shoulder = base + up * (sh_h - 0.02 * h) + side * (s * 0.42 * w)
        aang = -ang * 0.8
        hand = shoulder + 0.36 * h * (-math.cos(aang) * up + math.sin(aang) * fwd)
        arms.append((math.hypot(shoulder[0] - C[0], shoulder[1] - C[1]), shoulder, hand,
                     0.09 * w, 0.075 * w, look.shirt))
    legs.sort(key=lambda p: -p[0])
    arms.sort(key=lambda p: -p[0])
    torso = []
    waist, chest = base + up * (hip_h - 0.02 * h), base + up * sh_h
    bands = 6 if look.pattern == "stripes" else (2 if look.pattern == "twotone" else 1)
    for i in range(bands):
        col = look.shirt
        if (look.pattern == "stripes" and i % 2 == 1) or (look.pattern == "twotone" and i == 1):
            col = look.shirt2
        torso.append((0.0, waist + (chest - waist) * (i / bands),
                      waist + (chest - waist) * ((i + 1) / bands),
                      (0.4 + 0.1 * i / bands) * w, (0.4 + 0.1 * (i + 1) / bands) * w, col))
    neck = [(0.0, base + up * sh_h, base + up * (h - 2 * head_r + 0.01 * h), 0.07 * w, 0.07 * w,
             look.skin)]
    prims = legs + torso + arms + neck  # painter's order within the figure
    hc = base + up * (h - head_r)
    pts = np.array([p[1] for p in prims] + [p[2] for p in prims] + [hc, base + up * h])
    uv, _ = proj.uv(pts)
    px = proj.radius_px(pts, 0.1) * 10.0  # pixels per metre across the line of sight
    n = len(prims)
    for j, (_, _, _, ra, rb, col) in enumerate(prims):
        _quad(img, uv[j], uv[n + j], px[j] * ra, px[n + j] * rb, col, j < n - 1, cv2)
    c, top = uv[2 * n], uv[2 * n + 1]
    rp = float(px[2 * n] * head_r)
    ry = max(abs(c[1] - top[1]), 0.5)
    if rp >= 0.5:
        center = (int(round(c[0] * 16)), int(round(c[1] * 16)))
        axes = (int(round(rp * 16)), int(round(ry * 16)))
        cv2.ellipse(img, center, axes, 0, 0, 360, look.skin, -1, cv2.LINE_AA, 4)
        cv2.ellipse(img, center, axes, 0, 180, 360, look.hair, -1, cv2.LINE_AA, 4)


@dataclass
class Renderer:
    """Renders the frames of every camera of one world (the scenario's people)."""

    cameras: list[Camera]
    area: tuple[float, float, float, float]
    trajectories: Trajectories
    seed: int = 0
    noise: float = 2.0  # sensor noise, grey levels (sigma)

    def __post_init__(self) -> None:
        self.cv2 = _cv2()
        self._proj = [_Projector(c) for c in self.cameras]
        self._bg: dict[int, np.ndarray] = {}
        self._noise_bank: dict[int, tuple[list, list]] = {}
        self._texture = None
        self.looks = {int(pid): person_look(self.seed, int(pid)) for pid in self.trajectories.ids}
        xy = self.trajectories.xy
        F, N = xy.shape[:2]
        step = np.zeros((F, N))
        heading = np.zeros((F, N))
        d = np.diff(xy, axis=0)
        dist = np.hypot(d[..., 0], d[..., 1])
        moving = np.isfinite(dist) & (dist > 1e-4)
        step[1:] = np.where(moving, dist, 0.0)
        ang = np.where(moving, np.arctan2(d[..., 1], d[..., 0]), np.nan)
        # heading: last movement direction (persist through pauses); swing fades when still
        h = np.zeros(N)
        swing = np.zeros((F, N))
        s = np.zeros(N)
        for k in range(F):
            if k > 0:
                a = ang[k - 1]
                h = np.where(np.isfinite(a), a, h)
                s = np.where(moving[k - 1], np.minimum(1.0, s + 0.25), np.maximum(0.0, s - 0.15))
            heading[k] = h
            swing[k] = s
        self.heading = heading
        self.swing = swing
        self.phase = np.cumsum(step, axis=0) / STRIDE_M * 2 * math.pi
        self._rng = {c.id: np.random.default_rng([self.seed, _TAG_RENDER, 2, c.id])
                     for c in self.cameras}

    def background(self, c: int) -> np.ndarray:
        if c not in self._bg:
            if self._texture is None:
                self._texture = ground_texture(self.area, 6.0, self.seed)
            self._bg[c] = render_background(self.cameras[c], self.area, self.seed, self._texture)
        return self._bg[c]

    def frame(self, c: int, k: int, noise: bool = True) -> np.ndarray:
        """Camera ``c``'s image of frame ``k`` (BGR uint8)."""
        cv2 = self.cv2
        img = self.background(c).copy()
        proj = self._proj[c]
        traj = self.trajectories
        xy = traj.xy[k]
        present = np.flatnonzero(np.isfinite(xy[:, 0]))
        if len(present):
            W, H = self.cameras[c].image_size
            order = []
            for i in present:
                foot = np.array([xy[i, 0], xy[i, 1], 0.0])
                top = foot + np.array([0.0, 0.0, traj.wh[i, 1]])
                (uvs, z) = proj.uv(np.stack([foot, top]))
                if np.any(z <= 0.05):
                    continue  # (partly) behind the camera
                r = float(proj.radius_px(foot[None], traj.wh[i, 0])[0])
                u0, u1 = uvs[:, 0].min() - r, uvs[:, 0].max() + r
                if u1 < 0 or u0 > W or uvs[:, 1].max() < 0 or uvs[:, 1].min() > H:
                    continue
                order.append((float(np.hypot(*(xy[i] - proj.C[:2]))), i))
            for _, i in sorted(order, reverse=True):  # far to near
                draw_person(img, proj, xy[i], traj.wh[i], float(self.heading[k, i]),
                            float(self.phase[k, i]), float(self.swing[k, i]),
                            self.looks[int(traj.ids[i])], cv2)
        if noise and self.noise > 0:
            pos, neg = self._noise(c, img.shape)
            j = int(self._rng[c].integers(len(pos)))
            img = cv2.subtract(cv2.add(img, pos[j]), neg[j])
        return img

    def empty_frame(self, c: int) -> np.ndarray:
        """The empty scene of camera ``c`` with fresh sensor noise (a clip of it primes MOG2)."""
        img = self.background(c)
        if self.noise <= 0:
            return img.copy()
        pos, neg = self._noise(c, img.shape)
        j = int(self._rng[c].integers(len(pos)))
        return self.cv2.subtract(self.cv2.add(img, pos[j]), neg[j])

    def _noise(self, c: int, shape) -> tuple[list, list]:
        """A bank of sensor-noise images for camera ``c`` (as saturating +/- uint8 parts); each
        frame draws one of them (drawing fresh noise per frame costs more than the figures)."""
        if c not in self._noise_bank:
            rng = np.random.default_rng([self.seed, _TAG_RENDER, 3, c])
            pos, neg = [], []
            for _ in range(24):
                n = np.round(rng.normal(0.0, self.noise, shape)).astype(np.int16)
                pos.append(np.clip(n, 0, 255).astype(np.uint8))
                neg.append(np.clip(-n, 0, 255).astype(np.uint8))
            self._noise_bank[c] = (pos, neg)
        return self._noise_bank[c]


def world_trajectories(config: WorldConfig) -> Trajectories:
    """The people of a synthetic world, exactly as ``world.generate`` moves them."""
    return simulate_people(config.area, config.fps, config.frames, config.people,
                           np.random.default_rng([int(config.seed), _TAG_PEOPLE]))


def load_world(scenario: str | Path, seed: int | None = None,
               frames: int | None = None) -> WorldConfig:
    """The :class:`WorldConfig` of a synthetic scenario preset or file."""
    path = resolve_scenario_path(scenario)
    raw = read_scenario_toml(path)
    kind = (raw.get("source") or {}).get("kind", "synthetic")
    if kind != "synthetic":
        raise RenderError(f"{path.name}: only synthetic scenarios can be rendered (kind {kind!r})")
    if seed is None:
        seed = scenario_table(raw, path.name).integer("seed", 0, lo=0)
    return parse_synthetic(raw, path, int(seed), frames)


def renderer_for(scenario: str | Path, seed: int | None = None, frames: int | None = None,
                 noise: float = 2.0) -> Renderer:
    cfg = load_world(scenario, seed, frames)
    return Renderer(list(cfg.cameras), cfg.area, world_trajectories(cfg), int(cfg.seed), noise)


def render_scenario(scenario: str | Path, out: str | Path, *, seed: int | None = None,
                    frames: int | None = None, cameras: list[int] | None = None,
                    fmt: str = "avi", noise: float = 2.0, progress=None) -> dict:
    """Render every camera (or ``cameras``) of a synthetic scenario into ``out``; returns (and
    writes as ``render.json``) what was written: per camera the video (or image folder) and the
    background image."""
    cv2 = _cv2()
    if fmt not in ("avi", "png"):
        raise RenderError(f"format must be 'avi' or 'png', got {fmt!r}")
    cfg = load_world(scenario, seed, frames)
    r = Renderer(list(cfg.cameras), cfg.area, world_trajectories(cfg), int(cfg.seed), noise)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cams = list(range(len(cfg.cameras))) if cameras is None else list(cameras)
    written = {"scenario": cfg.name, "seed": int(cfg.seed), "frames": cfg.frames, "fps": cfg.fps,
               "format": fmt, "cameras": {}}
    total = cfg.frames * len(cams)
    done = 0
    for c in cams:
        cam = cfg.cameras[c]
        W, H = cam.image_size
        if fmt == "avi":
            bg_path = out / f"background_c{c}.avi"
            vw = cv2.VideoWriter(str(bg_path), cv2.VideoWriter_fourcc(*"MJPG"), float(cfg.fps),
                                 (W, H))
            if not vw.isOpened():
                raise RenderError(f"OpenCV cannot write {bg_path} (MJPG)")
            try:
                for _ in range(int(round(2 * cfg.fps))):
                    vw.write(r.empty_frame(c))
            finally:
                vw.release()
            path = out / f"c{c}.avi"
            vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), float(cfg.fps), (W, H))
            if not vw.isOpened():
                raise RenderError(f"OpenCV cannot write {path} (MJPG)")
            try:
                for k in range(cfg.frames):
                    vw.write(r.frame(c, k))
                    done += 1
                    if progress:
                        progress(done, total)
            finally:
                vw.release()
        else:
            bg_path = out / f"background_c{c}.png"
            cv2.imwrite(str(bg_path), r.background(c))
            path = out / f"c{c}"
            path.mkdir(exist_ok=True)
            for k in range(cfg.frames):
                cv2.imwrite(str(path / f"{k:06d}.png"), r.frame(c, k))
                done += 1
                if progress:
                    progress(done, total)
        written["cameras"][str(c)] = {"frames": str(path), "background": str(bg_path),
                                      "image_size": [W, H]}
    (out / "render.json").write_text(json.dumps(written, indent=2))
    return written


# -- rendering once for a cluster (sim_cluster up --source video) ------------------------------
def ensure_rendered(scenario: str | Path, out: str | Path, seed: int | None, frames: int | None,
                    cameras: list[int] | None = None, progress=None) -> dict:
    """``render_scenario`` into ``out`` unless ``out/render.json`` already holds this scenario,
    seed and frame count (a re-run of a cluster reuses its videos). A ``render.json`` that
    cannot be read (missing, not UTF-8 JSON of these fields) renders again."""
    out = Path(out)
    cfg = load_world(scenario, seed, frames)
    try:
        done = json.loads((out / "render.json").read_text(encoding="utf-8"))
        same = (done.get("scenario") == cfg.name and done.get("seed") == int(cfg.seed)
                and done.get("frames") == cfg.frames and done.get("format") == "avi"
                and all(Path(v["frames"]).is_file() and Path(v["background"]).is_file()
                        for v in done["cameras"].values())
                and all(str(c) in done["cameras"] for c in (cameras or range(len(cfg.cameras)))))
        if same:
            return done
    except (OSError, ValueError, KeyError, TypeError, AttributeError):  # ValueError: bad bytes too
        pass
    return render_scenario(scenario, out, seed=seed, frames=frames, cameras=cameras,
                           progress=progress)
