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


#: The fakes' cameras all view the same 10 m x 10 m, and a test gives each camera only the
#: detections its story needs ("only node 0 sees the person"). Negative evidence (on by
#: default: ``report_unseen``, ``views.OwnViews.expect``) would rightly refute, on a node, a
#: target its camera looks at and is never given; the tests of something else switch it off
#: with ``TrackerConfig(**SELECTIVE)``. tests/test_unseen.py tests it.
SELECTIVE = {"report_unseen": 0}


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


# -- a fake for every role of a node (tests/test_shape.py swaps each into a real node) ----------
# Each is the smallest thing that plays the role through the role's interface, and counts its
# calls. Stone Soup's tracker tests (stonesoup/tracker/tests/conftest.py) are the model.
class _Counted:
    def __init__(self):
        self.calls = 0


class FakePredictor(_Counted):
    """Nothing moves: the prediction is the last estimate, a little less certain."""

    def __call__(self, state, steps):
        self.calls += 1
        if steps and len(state):
            state.x_bar, state.P = state.x_hat.copy(), state.M + 1e-4 * np.eye(6)


class FakeMeasurer(_Counted):
    """A ``topdown_camera`` box's bottom centre, size and a fixed ``R``; no registration."""

    def __init__(self, cameras):
        super().__init__()
        self.cameras = list(cameras)

    def split(self, node, detections):
        return {self.cameras[0].id: detections}

    def __call__(self, cam, dets):
        from types import SimpleNamespace
        from edge_node.core.association import Observations
        self.calls += 1
        if not dets:
            return Observations(np.zeros((0, 4)), np.zeros((0, 4, 4)), []), None
        b = np.array([d.box for d in dets], float)
        z = np.stack([(b[:, 0] + b[:, 2] / 2) / PX_PER_M, (b[:, 1] + b[:, 3]) / PX_PER_M,
                      b[:, 2] / PX_PER_M, b[:, 3] / PX_PER_M], axis=1)
        R = np.broadcast_to(0.01 * np.eye(4), (len(b), 4, 4)).copy()
        return Observations(z, R, [None] * len(b)), SimpleNamespace(z=z, R=R, size=z[:, 2:])


class FakeAssociator(_Counted):
    """Each measurement to the nearest tracker within 1 m (greedy), its information added."""

    def __call__(self, state, c, k, obs):
        from edge_node.core.dkf import informations
        self.calls += 1
        free = []
        taken: set[int] = set()
        for j in range(len(obs)):
            d = np.linalg.norm(state.x_bar[:, :2] - obs.z[j, :2], axis=1) if len(state) else []
            i = int(np.argmin(d)) if len(d) else -1
            if i >= 0 and d[i] < 1.0 and i not in taken:
                taken.add(i)
                u, U = informations(obs.z[j:j + 1], obs.R[j:j + 1])
                state.add_information(np.array([i]), c, u, U, np.array([j]))
            else:
                free.append(obs[j])
        return free


class FakeInitiator(_Counted):
    """Every unassigned observation is a birth at once."""

    def step(self, k, unassigned):
        from edge_node.core.initiator import Pending
        self.calls += 1
        return [Pending([o], [k]) for o in unassigned]


class FakeLifecycle(_Counted):
    """Births under new ids; nothing adopted or merged; a tracker unseen for 5 frames goes."""

    def __init__(self):
        super().__init__()
        self.next = 0
        self.unseen: dict = {}

    def birth(self, state, k, c, observations):
        from edge_node.core.dkf import information
        from edge_node.core.gallery import Gallery
        self.calls += 1
        o = observations[-1]
        i = state.insert((99, self.next), Gallery(), x_bar=np.r_[o.z, 0.0, 0.0], P=np.eye(6),
                         born=k, since=k, heard=k)
        self.next += 1
        u, U = information(o.z, o.R)
        state.add_information(np.array([i]), c, u[None], U[None], np.array([o.raw]))

    def announced(self, state, msgs):
        self.calls += 1

    def adopt(self, state, k, heard):
        self.calls += 1

    def count(self, state, k, entries, lagless=None, news=frozenset()):
        self.calls += 1
        seen = state.seen_any()
        state.ell = np.where(seen, 0, state.ell + 1)
        state.coast = np.where(seen, 0, state.coast + 1)

    def manage(self, state, k, measured):
        self.calls += 1
        for t in [t for i, t in enumerate(state.ids) if state.ell[i] > 5]:
            state.delete(t)


class FakeInbound(_Counted):
    """Takes every message as it comes; gathers them per tracker."""

    def take(self, inbox, k, stale_ok, book, held):
        self.calls += 1
        return list(inbox)

    def gather(self, msgs, k, stale_ok, aliases):
        from edge_node.core.entries import Inbox
        from edge_node.core.inbound import Heard
        self.calls += 1
        return Heard(Inbox(msgs, aliases))


class FakeTrust(_Counted):
    """Believes every neighbour: the messages pass as they came."""

    def __call__(self, state, msgs, k, resolve):
        self.calls += 1
        return msgs

    def summary(self):
        return {}


class FakeUpdater(_Counted):
    """A Kalman update with the node's own information only (eq. 4 without neighbours)."""

    def __call__(self, state, entries):
        self.calls += 1
        if not len(state):
            return
        M = np.linalg.inv(np.linalg.inv(state.P) + state.U)
        innovation = state.u - (state.U @ state.x_bar[..., None])[..., 0]
        state.x_hat = state.x_bar + (M @ innovation[..., None])[..., 0]
        state.M, state.estimated = M, np.ones(len(state), bool)
        state.informed = state.U[:, 0, 0] > 0


class FakeRegistrar(_Counted):
    """Learns nothing."""

    def __call__(self, state, entries, raws):
        self.calls += 1


class FakeOutbound(_Counted):
    """Tells the neighbours nothing but the frame."""

    def __init__(self, network, sender):
        super().__init__()
        self.network, self.sender = network, sender

    def sent_values(self, state):
        self.calls += 1

    def message(self, state, k):
        from protocol.messages import FrameMessage
        self.calls += 1
        return FrameMessage(self.network, self.sender, k)

    def covariances(self):
        return np.zeros((0, 6, 6))

    @staticmethod
    def resync(msg, state):
        return msg


class FakeReporter(_Counted):
    """Every tracker with an estimate, no boxes."""

    def __call__(self, state, k):
        from edge_node.core.types import Track
        self.calls += 1
        return [Track(t, k, state.x_hat[i].copy(), state.M[i].copy(), bool(state.seen_any()[i]),
                      int(state.ell[i]), {})
                for i, t in enumerate(state.ids) if state.estimated[i]]


class FakeViews(_Counted):
    """Draws nothing."""

    def __init__(self, cameras=(), registrations=None):
        super().__init__()

    def saw(self, state, k, raws):
        self.calls += 1

    def boxes(self, state, rows, k, x_hat, two_people=None):
        self.calls += 1
        return [{} for _ in rows]

    def unseen_limit(self):
        return 0


def fake_roles(node) -> dict:
    """A fake for every role of ``node``: attribute name -> fake."""
    return {"predictor": FakePredictor(), "measurer": FakeMeasurer(node.cameras),
            "associator": FakeAssociator(), "initiators": {c.id: FakeInitiator() for c in node.cameras},
            "lifecycle": FakeLifecycle(), "inbound": FakeInbound(), "trust": FakeTrust(),
            "updater": FakeUpdater(),
            "registrar": FakeRegistrar(), "outbound": FakeOutbound(node.network, node.id),
            "reporter": FakeReporter(), "own_views": FakeViews()}
