"""Tiny fakes for core tests: a top-down camera, people with fixed appearance, a driver."""
from __future__ import annotations

import numpy as np

from edge_node.core import CameraNode, Detection, TrackerConfig
from edge_node.geometry import Camera
from protocol import codec

PX_PER_M = 100.0


def topdown_camera(cid: int, offset=(0.0, 0.0)) -> Camera:
    """A camera whose image maps linearly to the ground: 100 px per metre, 1000x1000 px over
    10x10 m. ``offset`` shifts where it believes things are (a calibration error, metres)."""
    G = np.array([[1 / PX_PER_M, 0, offset[0]], [0, 1 / PX_PER_M, offset[1]], [0, 0, 1.0]])
    return Camera(cid, (1000, 1000), G)


def box_at(x: float, y: float, w: float = 0.5, h: float = 1.7) -> np.ndarray:
    """The box whose bottom centre is ground point ``(x, y)`` in ``topdown_camera`` (no offset)."""
    fx, fy = x * PX_PER_M, y * PX_PER_M
    bw, bh = w * PX_PER_M, h * PX_PER_M
    return np.array([fx - bw / 2, fy - bh, bw, bh])


def homography_scene(G: np.ndarray, frames: int, people: int, extra: str = "") -> str:
    """A synthetic scenario's TOML with one 360x288 camera given by its image-to-ground
    homography ``G`` alone (no pose), over a 10 m x 10 m area; ``extra`` appends tables."""
    rows = ", ".join("[" + ", ".join(repr(float(v)) for v in r) + "]" for r in G)
    return f"""frames = {frames}
[area]
xmin = 0.0
xmax = 10.0
ymin = 0.0
ymax = 10.0
[[cameras]]
image_size = [360, 288]
homography = [{rows}]
[people]
concurrent = {people}
""" + extra


def identity(pid: int, dim: int = 64) -> np.ndarray:
    v = np.random.default_rng(1000 + pid).normal(size=dim)
    return v / np.linalg.norm(v)


def det(x: float, y: float, pid: int, rng=None, noise: float = 0.05) -> Detection:
    d = identity(pid)
    if rng is not None:
        d = d + noise * rng.normal(size=d.shape) / np.sqrt(d.size)
    return Detection(box_at(x, y), d)


def graph(kind: str, n: int) -> dict[int, tuple[int, ...]]:
    """A small topology written out by hand (core tests do not import the simulator)."""
    if kind == "complete":
        return {i: tuple(j for j in range(n) if j != i) for i in range(n)}
    if kind == "chain":
        return {i: tuple(j for j in (i - 1, i + 1) if 0 <= j < n) for i in range(n)}
    if kind == "ring":
        return {i: tuple(sorted({(i - 1) % n, (i + 1) % n} - {i})) for i in range(n)}
    if kind == "disconnected":
        return {i: () for i in range(n)}
    raise ValueError(kind)


def make_nodes(adj: dict[int, tuple[int, ...]], cfg: TrackerConfig | None = None,
               offsets: dict[int, tuple[float, float]] | None = None) -> dict[int, CameraNode]:
    offsets = offsets or {}
    return {i: CameraNode(topdown_camera(i, offsets.get(i, (0.0, 0.0))), adj[i], cfg, "t")
            for i in adj}


def step(nodes, k: int, dets: dict[int, list[Detection]], links_up=True):
    """One frame through the real codec; returns ``{node: tracks}``."""
    msgs = {i: codec.encode(n.prepare(k, dets.get(i, []))) for i, n in nodes.items()}
    out = {}
    for i, n in nodes.items():
        inbox = [codec.decode(msgs[j], expect_sender=j) for j in n.neighbours] if links_up else []
        out[i] = n.update(inbox)
    return out
