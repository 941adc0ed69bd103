"""Rerun recordings of whole networks: ``sim_cluster run --rerun ...`` and ``up --rerun ...``.

``run`` (in process) logs the finished run in one pass: every node's tracks, measurements and
active trackers, the cameras, the ground truth and the cross-node disagreement, all into one
recording. ``up`` lets every ``edge_node`` process log itself (``[viz]`` in its config, one
shared recording id) and logs the world-level entities from the launcher: area, ground truth,
and after the run the disagreement computed from the nodes' track files. With ``save`` each
process writes its own file and the launcher merges them into the one file the user named
(``rerun rrd merge``); with ``spawn`` / ``serve`` the launcher owns the viewer / server and the
nodes connect to it; with ``connect`` everybody connects to the given address.

Entity layout and the sink itself: ``edge_node/viz/rerun_log.py``.
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import numpy as np

from edge_node.formats.tracks import read_tracks
from edge_node.runtime.output import tracks_path
from edge_node.viz import VizSpec, VizSpecError, disagreement, ground_points, parse_spec
from edge_node.viz.rerun_log import DEFAULT_GRPC_PORT, make_blueprint, make_sink
from sim_cluster.cluster.processes import free_ports
from sim_cluster.cluster.state import ClusterError


class VizError(ClusterError):
    """A Rerun option that cannot be honoured; the message says why."""


def spec_from_args(value) -> VizSpec:
    """``--rerun`` tokens (or None) to a spec; errors name the option."""
    try:
        return parse_spec(value)
    except VizSpecError as e:
        raise VizError(f"--rerun {e}") from None


def new_recording_id() -> str:
    return f"dmtt-{uuid.uuid4().hex[:12]}"


def log_world(sink, data, *, cameras: bool = True) -> None:
    sink.log_world(area=data.area, units_per_metre=data.units_per_metre,
                   cameras=data.cameras if cameras else ())


def log_truth(sink, data, frames: int) -> None:
    """Frames ``0..frames-1`` of ``data``'s ground truth (a scenario, streamed or not)."""
    for k in range(min(frames, data.frames)):
        f = data.frame(k)
        sink.log_truth(k, f.ids, f.xy)


def log_disagreement(sink, tracks: dict[int, list], frames: int) -> None:
    for k in range(frames):
        sink.log_disagreement(k, disagreement({n: fr[k] for n, fr in tracks.items()
                                               if k < len(fr)}))


def log_run(sink, result, data) -> None:
    """A finished in-process run: world, truth, every node's frames, the disagreement."""
    frames = result.frames
    log_world(sink, data)
    log_truth(sink, data, frames)
    per_node = sorted(result.tracks) == list(range(data.num_cameras))
    for node, fr in sorted(result.tracks.items()):
        cams = [data.cameras[node]] if per_node else list(data.cameras)
        for k in range(frames):
            tracks = fr[k] if k < len(fr) else []
            meas = [ground_points(c, data.detections[k][c.id]) for c in cams]
            xy = meas[0] if len(meas) == 1 else np.vstack(meas)
            sink.log_frame(k, tracks, node=node, measurements_xy=xy,
                           stats={"active_trackers": len(tracks)})
    log_disagreement(sink, result.tracks, frames)


def wait_for_interrupt(url: str) -> None:
    """``serve``: keep the server up for the browser until Ctrl-C (or SIGTERM)."""
    print(f"Rerun web viewer: {url}  (Ctrl-C to stop serving)", flush=True)
    done = threading.Event()
    old = {s: signal.signal(s, lambda *_: done.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        while not done.wait(0.5):
            pass
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def open_sink(spec: VizSpec, **kw):
    """``make_sink``; a Rerun that cannot start (port in use, no viewer binary, unwritable
    file) is a :class:`VizError`."""
    try:
        return make_sink(spec, **kw)
    except Exception as e:  # noqa: BLE001
        raise VizError(f"--rerun {spec}: Rerun could not start ({type(e).__name__}: {e})") from None


def record_run(spec: VizSpec, result, data) -> None:
    """``sim_cluster run --rerun SPEC``: log the finished run, then report where it went."""
    if not spec.enabled:
        return
    nodes = sorted(result.tracks)
    sink = open_sink(spec, recording_id=new_recording_id(),
                     blueprint=make_blueprint(nodes, area=data.area, cameras=data.cameras))
    try:
        log_run(sink, result, data)
    finally:
        sink.close()
    announce(spec, sink)


def announce(spec: VizSpec, sink) -> None:
    if spec.kind == "save":
        print(f"wrote the Rerun recording {spec.arg}; open it with: {rerun_command()} {spec.arg}")
    elif spec.kind == "serve":
        wait_for_interrupt(sink.url)


def rerun_command() -> str:
    """The viewer command of this environment (relative when under the working directory)."""
    exe = Path(sys.executable).parent / "rerun"
    if not exe.exists():
        return "rerun"
    try:
        return str(exe.relative_to(Path.cwd()))
    except ValueError:
        return str(exe)


def merge_rrd(parts: list[Path], dest: Path) -> None:
    """``rerun rrd merge`` of ``parts`` into ``dest`` (one recording: they share its id)."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "rerun_cli", "rrd", "merge", *map(str, parts), "-o", str(dest)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0 or not dest.exists():
        tail = "\n".join((r.stderr or r.stdout).splitlines()[-5:])
        raise VizError(f"could not merge the nodes' recordings into {dest}: {tail}")


class ClusterViz:
    """Rerun for ``sim_cluster up``: the nodes' ``[viz]`` tables and the launcher's own sink."""

    def __init__(self, spec: VizSpec, out: Path, nodes: int, data, *, detach: bool = False):
        if detach and spec.kind in ("save", "serve"):
            raise VizError(f"--rerun {spec.kind} needs the launcher until the end of the run: "
                           "drop --detach, or use --rerun spawn / connect ADDR")
        self.spec, self.out, self.n, self.data = spec, Path(out), nodes, data
        self.recording_id = new_recording_id()
        self.dir = self.out / "rerun"
        self.sink = None
        self.grpc_port = free_ports(1)[0] if spec.kind == "serve" else None

    @property
    def enabled(self) -> bool:
        return self.spec.enabled

    def node_spec(self, i: int) -> str:
        k = self.spec.kind
        if k == "save":
            return f"save {self.dir / f'node{i}.rrd'}"
        if k == "spawn":
            return f"connect rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy"
        if k == "serve":
            return f"connect rerun+http://127.0.0.1:{self.grpc_port}/proxy"
        return str(self.spec)  # connect ADDR

    def node_toml(self, i: int) -> str:
        """The ``[viz]`` table of node ``i`` (empty when off)."""
        if not self.enabled:
            return ""
        area = ", ".join(repr(float(v)) for v in self.data.area)
        return "\n".join(["", "[viz]", f"rerun = {json.dumps(self.node_spec(i))}",
                          f"recording_id = {json.dumps(self.recording_id)}",
                          "blueprint = false", f"area = [{area}]", ""])

    def open(self) -> None:
        """Before the nodes start: the launcher's sink (``spawn`` starts the viewer, ``serve``
        the server the nodes then connect to); ``save`` first removes the previous run's
        recordings from ``<out>/rerun``."""
        if not self.enabled:
            return
        spec = self.spec
        if spec.kind == "save":
            self.dir.mkdir(parents=True, exist_ok=True)
            for f in self.dir.glob("*.rrd"):
                f.unlink()
            spec = VizSpec("save", str(self.dir / "world.rrd"))
        self.sink = open_sink(spec, recording_id=self.recording_id, grpc_port=self.grpc_port,
                              blueprint=make_blueprint(list(range(self.n)), area=self.data.area,
                                                       cameras=self.data.cameras))
        log_world(self.sink, self.data, cameras=False)  # each node logs its own camera

    def log_truth(self, frames: int) -> None:
        if self.sink is not None:
            log_truth(self.sink, self.data, frames)

    def finish(self, frames: int) -> None:
        """After the run: the disagreement (from the nodes' track files), close, merge
        (``save``), say where it is."""
        if self.sink is None:
            return
        tracks = {}
        for i in range(self.n):
            path = tracks_path(self.out / "nodes", i)
            if path.exists():
                tracks[i] = read_tracks(path, frames, camera=i)
        log_disagreement(self.sink, tracks, frames)
        self.sink.close()
        if self.spec.kind == "save":
            parts = [self.dir / "world.rrd"] + sorted(self.dir.glob("node*.rrd"))
            merge_rrd(parts, Path(self.spec.arg))
        announce(self.spec, self.sink)

    def close(self) -> None:
        """Without finishing (detach, errors): flush what the launcher logged."""
        if self.sink is not None:
            self.sink.close()
            self.sink = None
