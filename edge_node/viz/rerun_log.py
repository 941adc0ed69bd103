"""Logging a camera network into Rerun: every node's ground-plane tracks in one recording.

A sink is made from a spec string (``--rerun`` on the command lines, ``[viz] rerun`` in a camera
config)::

    off                 nothing (the default); Rerun is not even imported
    spawn               start a native viewer (or use the one on port 9876) and stream to it
    connect [ADDR]      stream to a running viewer / server: rerun+http://HOST:PORT/proxy or
                        HOST:PORT (default rerun+http://127.0.0.1:9876/proxy)
    save FILE.rrd       write a recording file (open it with ``rerun FILE.rrd``)
    serve [PORT]        serve a web viewer on http://127.0.0.1:PORT (default 9090) and the data
                        over gRPC on 9876

Every process of one network logs with the same application id (``dmtt``) and the same
recording id, so one viewer shows the whole network as one recording. Entities::

    world/area                          the walkable rectangle (static)
    world/cameras/<c>/fov               camera c's field of view on the ground (static polygon)
    world/cameras/<c>/position          camera c's ground position, when its projection is known
    world/ground_truth                  true positions (scenarios with ground truth)
    world/disagreement/{max,mean}       spread of the nodes' estimates of one track id (metres)
    nodes/<n>/tracks                    node n's tracks: circles of the tracked width (line
                                        strips), labelled with the track id "camera:counter",
                                        one colour per id on every node
    nodes/<n>/trails                    the last TRAIL positions of each track
    nodes/<n>/measurements              node n's detections of the frame, projected to the ground
    nodes/<n>/stats/<name>              time series: active_trackers, bytes_sent, dropped,
                                        rejected, timeouts
    nodes/<n>/camera/{image,detections,tracks}   the camera image with boxes (when there is one)

Time: the ``frame`` sequence timeline, and ``wall_time`` where the logger runs live.
Ground coordinates are logged as they are (the scenario's units); Rerun's 2-D view draws +y
downwards, so the ground plane appears mirrored top to bottom against a map with +y up.
"""
from __future__ import annotations

import colorsys
import functools
import logging
import zlib
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.viz.live import LiveSink
from protocol.errors import DmttError

APP_ID = "dmtt"
KINDS = ("off", "spawn", "connect", "save", "serve")
DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
DEFAULT_URL = f"rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy"
TRAIL = 25  # positions kept per track trail
# How long closing a streaming sink (spawn, connect, serve) waits for its data to reach the
# viewer: one that cannot be reached (``connect`` to an address nothing listens on, a viewer
# closed meanwhile) must not hold a finished node or launcher; Rerun's own shutdown adds up to
# 5 s more. A saved file is flushed without a bound (it goes to disk, and a cut one is lost).
FLUSH_TIMEOUT_S = 5.0
log = logging.getLogger(__name__)
_ANG = np.linspace(0.0, 2.0 * np.pi, 25)
_UNIT_CIRCLE = np.stack([np.cos(_ANG), np.sin(_ANG)], axis=1)  # closed: first == last

# tab10: one colour per node (its camera's field of view and its raw measurements)
_NODE_COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
                 (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


class VizSpecError(DmttError, ValueError):
    """A ``--rerun`` spec that cannot be used; the message says why."""


class SinkError(DmttError, RuntimeError):
    """A Rerun sink that could not start (port in use, unwritable file, no viewer binary)."""


@dataclass(frozen=True)
class VizSpec:
    kind: str  # one of KINDS
    arg: str | None = None  # connect: URL; save: path; serve: web port

    def __str__(self) -> str:
        return self.kind if self.arg is None else f"{self.kind} {self.arg}"

    @property
    def enabled(self) -> bool:
        return self.kind != "off"


def parse_spec(spec: str | Sequence[str] | None) -> VizSpec:
    """``"save x.rrd"`` / ``["save", "x.rrd"]`` / ``None`` (off) to a checked :class:`VizSpec`."""
    if spec is None:
        return VizSpec("off")
    text = spec if isinstance(spec, str) else " ".join(spec)
    parts = text.strip().split(maxsplit=1)
    if not parts:
        raise VizSpecError("is empty; use one of: off, spawn, connect [ADDR], save FILE.rrd, "
                           "serve [PORT]")
    kind, arg = parts[0].lower(), (parts[1].strip() if len(parts) > 1 else None)
    if kind not in KINDS:
        raise VizSpecError(f"must start with one of {', '.join(KINDS)}, got {text!r}")
    if kind in ("off", "spawn") and arg:
        raise VizSpecError(f"'{kind}' takes no argument, got {text!r}")
    if kind == "save":
        if not arg:
            raise VizSpecError("'save' needs a file, e.g. 'save runs/latest.rrd'")
    elif kind == "connect":
        arg = arg or DEFAULT_URL
        if "://" not in arg:
            host, sep, port = arg.rpartition(":")
            if not sep or not host or not port.isdigit():
                raise VizSpecError(f"'connect' needs rerun+http://HOST:PORT/proxy or HOST:PORT, "
                                   f"got {arg!r}")
            arg = f"rerun+http://{host}:{port}/proxy"
    elif kind == "serve" and arg is not None:
        if not arg.isdigit() or not 0 < int(arg) < 65536:
            raise VizSpecError(f"'serve' takes an optional web port (1-65535), got {arg!r}")
    return VizSpec(kind, arg)


# -- pure helpers (no Rerun) --------------------------------------------------------------------
def track_label(tid: tuple[int, int]) -> str:
    """The label of a track id ``(camera, counter)``: ``"camera:counter"``."""
    return f"{int(tid[0])}:{int(tid[1])}"


def track_colour(tid: tuple[int, int]) -> tuple[int, int, int]:
    """A colour for a track id, the same in every process (no salted ``hash``)."""
    return _colour(int(tid[0]), int(tid[1]))


@functools.lru_cache(maxsize=4096)
def _colour(camera: int, counter: int) -> tuple[int, int, int]:
    h = zlib.crc32(f"{camera}:{counter}".encode()) / 2**32
    r, g, b = colorsys.hsv_to_rgb(h, 0.8, 0.95)
    return int(r * 255), int(g * 255), int(b * 255)


def node_colour(node: int) -> tuple[int, int, int]:
    return _NODE_COLOURS[int(node) % len(_NODE_COLOURS)]


def ground_points(camera, detections: Iterable[Any]) -> np.ndarray:
    """The foot points (bottom centres) of detection boxes through ``camera.to_ground``, (n, 2)."""
    boxes = np.asarray([np.asarray(getattr(d, "box", d), float)[:4] for d in detections],
                       float).reshape(-1, 4)
    if not len(boxes):
        return np.zeros((0, 2))
    feet = np.stack([boxes[:, 0] + boxes[:, 2] / 2.0, boxes[:, 1] + boxes[:, 3]], axis=1)
    xy = camera.to_ground(feet)
    return xy[np.all(np.isfinite(xy), axis=1)]


def disagreement(tracks_by_node: Mapping[int, Sequence[Any]]) -> dict[tuple[int, int], float]:
    """For every track id held by two or more nodes: the spread of their estimates, the largest
    distance between two nodes' ``(x, y)`` (ground units)."""
    pos: dict[tuple[int, int], list[np.ndarray]] = {}
    for tracks in tracks_by_node.values():
        for t in tracks:
            pos.setdefault(tuple(t.id), []).append(np.asarray(t.x[:2], float))
    out = {}
    for tid, ps in pos.items():
        if len(ps) > 1:
            p = np.stack(ps)
            d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
            out[tid] = float(d.max())
    return out


def _clip(poly: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    """Sutherland-Hodgman: the polygon ``poly`` (n, 2) clipped to ``(xmin, xmax, ymin, ymax)``."""
    xmin, xmax, ymin, ymax = box
    edges = [(0, xmin, 1), (0, xmax, -1), (1, ymin, 1), (1, ymax, -1)]
    pts = [p for p in poly]
    for axis, bound, sign in edges:
        if not pts:
            break
        out = []
        for i, cur in enumerate(pts):
            prev = pts[i - 1]
            cin = sign * (cur[axis] - bound) >= 0
            pin = sign * (prev[axis] - bound) >= 0
            if cin != pin:
                t = (bound - prev[axis]) / (cur[axis] - prev[axis])
                out.append(prev + t * (cur - prev))
            if cin:
                out.append(cur)
        pts = out
    return np.array(pts).reshape(-1, 2)


def fov_polygon(camera, area: Sequence[float] | None = None, margin: float = 0.25) -> np.ndarray:
    """The ground polygon the camera sees, clipped to ``area`` grown by ``margin`` of its size
    (without an area: to a square around the camera reaching four times as far as the image
    centre's ground point). Empty when the camera sees no ground."""
    poly = camera.footprint()
    poly = poly[np.all(np.isfinite(poly), axis=1)] if len(poly) else poly
    if len(poly) < 3:
        return np.zeros((0, 2))
    if area is not None:
        xmin, xmax, ymin, ymax = (float(v) for v in area)
        mx, my = margin * (xmax - xmin), margin * (ymax - ymin)
        box = (xmin - mx, xmax + mx, ymin - my, ymax + my)
    else:
        W, H = camera.image_size
        anchor = camera_position(camera)
        bottom = camera.to_ground(np.array([[W / 2.0, float(H)]]))[0]
        mid = camera.to_ground(np.array([[W / 2.0, H / 2.0]]))[0]
        anchor = bottom if anchor is None else anchor
        reach = np.linalg.norm(mid - anchor) if camera.in_front(mid[None])[0] else 0.0
        reach = 4.0 * max(reach, np.linalg.norm(bottom - anchor), 1e-6)
        box = (anchor[0] - reach, anchor[0] + reach, anchor[1] - reach, anchor[1] + reach)
    return _clip(poly, box)


def camera_position(camera) -> np.ndarray | None:
    """The camera's ground position ``(x, y)`` when its projection matrix is known."""
    c = camera.center() if getattr(camera, "P", None) is not None else None
    if c is None or not np.all(np.isfinite(c)):
        return None
    return np.asarray(c[:2], float)


# -- the sinks -------------------------------------------------------------------------------------
class NullSink:
    """``--rerun off``: every call does nothing."""

    enabled = False
    spec = VizSpec("off")
    url: str | None = None

    def log_world(self, *a, **k) -> None: ...
    def log_cameras(self, *a, **k) -> None: ...
    def log_truth(self, *a, **k) -> None: ...
    def log_frame(self, *a, **k) -> None: ...
    def log_disagreement(self, *a, **k) -> None: ...
    def log_image(self, *a, **k) -> None: ...

    def close(self) -> bool:
        return True


def make_sink(spec: str | Sequence[str] | VizSpec | None, *, app_id: str = APP_ID,
              recording_id: str | None = None, node: int | None = None,
              blueprint: Any = None, grpc_port: int | None = None):
    """A sink for ``spec``: :class:`NullSink` for ``off`` (Rerun not imported), else a
    :class:`RerunSink`. ``blueprint`` is an ``rerun.blueprint.Blueprint`` (see
    :func:`make_blueprint`), ``"auto"`` for the generic one, or ``None`` (send none)."""
    spec = spec if isinstance(spec, VizSpec) else parse_spec(spec)
    if not spec.enabled:
        return NullSink()
    return RerunSink(spec, app_id=app_id, recording_id=recording_id, node=node,
                     blueprint=blueprint, grpc_port=grpc_port)


def make_blueprint(nodes: Sequence[int] | None = None, *, images: Sequence[int] = (),
                   area: Sequence[float] | None = None, cameras: Sequence[Any] = ()):
    """The layout the viewer opens on: the ground plane large (framing ``area`` and the
    ``cameras``' positions), time series below, one image panel per node in ``images``.
    Without ``nodes`` the time series panels take every node's series (a standalone node does
    not know the others)."""
    import rerun.blueprint as rrb  # Rerun is optional (viz extra), imported only to log

    hide = [f"- /nodes/{i}/camera/**" for i in images]
    bounds = None
    if area is not None:
        xmin, xmax, ymin, ymax = (float(v) for v in area)
        for c in cameras:
            p = camera_position(c)
            if p is not None:
                xmin, xmax = min(xmin, p[0]), max(xmax, p[0])
                ymin, ymax = min(ymin, p[1]), max(ymax, p[1])
        mx, my = 0.08 * (xmax - xmin), 0.08 * (ymax - ymin)
        bounds = rrb.VisualBounds2D(x_range=[xmin - mx, xmax + mx], y_range=[ymin - my, ymax + my])
    ground = rrb.Spatial2DView(name="ground plane", origin="/",
                               contents=["+ /world/**", "+ /nodes/**", *hide],
                               visual_bounds=bounds)
    if nodes is None:
        series = [rrb.TimeSeriesView(name="nodes", origin="/nodes"),
                  rrb.TimeSeriesView(name="disagreement (m)", origin="/",
                                     contents=["+ /world/disagreement/**"])]
    else:
        def ts(name, metrics):
            return rrb.TimeSeriesView(name=name, origin="/", contents=[
                f"+ /nodes/{i}/stats/{m}" for i in nodes for m in metrics])
        series = [ts("active trackers", ["active_trackers"]), ts("bytes sent", ["bytes_sent"]),
                  ts("dropped / rejected / timeouts", ["dropped", "rejected", "timeouts"]),
                  rrb.TimeSeriesView(name="disagreement (m)", origin="/",
                                     contents=["+ /world/disagreement/**"])]
    top: Any = ground
    if images:
        cams = [rrb.Spatial2DView(name=f"camera {i}", origin=f"/nodes/{i}/camera") for i in images]
        top = rrb.Horizontal(ground, rrb.Vertical(*cams), column_shares=[3, 2])
    return rrb.Blueprint(rrb.Vertical(top, rrb.Horizontal(*series), row_shares=[3, 1]),
                         rrb.TimePanel(state="collapsed", timeline="frame"),
                         rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"))


class RerunSink:
    """Logs one node (``node``) or a whole in-process network (``node=`` on each call) into
    the recording ``recording_id`` of application ``app_id``."""

    enabled = True

    def __init__(self, spec: VizSpec, *, app_id: str = APP_ID, recording_id: str | None = None,
                 node: int | None = None, blueprint: Any = None, grpc_port: int | None = None):
        import rerun as rr  # Rerun is optional (viz extra), imported only to log

        self.rr = rr
        self.spec = spec
        self.node = node
        self.units_per_metre = 1.0
        self.url: str | None = None  # serve: what a browser opens
        self._trails: dict[int, dict[tuple[int, int], deque]] = {}
        self._series_styled: set[str] = set()
        self._stats: dict[str, tuple[int, float, bool]] = {}  # path -> (frame, value, pending)
        if isinstance(blueprint, str) and blueprint == "auto":
            blueprint = make_blueprint(None)
        rec = rr.RecordingStream(app_id, recording_id=recording_id)
        self.rec = rec
        kind, arg = spec.kind, spec.arg
        if kind == "save":
            path = Path(arg)
            path.parent.mkdir(parents=True, exist_ok=True)
            rec.save(path, default_blueprint=blueprint)
        elif kind == "connect":
            rec.connect_grpc(arg, default_blueprint=blueprint)
        elif kind == "spawn":
            rec.spawn(port=grpc_port or DEFAULT_GRPC_PORT, default_blueprint=blueprint)
        elif kind == "serve":
            web = int(arg) if arg else DEFAULT_WEB_PORT
            uri = rec.serve_grpc(grpc_port=grpc_port or DEFAULT_GRPC_PORT,
                                 default_blueprint=blueprint)
            rr.serve_web_viewer(web_port=web, open_browser=False, connect_to=uri)
            self.grpc_url = uri
            self.url = f"http://127.0.0.1:{web}/?url={uri}"
        else:  # pragma: no cover - parse_spec checked it
            raise VizSpecError(f"unknown kind {kind!r}")

    # -- static world ------------------------------------------------------------------------
    def log_world(self, *, area: Sequence[float] | None = None, units_per_metre: float = 1.0,
                  cameras: Sequence[Any] = ()) -> None:
        """The static scene: the area rectangle and the cameras (see :meth:`log_cameras`)."""
        rr = self.rr
        self.units_per_metre = float(units_per_metre)
        if area is not None:
            xmin, xmax, ymin, ymax = (float(v) for v in area)
            rect = [[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax], [xmin, ymin]]
            self.rec.log("world/area", rr.LineStrips2D([rect], colors=[(90, 90, 90)],
                                                       radii=[-1.0], draw_order=0.0), static=True)
        if cameras:
            self.log_cameras(cameras, area=area)

    def log_cameras(self, cameras: Sequence[Any], *, area: Sequence[float] | None = None) -> None:
        """Each camera's field of view (ground polygon) and position, static."""
        rr = self.rr
        for cam in cameras:
            c = node_colour(cam.id)
            poly = fov_polygon(cam, area)
            if len(poly) >= 3:
                ring = np.vstack([poly, poly[:1]])
                self.rec.log(f"world/cameras/{cam.id}/fov",
                             rr.LineStrips2D([ring], colors=[c], radii=[-1.0],
                                             labels=[f"camera {cam.id}"], show_labels=False,
                                             draw_order=1.0), static=True)
            pos = camera_position(cam)
            if pos is not None:
                self.rec.log(f"world/cameras/{cam.id}/position",
                             rr.Points2D([pos], colors=[c], radii=[-6.0],
                                         labels=[f"cam {cam.id}"], show_labels=True,
                                         draw_order=30.0), static=True)

    # -- per frame ---------------------------------------------------------------------------
    def _time(self, k: int, wall_time: float | None) -> None:
        self.rec.set_time("frame", sequence=int(k))
        if wall_time is not None:
            self.rec.set_time("wall_time", timestamp=float(wall_time))

    def log_truth(self, k: int, ids: Sequence[int], xy: np.ndarray, *,
                  wall_time: float | None = None) -> None:
        """Ground-truth positions of frame ``k`` at ``world/ground_truth``."""
        rr = self.rr
        self._time(k, wall_time)
        xy = np.asarray(xy, float).reshape(-1, 2)
        self.rec.log("world/ground_truth", rr.Points2D(
            xy, radii=[0.08 * self.units_per_metre], colors=[(20, 20, 20)],
            labels=[f"person {int(i)}" for i in ids], show_labels=False, draw_order=40.0))

    def log_frame(self, k: int, tracks: Sequence[Any], *, node: int | None = None,
                  measurements_xy: np.ndarray | None = None,
                  stats: Mapping[str, float] | None = None,
                  wall_time: float | None = None) -> None:
        """One node's frame: its tracks (footprints, labels, trails), its raw measurements on
        the ground and its counters as time series."""
        rr = self.rr
        node = self.node if node is None else node
        base = f"nodes/{node}"
        self._time(k, wall_time)
        ids = [tuple(int(v) for v in t.id) for t in tracks]
        pos = np.array([t.x[:2] for t in tracks], float).reshape(-1, 2)
        w = np.array([t.x[2] for t in tracks], float)
        w = np.where(np.isfinite(w) & (w > 0), w, 0.5 * self.units_per_metre)
        # (n, 25, 2) arrays take Rerun's fast numpy path (a list of strips is ~2x slower)
        circles = pos[:, None, :] + (w / 2.0)[:, None, None] * _UNIT_CIRCLE[None, :, :]
        colours = np.array([track_colour(i) for i in ids], np.uint8).reshape(-1, 3)
        self.rec.log(f"{base}/tracks", rr.LineStrips2D(
            circles, colors=colours, radii=[-1.5], labels=[track_label(i) for i in ids],
            show_labels=True, draw_order=20.0))
        trails = self._trails.setdefault(node, {})
        for tid in list(trails):
            if tid not in ids:
                del trails[tid]
        for tid, p in zip(ids, pos):
            trails.setdefault(tid, deque(maxlen=TRAIL)).append(p)
        # every trail TRAIL points long: a young track's first point repeated (zero-length
        # segments draw nothing)
        strips = np.array([[q[0]] * (TRAIL - len(q)) + list(q) for q in trails.values()],
                          float).reshape(-1, TRAIL, 2)
        self.rec.log(f"{base}/trails", rr.LineStrips2D(
            strips, colors=np.array([track_colour(t) for t in trails], np.uint8).reshape(-1, 3),
            radii=[-1.5], draw_order=15.0))
        if measurements_xy is not None:
            m = np.asarray(measurements_xy, float).reshape(-1, 2)
            self.rec.log(f"{base}/measurements", rr.Points2D(
                m, radii=[-3.0], colors=[node_colour(node)], draw_order=25.0))
        for name, v in (stats or {}).items():
            # a step plot, logged only when the value changes (most counters rarely do; every
            # log call costs ~0.2 ms) and at the last frame (close)
            path, v = f"{base}/stats/{name}", float(v)
            if path not in self._series_styled:
                self._series_styled.add(path)
                self.rec.log(path, rr.SeriesLines(names=[f"node {node} {name}"],
                                                  colors=[node_colour(node)],
                                                  interpolation_mode="StepAfter"), static=True)
            last = self._stats.get(path)
            if last is None or last[1] != v:
                self.rec.log(path, rr.Scalars(v))
            self._stats[path] = (int(k), v, last is not None and last[1] == v)

    def log_disagreement(self, k: int, spreads: Mapping[Any, float], *,
                         wall_time: float | None = None) -> None:
        """``world/disagreement/{max,mean}``: spreads (ground units) in metres; nothing when no
        id is held by two nodes."""
        if not spreads:
            return
        self._time(k, wall_time)
        v = np.array(list(spreads.values()), float) / self.units_per_metre
        for name, x, colour in (("max", v.max(), (214, 39, 40)), ("mean", v.mean(), (60, 60, 60))):
            path = f"world/disagreement/{name}"
            if path not in self._series_styled:
                self._series_styled.add(path)
                self.rec.log(path, self.rr.SeriesLines(names=[f"{name} spread of one id (m)"],
                                                       colors=[colour]), static=True)
            self.rec.log(path, self.rr.Scalars(float(x)))

    def log_image(self, k: int, image: np.ndarray, *, node: int | None = None,
                  detections: np.ndarray | None = None,
                  tracks: Sequence[tuple[tuple[int, int], np.ndarray]] = (),
                  wall_time: float | None = None) -> None:
        """A camera image with its detection boxes and the node's track boxes ``(id, box)``
        (boxes ``(x, y, w, h)`` in pixels) under ``nodes/<n>/camera/``."""
        rr = self.rr
        node = self.node if node is None else node
        base = f"nodes/{node}/camera"
        self._time(k, wall_time)
        self.rec.log(f"{base}/image", rr.Image(image))
        if detections is not None:
            d = np.asarray(detections, float).reshape(-1, 4)
            self.rec.log(f"{base}/detections", rr.Boxes2D(mins=d[:, :2], sizes=d[:, 2:4],
                                                          colors=[node_colour(node)]))
        b = np.array([box for _, box in tracks], float).reshape(-1, 4)
        self.rec.log(f"{base}/tracks", rr.Boxes2D(
            mins=b[:, :2], sizes=b[:, 2:4], labels=[track_label(t) for t, _ in tracks],
            colors=[track_colour(t) for t, _ in tracks]))

    def close(self) -> bool:
        """The time series' last values, flush; a saved file gets its footer. Never raises: a
        viewer that cannot be reached within ``FLUSH_TIMEOUT_S`` costs the data it did not get
        (a warning, and ``False``), not what its caller does after this (a launcher stops its
        nodes)."""
        ok = True
        try:
            for path, (k, v, pending) in self._stats.items():
                if pending:
                    self.rec.set_time("frame", sequence=k)
                    self.rec.log(path, self.rr.Scalars(v))
            self._stats = {}
            if self.spec.kind == "save":
                self.rec.flush()
            else:
                self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except Exception as e:  # noqa: BLE001 - Rerun raises RuntimeError when the flush times out
            ok = False
            log.warning("Rerun (%s): %s; the data not delivered is dropped", self.spec, e)
        finally:
            if self.spec.kind != "serve":  # a server keeps serving until the process ends
                try:
                    self.rec.disconnect()
                except Exception as e:  # noqa: BLE001 - as above
                    ok = False
                    log.warning("Rerun (%s): %s", self.spec, e)
        return ok


def open_node_sink(cfg, camera, units_per_metre: float = 1.0, *, keep_existing: bool = False):
    """The sink of one ``edge_node`` process from its ``[viz]`` settings (``NullSink`` when
    off), with its camera logged. A Rerun that cannot start raises :class:`SinkError` (the
    runtime reports it as a config error on ``viz.rerun``). ``keep_existing`` (a restarted
    node): ``save`` never overwrites an earlier life's file, it writes ``<stem>.<n>.rrd``
    beside it."""
    viz = cfg.viz
    spec = parse_spec(viz.rerun)
    if not spec.enabled:
        return NullSink()
    if keep_existing and spec.kind == "save" and Path(spec.arg).exists():
        p, n = Path(spec.arg), 1
        while p.with_name(f"{p.stem}.{n}{p.suffix}").exists():
            n += 1
        spec = VizSpec("save", str(p.with_name(f"{p.stem}.{n}{p.suffix}")))
    try:
        sink = make_sink(spec, recording_id=viz.recording_id or f"dmtt-{cfg.network}",
                         node=cfg.node,
                         blueprint=make_blueprint(None, area=viz.area) if viz.blueprint else None)
        sink.log_world(area=viz.area, units_per_metre=units_per_metre, cameras=[camera])
    except Exception as e:  # noqa: BLE001 - port in use, unwritable file, no viewer binary ...
        raise SinkError(f"{str(spec)!r}: Rerun could not start ({type(e).__name__}: {e})") from None
    # streaming: from a thread of its own, so that a viewer that cannot keep up (or be reached)
    # costs frames of the view, never frames of tracking (edge_node/viz/live.py)
    return sink if spec.kind == "save" else LiveSink(sink, timeout=FLUSH_TIMEOUT_S)
