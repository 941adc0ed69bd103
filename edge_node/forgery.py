"""What a faulty node does (``faults.FaultyNode``): the same in both shells, because the frame
driver (``edge_node/driver.py``) applies it to the node's detections before ``prepare`` and to
its message before the outbox.

The fault model (docs/deploy.md, "Threat model"): a faulty node sends any values the wire's
schema allows, certificate or not. The kinds are the harms a network meets in practice:

* ``hijack``: the states of the trackers it sends moved ``offset`` metres (a direction per id)
  and a sharp measurement (5 cm) claimed there, ``ell`` 0: a plausible but wrong peer;
* ``phantom``: ``count`` invented people walking straight at 1.2 m/s through its camera's view,
  under fresh ids, each with a sharp measurement;
* ``stale``: the message of ``lag`` frames ago re-sent as this frame's (a box whose frames lag);
* ``forged_merge``: merges announced of the trackers it sends into one another (ids stolen);
* ``bumped``: its camera's true pose moved ``offset`` metres and ``rotation`` degrees (knocked;
  not malicious): every detection lands elsewhere on the ground through the old calibration;
* ``hallucinate``: its detector reports ``count`` people who are not there, walking.

Deterministic from each rule's seed and the frame: same plan, same lies, in one process or many.
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from edge_node.core.types import Detection
from edge_node.faults import DETECTION_KINDS, FaultyNode
from edge_node.geometry import Camera
from protocol.messages import FrameMessage, Merge, TrackerInfo

SHARP_M = 0.05  # m: the standard deviation a forged measurement claims
PERSON_M = (0.5, 1.7)  # m: width and height of an invented person
WALK_M_S = 1.2  # m/s: how fast an invented person walks
COUNTER = 10**9  # invented ids' counters start here (fresh ids of the faulty node's camera)


def _sharp(z: np.ndarray, upm: float) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2's ``u, U`` of a measurement ``z = (x, y, w, h)`` claimed to ``SHARP_M``."""
    U = np.zeros((6, 6))
    U[:4, :4] = np.eye(4) / (SHARP_M * upm) ** 2
    u = U[:, :4] @ np.asarray(z, float)[:4]
    return u, U


class Walkers:
    """``count`` invented people walking straight through a camera's view; one who leaves it is
    replaced by a new one (a new id). Deterministic from ``seed``."""

    def __init__(self, camera: Camera, count: int, seed: int, upm: float, dt: float):
        self.camera, self.count, self.upm, self.dt = camera, count, upm, dt
        self.rng = np.random.default_rng([seed, 7919])
        self.people: list[tuple[int, np.ndarray, np.ndarray, int]] = []  # (n, p0, v, k0)
        self.n = 0

    def _new(self, k: int) -> tuple[int, np.ndarray, np.ndarray, int]:
        W, H = self.camera.image_size
        for _ in range(20):  # a ground point the camera sees, in its image's lower two thirds
            uv = np.array([[self.rng.uniform(0.1, 0.9) * W, self.rng.uniform(0.4, 0.95) * H]])
            p = self.camera.to_ground(uv)[0]
            if np.all(np.isfinite(p)):
                break
        a = self.rng.uniform(0.0, 2.0 * math.pi)
        v = WALK_M_S * self.upm * np.array([math.cos(a), math.sin(a)])
        self.n += 1
        return self.n - 1, p, v, k

    def _inside(self, p: np.ndarray) -> bool:
        uv = self.camera.to_image(p[None])[0]
        W, H = self.camera.image_size
        return bool(np.all(np.isfinite(uv)) and 0 <= uv[0] < W and 0 <= uv[1] < H)

    def at(self, k: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """The invented people at frame ``k``: ``(n, position, velocity)`` each."""
        while len(self.people) < self.count:
            self.people.append(self._new(k))
        out = []
        for i, (n, p0, v, k0) in enumerate(self.people):
            p = p0 + v * (k - k0) * self.dt
            if not self._inside(p):
                n, p0, v, k0 = self.people[i] = self._new(k)
                p = p0
            out.append((n, p, v))
        return out


class Forger:
    """A faulty node's lies (``rules``: its ``FaultyNode`` rules) on its ``camera``'s
    detections and on its messages; ``upm``, ``dt``: the node's ground units and frame time."""

    def __init__(self, rules: Sequence[FaultyNode], camera: Camera, upm: float, dt: float):
        self.rules = list(rules)
        self.camera, self.upm, self.dt = camera, upm, dt
        lag = max([r.lag for r in self.rules if r.kind == "stale"], default=0)
        self.history: deque[FrameMessage] = deque(maxlen=lag + 1)
        self.walkers = {id(r): Walkers(camera, r.count, r.seed, upm, dt) for r in self.rules
                        if r.kind in ("phantom", "hallucinate")}
        self.born: dict[int, int] = {}  # invented person -> frame first sent

    def __bool__(self) -> bool:
        return bool(self.rules)

    # -- what the camera detects ----------------------------------------------------------------
    def detections(self, k: int, dets: Sequence[Detection]) -> list[Detection]:
        out = list(dets)
        for r in self.rules:
            if r.kind not in DETECTION_KINDS or not r.active(k):
                continue
            if r.kind == "bumped":
                out = [self._bumped(r, d) for d in out]
            else:
                out += self._hallucinated(r, k, out)
        return out

    def _bumped(self, r: FaultyNode, d: Detection) -> Detection:
        """``d`` as the moved camera sees it through its old calibration: the ground point of
        its foot moved by the pose change (a rotation about the camera's view and a shift),
        drawn back at the size it has there."""
        cam = self.camera
        x, y, w, h = np.asarray(d.box, float)
        g = cam.to_ground(np.array([[x + w / 2.0, y + h]]))[0]
        W, H = cam.image_size
        c = cam.to_ground(np.array([[W / 2.0, 0.75 * H]]))[0]
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(c))):
            return d
        rng = np.random.default_rng([r.seed, 104729])
        a = rng.uniform(0.0, 2.0 * math.pi)
        t = r.offset * self.upm * np.array([math.cos(a), math.sin(a)])
        th = math.radians(r.rotation)
        Rm = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        g2 = c + Rm @ (g - c) + t
        uv, J = cam.image_and_jacobians(g2[None])
        (u, v), J = uv[0], J[0]
        J0 = cam.image_and_jacobians(g[None])[1][0]
        scale = float(np.linalg.norm(J0[:, 0]) / max(np.linalg.norm(J[:, 0]), 1e-12))
        if not (np.isfinite(u) and np.isfinite(v) and np.isfinite(scale)):
            return d
        return replace(d, box=np.array([u - w * scale / 2.0, v - h * scale, w * scale, h * scale]))

    def _hallucinated(self, r: FaultyNode, k: int, dets: list[Detection]) -> list[Detection]:
        """Boxes of the invented people the camera sees (their foot inside the image)."""
        dim = next((len(d.descriptor) for d in dets if d.descriptor is not None), None)
        out = []
        for n, p, _ in self.walkers[id(r)].at(k):
            uv, J = self.camera.image_and_jacobians(p[None])
            (u, v), J = uv[0], J[0]
            ppu = 1.0 / max(float(np.linalg.norm(J[:, 0])), 1e-12)
            w, h = (s * self.upm * ppu for s in PERSON_M)
            desc = None
            if dim:
                desc = np.random.default_rng([r.seed, n, 15485863]).normal(size=dim)
                desc /= np.linalg.norm(desc)
            out.append(Detection(np.array([u - w / 2.0, v - h, w, h]), desc, 0.9))
        return out

    # -- what the node sends --------------------------------------------------------------------
    def message(self, k: int, msg: FrameMessage) -> FrameMessage:
        self.history.append(msg)
        for r in self.rules:
            if r.kind in DETECTION_KINDS or not r.active(k):
                continue
            msg = getattr(self, "_" + r.kind)(r, k, msg)
        return msg

    def _hijack(self, r: FaultyNode, k: int, msg: FrameMessage) -> FrameMessage:
        out = []
        for t in msg.trackers:
            rng = np.random.default_rng([r.seed, t.id[0], t.id[1], 1299709])
            a = rng.uniform(0.0, 2.0 * math.pi)
            x = np.array(t.x_bar, float)
            x[:2] += r.offset * self.upm * np.array([math.cos(a), math.sin(a)])
            u, U = _sharp(x[:4], self.upm)
            out.append(replace(t, x_bar=x, u=u, U=U, ell=0))
        return replace(msg, trackers=tuple(out))

    def _phantom(self, r: FaultyNode, k: int, msg: FrameMessage) -> FrameMessage:
        """Invented people under fresh ids of the node's camera; an id its neighbours relayed
        back (the node adopted its own phantom) is replaced, not sent twice."""
        extra = []
        for n, p, v in self.walkers[id(r)].at(k):
            born = self.born.setdefault(n, k)
            x = np.array([p[0], p[1], PERSON_M[0] * self.upm, PERSON_M[1] * self.upm, v[0], v[1]])
            u, U = _sharp(x[:4], self.upm)
            extra.append(TrackerInfo((msg.sender, COUNTER + n), x, u, U, 0, born=born))
        ids = {t.id for t in extra}
        return replace(msg, trackers=tuple(t for t in msg.trackers if t.id not in ids)
                       + tuple(extra))

    def _stale(self, r: FaultyNode, k: int, msg: FrameMessage) -> FrameMessage:
        old = self.history[0] if len(self.history) > r.lag else None
        return msg if old is None else replace(old, frame=k, sent_at=msg.sent_at)

    def _forged_merge(self, r: FaultyNode, k: int, msg: FrameMessage) -> FrameMessage:
        ids = sorted((t.id, t.born) for t in msg.trackers)
        merges = tuple(Merge(a, b, born) for (a, _), (b, born) in zip(ids, ids[1:]))
        return replace(msg, merges=tuple(msg.merges) + merges)
