"""The camera configs of a cluster's nodes (``edge_node/runtime/config.py`` schema), as
``sim_cluster up`` and the cluster benchmark write them: one listen endpoint per node and
connects on both ends of every link, the scenario (or a det-files folder, or a rendered video)
as the source, the tracker configuration and the output folder.
"""
from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.geometry import Camera
from edge_node.perception.reid import REID
from sim_cluster.cluster.state import ClusterState


def _toml_str(v: str) -> str:
    return json.dumps(v)  # a JSON string is a valid TOML basic string


def node_config(i: int, state: ClusterState, ports: dict[int, int], *, config: str,
                sync_timeout_s: float, startup_timeout_s: float, fps: float = 0.0,
                faults: Path | None = None, source_toml: str | None = None,
                connect_first: Sequence[str] = (), tracker: dict | None = None,
                status_interval_s: float = 0.5) -> str:
    """The TOML of node ``i`` (schema: ``edge_node/runtime/config.py``). ``source_toml``: its
    ``[source]`` body and further tables (frames rendered for its camera), instead of the
    scenario; ``connect_first``: endpoints connected before the neighbours' (a monitor);
    ``tracker``: ``TrackerConfig`` fields set beside the ablation (e.g. ``scope_hops``);
    ``status_interval_s``: how often the node rewrites its status file."""
    neighbours = state.adjacency[str(i)]
    listen = [f"tcp/127.0.0.1:{ports[i]}"]
    connect = [*connect_first, *(f"tcp/127.0.0.1:{ports[j]}" for j in neighbours)]
    scenario = state.scenario
    src = Path(scenario)
    lines = [
        f"# node {i} of a {len(ports)}-node {state.topology} cluster (written by sim_cluster up)",
        f"node = {i}",
        f"network = {_toml_str(state.network)}",
        f"neighbours = {neighbours}",
        "",
        "[zenoh]",
        f"listen = {json.dumps(listen)}",
        f"connect = {json.dumps(connect)}",
        "lease_ms = 1000",
        "",
        "[runtime]",
        f"mode = {_toml_str(state.mode)}",
        f"sync_timeout_s = {sync_timeout_s}",
        f"startup_timeout_s = {startup_timeout_s}",
        f"fps = {float(fps)}",
        "",
        "[source]",
    ]
    if state.frames is not None:
        lines.insert(lines.index("[source]") - 1, f"frames = {state.frames}")
    if source_toml is not None:  # frames rendered for this camera (video_source_toml)
        lines += source_toml.splitlines()
    elif src.is_dir() or src.suffix == ".json":  # an exported detections folder
        lines += ['kind = "det-file"', f"path = {_toml_str(str(src.resolve()))}", f"camera = {i}"]
    else:  # the scenario itself, regenerated in the process: identical detections
        name = str(src.resolve()) if src.suffix == ".toml" else scenario
        lines += ['kind = "scenario"', f"scenario = {_toml_str(name)}", f"seed = {state.seed}",
                  f"camera = {i}"]
        if state.frames is not None:
            lines.append(f"frames = {state.frames}")
        if state.data_root:
            lines.append(f"data_root = {_toml_str(state.data_root)}")
    if faults is not None:
        lines += ["", "[faults]", f"file = {_toml_str(str(faults))}"]
    lines += ["", "[tracker]", f"ablation = {_toml_str(config)}",
              *(f"{k} = {json.dumps(v)}" for k, v in sorted((tracker or {}).items())), "", "[output]",
              f"dir = {_toml_str(str(Path(state.out) / 'nodes'))}",
              f"status_interval_s = {float(status_interval_s)}", ""]
    return "\n".join(lines)


def _toml_matrix(m) -> str:
    return "[" + ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]"
                           for row in np.asarray(m, float)) + "]"


def _toml_value(v: Any) -> str:
    if isinstance(v, Path):
        v = str(v.resolve())
    return json.dumps(v)  # strings, numbers, booleans and lists of them read back as TOML


def _options_table(name: str, options: Mapping[str, Any]) -> list[str]:
    return ["", f"[perception.{name}]", *(f"{k} = {_toml_value(v)}" for k, v in options.items())]


def video_source_toml(camera: Camera, video: str | Path, background: str | Path | None, *,
                      detector: str = "mog2", reid: str = "histogram",
                      detector_options: Mapping[str, Any] | None = None,
                      reid_options: Mapping[str, Any] | None = None,
                      units_per_metre: float = 1.0) -> str:
    """The ``[source]`` body, ``[camera]`` and ``[perception]`` tables of a node that runs from a
    rendered video (what ``sim_cluster up --source video`` writes; schema in
    ``edge_node/perception/settings.py``). ``detector_options`` go to the detector's table
    ``[perception.<detector>]``, ``reid_options`` to the re-id kind's table (``osnet`` for every
    OSNet variant); a ``Path`` is written absolute. MOG2 also gets the rendered empty scene
    (``background``) and a slow learning rate, so people who pause stay foreground."""
    lines = ['kind = "video"', f"path = {json.dumps(str(Path(video).resolve()))}", "",
             "[camera]",
             f"homography = {_toml_matrix(camera.G)}"]
    if camera.P is not None:
        lines.append(f"projection = {_toml_matrix(camera.P)}")
    lines += [f"image_size = [{int(camera.image_size[0])}, {int(camera.image_size[1])}]",
              f"pixel_scale = {float(camera.pixel_scale)!r}", f"fps = {float(camera.fps)!r}",
              f"units_per_metre = {float(units_per_metre)!r}", "",
              "[perception]", f"detector = {json.dumps(detector)}", f"reid = {json.dumps(reid)}"]
    det = dict(detector_options or {})
    if detector == "mog2":  # the simulator knows its scene: start MOG2 from the empty one
        det = {"learning_rate": 0.001, **det}
        if background is not None:
            det.setdefault("background", Path(background))
    if det:
        lines += _options_table(detector, det)
    table = REID.get(reid).table
    if table is not None:
        lines += _options_table(table, {"threads": 1, **(reid_options or {})})
    return "\n".join(lines)
