"""The camera-process configuration: one TOML file per camera, validated on load.

Every error is a :class:`NodeConfigError` naming the file and the field, e.g.
``cam0.toml: zenoh.listen[0] must be an endpoint like tcp/127.0.0.1:7447, got 'x'``.
Unknown fields are errors (a typo must not silently fall back to a default). Relative paths
are relative to the directory of the TOML file.

Schema (defaults in brackets)::

    node = 0                        # this node's id (non-negative int); also its camera id
    network = "terrace"             # network name: one Zenoh key chunk (protocol.keys)
    neighbours = [1, 3]             # ids of the nodes this one exchanges messages with

    [zenoh]
    listen = ["tcp/127.0.0.1:7447"] # endpoints this node listens on                      [[]]
    connect = ["tcp/127.0.0.1:7448"]# endpoints of neighbours to connect to               [[]]
    scouting = false                # multicast scouting                                   [false]
    gossip = false                  # gossip scouting (turns a chain into a full mesh)      [false]
    lease_ms = 1000                 # optional: link lease (how soon a frozen peer is gone) [Zenoh's]
    config_file = "peer.json5"      # optional: a Zenoh json5 config to start from (TLS, ACL...)
    shared_memory = false           # Zenoh's shared-memory transport between processes on one
                                    # host (a restarted neighbour's pool stays mapped) [false]

    [runtime]
    mode = "sync"                   # "sync" | "async"                                     ["sync"]
    sync_timeout_s = 1.0            # sync: how long frame k waits for live neighbours      [1.0]
    startup_timeout_s = 5.0         # start-up barrier: how long to wait for own neighbours [5.0]
                                    # (and an unpaced run's first frame: runtime/loop.py)
    stall_after_s = 5.0             # status 'stalled' after this long without a frame      [5.0]
    fps = 0.0                       # pacing; 0 = as fast as possible                       [0]
    frames = 100                    # optional limit on the number of frames
    heartbeat_frames = 5            # async: send at least every N frames  [core.trigger's: 5]
    drift_m = 0.1                   # async: send a tracker when it drifted this far (metres)
                                    #        from what the neighbours extrapolate  [core.trigger's]
    gain_nats = 1.0                 # async: send withheld measurement information once it is
                                    #        worth this much (KL divergence, nats)  [core.trigger's: 1]
    staleness_frames = 2            # async: use a stale message's u, U only this many frames
                                    #        (sets TrackerConfig.staleness_frames)     [tracker's]

    [source]                        # where detections (and by default the camera) come from
    kind = "det-file"               # a det-files directory (edge_node/formats/calibration.py)
    path = "export/calibration.json"#   its calibration.json (or the directory)
    camera = 0                      #   camera index in calibration.json                 [node]
    # kind = "scenario"             # a plug-in kind (edge_node/runtime/sources.py): sim_cluster's
    # scenario = "terrace-sim"      #   replay of a scenario, preset name or path
    # seed = 0  frames = 200  data_root = "..."  camera = 0
    # kind = "video"                # frames: "video" | "images" | "epfl" | "camera", run through
    # path = "cam0.avi"             #   [perception] (detector, re-id); needs [camera] (except
                                    #   epfl with homographies.json): edge_node/perception/settings.py

    [camera]                        # optional: overrides the calibration from the source
    homography = [[...], [...], [...]]   # image (scaled pixels) -> ground, 3x3
    projection = [[...], [...], [...]]   # optional, ground (x, y, z) -> pixels, 3x4
    image_size = [360, 288]
    pixel_scale = 1.0               #                                                      [1.0]
    fps = 25.0                      #                                                      [25.0]
    units_per_metre = 1.0           # optional: ground units per metre                   [source's]

    [tracker]                       # TrackerConfig fields (edge_node/core/config.py)
    ablation = "dkf+lda+dtm"        # "dkf" | "dkf+lda" | "dkf+lda+dtm"                  ["dkf+lda+dtm"]
    tau = 3.0                       # ... any TrackerConfig field

    [faults]                        # optional: fault injection (edge_node/faults.py)
    file = "faults.toml"            #   a FaultPlan: this node applies the link faults on its
                                    #   outgoing links and crashes itself at its kill frame;
                                    #   a rule naming one of this node's links must name a
                                    #   neighbour (the launcher checks the whole network)

    [output]
    dir = "out"                     # optional: tracks_node<id>.csv, status_node<id>.json,
                                    # counters_node<id>.json (edge_node/runtime/output.py)
    status_interval_s = 1.0         #                                                      [1.0]
    rotate_mb = 100.0               # optional: rotate the track file at this size: tracks_node
                                    # <id>.csv.1 .. .<keep> (SIGHUP reopens it, for logrotate)
    keep = 5                        # rotated track files kept                               [5]

    [viz]                           # optional: live view in Rerun (edge_node/viz/rerun_log.py)
    rerun = "off"                   # "off" | "spawn" | "connect [ADDR]" | "save FILE.rrd" |
                                    # "serve [PORT]" (a relative FILE: to this file)     ["off"]
    recording_id = "terrace"        # one per network: every node logs into it  ["dmtt-<network>"]
    blueprint = true                # send the viewer layout (false: a launcher sends it) [true]
    area = [0.0, 10.0, 0.0, 10.0]   # optional: ground xmin, xmax, ymin, ymax (clips the view)

The tracker's ``fps`` and ``units_per_metre`` come from the source (as in sim_cluster's in-process
run) unless ``[tracker]`` sets them explicitly; ``[camera] units_per_metre`` overrides the source's.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.core.config import CONFIG_NAMES, TrackerConfig
from edge_node.core.params import build
from edge_node.core.trigger import TriggerConfig
from edge_node.faults import FaultPlan, FaultPlanError, Network
from edge_node.geometry import Camera
from edge_node.perception.frames import FRAME_KINDS
from edge_node.perception.settings import PerceptionSettings, parse_frame_source, parse_perception
from edge_node.runtime.sources import PLUGIN_GROUP, SourceError, plugin_kinds, source_plugin
from edge_node.settings import SettingsError, Table, read_toml
from edge_node.viz import VizSpecError, parse_spec
from protocol.keys import is_valid_network, is_valid_node

MODES = ("sync", "async")
_TRIGGER = TriggerConfig()
SOURCE_KINDS = ("det-file", *FRAME_KINDS)  # built in; others are plug-ins (runtime/sources.py)
_ENDPOINT_RE = re.compile(r"(?P<proto>[a-z][a-z0-9-]*)/(?P<addr>[^?#]+)(?:\?[^#]*)?(?:#.*)?")
_IP_PROTOS = frozenset({"tcp", "udp", "tls", "quic", "ws"})
_OTHER_PROTOS = frozenset({"unixsock-stream", "unixpipe", "serial", "vsock"})
_HOST_RE = re.compile(r"\[[0-9A-Fa-f:.]+(?:%[A-Za-z0-9_.-]+)?\]|[A-Za-z0-9_.-]+")
ENDPOINT_HINT = "an endpoint like tcp/127.0.0.1:7447"


class NodeConfigError(SettingsError):
    """A camera config that cannot be used; the message names the file and the field."""


# -- endpoints ------------------------------------------------------------------------------------------
def endpoint_problem(endpoint: Any, *, listen: bool) -> str | None:
    """Why ``endpoint`` is not a usable Zenoh endpoint (``None`` when it is)."""
    if not isinstance(endpoint, str):
        return "not a string"
    m = _ENDPOINT_RE.fullmatch(endpoint)
    if not m:
        return "not <protocol>/<address>"
    proto, addr = m.group("proto"), m.group("addr")
    if proto in _OTHER_PROTOS:
        return None
    if proto not in _IP_PROTOS:
        return f"unknown protocol {proto!r}"
    host, sep, port = addr.rpartition(":")
    if not sep or not host or not _HOST_RE.fullmatch(host):
        return "address must be host:port"
    if not port.isdigit() or not (0 if listen else 1) <= int(port) <= 65535:
        return f"bad port {port!r}"
    return None


# -- the config objects ------------------------------------------------------------------------------
@dataclass(frozen=True)
class ZenohSettings:
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    scouting: bool = False
    gossip: bool = False
    lease_ms: int | None = None
    config_file: Path | None = None
    shared_memory: bool = False


@dataclass(frozen=True)
class RuntimeSettings:
    mode: str = "sync"
    sync_timeout_s: float = 1.0
    startup_timeout_s: float = 5.0
    fps: float = 0.0
    frames: int | None = None
    heartbeat_frames: int = _TRIGGER.heartbeat_frames
    drift_m: float = _TRIGGER.drift
    staleness_frames: int | None = None  # None: the tracker config's
    gain_nats: float = _TRIGGER.gain
    stall_after_s: float = 5.0  # no frame completed for this long: status 'stalled'


@dataclass(frozen=True, eq=False)
class CameraSettings:
    homography: np.ndarray
    image_size: tuple[int, int]
    projection: np.ndarray | None = None
    pixel_scale: float = 1.0
    fps: float = 25.0
    units_per_metre: float | None = None

    def camera(self, node: int) -> Camera:
        return Camera(id=node, image_size=self.image_size, G=self.homography, P=self.projection,
                      pixel_scale=self.pixel_scale, fps=self.fps)


@dataclass(frozen=True)
class SourceSettings:
    kind: str
    camera: int  # index of this node's camera in the source
    path: Path | None = None  # det-file: calibration.json or its directory
    options: dict = field(default_factory=dict)  # a plug-in kind's own fields (its parse())
    sequence: str | None = None  # epfl: the files' prefix (terrace1)
    pattern: str | None = None  # images: a glob
    device: int | str | None = None  # camera: device index or stream URL
    fps: float | None = None  # images / camera: frame rate


@dataclass(frozen=True)
class OutputSettings:
    dir: Path | None = None
    status_interval_s: float = 1.0
    rotate_mb: float | None = None  # None: one track file, never rotated
    keep: int = 5


@dataclass(frozen=True)
class VizSettings:
    rerun: str = "off"  # a spec for edge_node.viz.make_sink
    recording_id: str | None = None  # None: "dmtt-<network>"
    blueprint: bool = True
    area: tuple[float, float, float, float] | None = None


@dataclass(frozen=True, eq=False)
class NodeConfig:
    """A validated camera-process config (see the module docstring for the TOML schema)."""

    file: Path
    node: int
    network: str
    neighbours: tuple[int, ...]
    zenoh: ZenohSettings
    runtime: RuntimeSettings
    source: SourceSettings
    tracker: TrackerConfig
    ablation: str = "dkf+lda+dtm"
    tracker_explicit: frozenset[str] = field(default_factory=frozenset)  # keys set in [tracker]
    camera: CameraSettings | None = None
    output: OutputSettings = field(default_factory=OutputSettings)
    faults: Path | None = None  # a fault plan TOML (tests, fault reports)
    viz: VizSettings = field(default_factory=VizSettings)
    perception: Any = None  # edge_node.perception.settings.PerceptionSettings (frame sources)

    @property
    def name(self) -> str:
        return self.file.name

    def with_runtime(self, **changes) -> "NodeConfig":
        """A copy with ``[runtime]`` fields changed (command-line overrides), re-validated."""
        for k, v in changes.items():
            if k == "mode" and v not in MODES:
                raise NodeConfigError(self.name, "runtime.mode", f"must be one of {MODES}, got {v!r}")
            if k == "frames" and v is not None and (not isinstance(v, int) or v < 1):
                raise NodeConfigError(self.name, "runtime.frames", f"must be an integer >= 1, got {v!r}")
        return replace(self, runtime=replace(self.runtime, **changes))

    def to_dict(self) -> dict:
        """The resolved config, JSON-serialisable (``edge_node check`` prints it)."""
        def conv(v):
            if isinstance(v, Path):
                return str(v)
            if isinstance(v, np.ndarray):
                return v.tolist()
            if isinstance(v, (tuple, list)):
                return [conv(x) for x in v]
            if isinstance(v, frozenset):
                return sorted(v)
            if isinstance(v, dict):
                return {k: conv(x) for k, x in v.items()}
            return v

        def table(obj) -> dict:
            return {f.name: conv(getattr(obj, f.name)) for f in fields(obj)}

        return {
            "file": str(self.file.resolve()),
            "node": self.node,
            "network": self.network,
            "neighbours": list(self.neighbours),
            "zenoh": table(self.zenoh),
            "runtime": table(self.runtime),
            "source": table(self.source),
            "camera": None if self.camera is None else table(self.camera),
            "tracker": {"ablation": self.ablation, **{k: conv(v) for k, v in self.tracker.to_dict().items()}},
            "output": table(self.output),
            "viz": table(self.viz),
            "perception": None if self.perception is None else self.perception.to_dict(),
            "faults": None if self.faults is None else {"file": str(self.faults)},
        }


# -- parsing ------------------------------------------------------------------------------------------
def load_node_config(path: str | Path) -> NodeConfig:
    """Read and validate a camera config TOML file."""
    return parse_node_config(read_toml(path, NodeConfigError, what="config file"), path)


def parse_node_config(data: dict, path: str | Path) -> NodeConfig:
    """Validate an already parsed TOML document; ``path`` names it in errors and anchors
    relative paths."""
    path = Path(path)
    file = path.name
    base = path.resolve().parent
    top = Table(data, file, error=NodeConfigError)

    node = top.raw("node")
    if not is_valid_node(node):
        raise top.error("node", f"must be a non-negative integer, got {node!r}")
    network = top.raw("network")
    if not is_valid_network(network):
        raise top.error("network", "must be a non-empty name without '/', '*', '$', '?', '#' or "
                        f"spaces (at most 64 bytes), got {network!r}")
    neigh = top.list("neighbours", [])
    seen: set[int] = set()
    for i, n in enumerate(neigh):
        if not is_valid_node(n):
            raise top.error(f"neighbours[{i}]", f"must be a non-negative integer, got {n!r}")
        if n == node:
            raise top.error(f"neighbours[{i}]", f"is this node itself ({n})")
        if n in seen:
            raise top.error(f"neighbours[{i}]", f"repeats neighbour {n}")
        seen.add(n)

    zenoh_s = _zenoh(top.optional_table("zenoh"), base)
    runtime = _runtime(top.optional_table("runtime"))
    source = _source(top.table("source", required=True), base, node)
    camera = _camera(top.optional_table("camera"))
    tracker, ablation, explicit = _tracker(top.optional_table("tracker"))
    output = _output(top.optional_table("output"), base)
    faults = _faults(top.optional_table("faults"), base, node, tuple(seen))
    viz = _viz(top.optional_table("viz"), base)
    perception = _perception(top.optional_table("perception"), base, source, camera, file)
    top.finish()
    if runtime.staleness_frames is not None and "staleness_frames" in explicit:
        raise NodeConfigError(file, "runtime.staleness_frames", "and tracker.staleness_frames are "
                              "both set: set one")
    return NodeConfig(file=path, node=node, network=network, neighbours=tuple(sorted(seen)),
                      zenoh=zenoh_s, runtime=runtime, source=source, tracker=tracker,
                      ablation=ablation, tracker_explicit=explicit, camera=camera, output=output,
                      faults=faults, viz=viz, perception=perception)


def _endpoints(t: Table, key: str, listen: bool) -> tuple[str, ...]:
    v = t.list(key, [])
    for i, e in enumerate(v):
        why = endpoint_problem(e, listen=listen)
        if why is not None:
            raise t.error(f"{key}[{i}]", f"must be {ENDPOINT_HINT}, got {e!r} ({why})")
    return tuple(v)


def _zenoh(t: Table | None, base: Path) -> ZenohSettings:
    if t is None:
        return ZenohSettings()
    listen = _endpoints(t, "listen", True)
    connect = _endpoints(t, "connect", False)
    scouting = t.boolean("scouting", False)
    gossip = t.boolean("gossip", False)
    lease = t.integer("lease_ms", None, lo=1)
    cf = t.path("config_file", base, None)
    if cf is not None and not cf.is_file():
        raise t.error("config_file", f"names a file that does not exist: {cf}")
    shm = t.boolean("shared_memory", False)
    t.finish()
    return ZenohSettings(listen, connect, scouting, gossip, lease, cf, shm)


def _runtime(t: Table | None) -> RuntimeSettings:
    if t is None:
        return RuntimeSettings()
    d = RuntimeSettings()
    mode = t.string("mode", d.mode, choices=MODES)
    sync_timeout_s = t.number("sync_timeout_s", d.sync_timeout_s, lo=0, lo_open=True)
    startup_timeout_s = t.number("startup_timeout_s", d.startup_timeout_s, lo=0, lo_open=True)
    fps = t.number("fps", d.fps, lo=0)
    frames = t.integer("frames", None, lo=1)
    # the event trigger's own rules (core/trigger.py) check heartbeat_frames and drift_m
    trigger = t.built(lambda: build(TriggerConfig, {
        "heartbeat_frames": t.raw("heartbeat_frames", d.heartbeat_frames),
        "drift": t.raw("drift_m", d.drift_m), "gain": t.raw("gain_nats", d.gain_nats)}, t.where),
        keys={"drift": "drift_m", "gain": "gain_nats"})
    staleness_frames = t.integer("staleness_frames", None, lo=0)
    stall_after_s = t.number("stall_after_s", d.stall_after_s, lo=0, lo_open=True)
    t.finish()
    return RuntimeSettings(mode, sync_timeout_s, startup_timeout_s, fps, frames,
                           trigger.heartbeat_frames, float(trigger.drift), staleness_frames,
                           gain_nats=float(trigger.gain), stall_after_s=stall_after_s)


def _source(t: Table, base: Path, node: int) -> SourceSettings:
    kind = t.string("kind")
    camera = t.integer("camera", node, lo=0)
    if kind in FRAME_KINDS:
        fields_ = parse_frame_source(t, kind, base)
        t.finish()
        return SourceSettings(kind, camera, **fields_)
    if kind == "det-file":
        p = t.path("path", base)
        if not p.exists():
            raise t.error("path", f"does not exist: {p}")
        cal = p / "calibration.json" if p.is_dir() else p
        if not cal.is_file():
            raise t.error("path", f"has no calibration.json: {p}")
        t.finish()
        return SourceSettings(kind, camera, path=cal)
    if kind not in plugin_kinds():
        kinds = ", ".join(repr(k) for k in (*SOURCE_KINDS, *plugin_kinds()))
        raise t.error("kind", f"must be one of {kinds}, got {kind!r} (other kinds are plug-ins: "
                      f"none is installed for it in the entry-point group {PLUGIN_GROUP!r})")
    try:
        plugin = source_plugin(kind)
    except SourceError as e:  # installed but broken
        raise t.error("kind", str(e)) from None
    options = plugin.parse(t, base)
    t.finish()
    return SourceSettings(kind, camera, options=options)


def _camera(t: Table | None) -> CameraSettings | None:
    if t is None:
        return None
    G = t.matrix("homography", 3, 3)
    P = t.matrix("projection", 3, 4) if t.has("projection") else None
    size = t.raw("image_size")
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
        raise t.error("image_size", f"must be [width, height] in pixels (positive integers), got {size!r}")
    ps = t.number("pixel_scale", 1.0, lo=0, lo_open=True)
    fps = t.number("fps", 25.0, lo=0, lo_open=True)
    upm = t.number("units_per_metre", None, lo=0, lo_open=True)
    t.finish()
    cam = CameraSettings(G, (size[0], size[1]), P, ps, fps, upm)
    try:
        cam.camera(0)
    except ValueError as e:  # GeometryError: singular homography ...
        raise t.error("homography", f"is not usable: {e}") from None
    return cam


def _tracker(t: Table | None) -> tuple[TrackerConfig, str, frozenset[str]]:
    if t is None:
        return TrackerConfig.for_ablation("dkf+lda+dtm"), "dkf+lda+dtm", frozenset()
    ablation = t.string("ablation", "dkf+lda+dtm", choices=CONFIG_NAMES)
    rest = {k: v for k, v in t.data.items() if k != "ablation"}
    try:  # the parameters' own rules (core/config.py) check the rest, unknown names too
        cfg = t.built(lambda: TrackerConfig.for_ablation(ablation, **rest))
    except TypeError as e:  # e.g. fixed_R not a list
        raise NodeConfigError(t.file, t.where, f"has a bad value ({e})") from None
    return cfg, ablation, frozenset(rest)


def _faults(t: Table | None, base: Path, node: int, neighbours: tuple[int, ...]) -> Path | None:
    """``[faults] file``, a fault plan checked as far as this node knows the network: its own
    links must be links to its neighbours (``edge_node/faults.py``)."""
    if t is None:
        return None
    f = t.path("file", base, None)
    t.finish()
    if f is not None:
        try:
            FaultPlan.load(f, Network.of_node(node, neighbours))
        except FaultPlanError as e:
            raise t.error("file", f"is not a usable fault plan: {e}") from None
    return f


def _viz(t: Table | None, base: Path) -> VizSettings:
    if t is None:
        return VizSettings()
    try:
        spec = parse_spec(t.string("rerun", "off"))
    except VizSpecError as e:
        raise t.error("rerun", str(e)) from None
    if spec.kind == "save" and not Path(spec.arg).expanduser().is_absolute():
        spec = type(spec)("save", str(base / Path(spec.arg).expanduser()))
    rid = t.string("recording_id", None)
    if rid is not None and not rid.strip():
        raise t.error("recording_id", "must be a non-empty string")
    blueprint = t.boolean("blueprint", True)
    area = None
    if t.has("area"):
        a = t.list("area")
        if len(a) != 4:
            raise t.error("area", f"must be [xmin, xmax, ymin, ymax], got {a!r}")
        area = tuple(t.check_number(f"area[{i}]", v) for i, v in enumerate(a))
        if not (area[0] < area[1] and area[2] < area[3]):
            raise t.error("area", f"must have xmin < xmax and ymin < ymax, got {a!r}")
    t.finish()
    return VizSettings(str(spec), rid, blueprint, area)


def _perception(t: Table | None, base: Path, source: SourceSettings,
                camera: CameraSettings | None, file: str):
    """``[perception]`` (frame sources only; edge_node/perception/settings.py)."""
    if source.kind not in FRAME_KINDS:
        if t is not None:
            raise t.error(None, f"applies to frame sources ({', '.join(FRAME_KINDS)}), "
                          f"not to source kind {source.kind!r}")
        return None
    if camera is None and source.kind != "epfl":
        raise NodeConfigError(file, "camera", f"is required for source "
                              f"kind {source.kind!r}: the image-to-ground homography (see "
                              "docs/perception.md, edge_node calibrate)")
    return parse_perception(t, base) if t is not None else PerceptionSettings()


def _output(t: Table | None, base: Path) -> OutputSettings:
    if t is None:
        return OutputSettings()
    d = t.path("dir", base, None)
    interval = t.number("status_interval_s", 1.0, lo=0, lo_open=True)
    rotate = t.number("rotate_mb", None, lo=0, lo_open=True)
    keep = t.integer("keep", 5, lo=0)
    t.finish()
    return OutputSettings(d, interval, rotate, keep)
