"""``sim_cluster up`` and the commands that act on a running cluster: ``status``, ``kill``,
``restart``, ``down`` (the :class:`~sim_cluster.cluster.launcher.Cluster` does the work).

``up`` starts one ``edge_node`` process per camera, shows progress, waits, gathers every node's
tracks and wire counters, and evaluates them like ``sim_cluster run``. With ``--detach`` it
returns once the processes run; the other commands then reach the cluster through its state
file ``<out>/cluster.json``.
"""
from __future__ import annotations

import json
import sys
import tomllib
from pathlib import Path

from edge_node.faults import FaultPlan, Network
from edge_node.formats.calibration import CALIBRATION
from edge_node.perception.settings import parse_perception
from edge_node.settings import SettingsError, Table
from sim_cluster.cluster.configs import video_source_toml
from sim_cluster.cluster.launcher import Cluster
from sim_cluster.cluster.state import ClusterError, node_status
from sim_cluster.evaluation.report import latency_line, run_table
from sim_cluster.progress import progress_bar
from sim_cluster.scenarios.loader import stream_from_args
from sim_cluster.scenarios.synthetic.render import RenderError, ensure_rendered
from sim_cluster.viz import ClusterViz, spec_from_args


def up(args) -> int:
    """``sim_cluster up``. Everything the command line names (scenario, topology, fault plan,
    Rerun option, node configs) is checked before the first write to ``--out``, so a mistake
    leaves a previous run's files there as they were."""
    spec = spec_from_args(getattr(args, "rerun", None))  # --rerun (sim_cluster/viz.py)
    folder = Path(str(args.scenario))
    if folder.is_dir() and not (folder / CALIBRATION).is_file():
        raise ClusterError(f"{folder}: the nodes read det-files folders with {CALIBRATION}; "
                           f"convert this one first: sim_cluster import-detections {folder} "
                           "--out DIR (with --homographies, --image-size ... as run takes them)")
    data = stream_from_args(args)  # frames on demand: nothing is generated up front
    n = data.num_cameras if args.nodes is None else args.nodes
    if not 1 <= n <= data.num_cameras:
        raise ClusterError(f"--nodes {n}: scenario {data.name} has {data.num_cameras} cameras")
    data = data.first_cameras(n)
    cluster = Cluster.prepare(args.out, network=args.network, scenario=args.scenario,
                              seed=args.seed, frames=args.frames, mode=args.mode,
                              topology=args.topology, nodes=n, data_root=args.data_root)
    out = cluster.out
    plan = None
    faults_file = None
    if getattr(args, "faults", None):
        faults_file = Path(args.faults).resolve()
        adjacency = {int(i): v for i, v in cluster.state.adjacency.items()}
        plan = FaultPlan.load(faults_file, Network(adjacency, data.frames))
    viz = ClusterViz(spec, out, n, data, detach=bool(getattr(args, "detach", False)))
    # Pacing: a synchronous cluster runs in lock-step as fast as it can; an asynchronous one
    # never waits, so it plays frames at the cameras' rate (as real cameras deliver them).
    # Crashes and restarts happen in wall-clock time too (a process takes a second or two to
    # start), so a cluster whose fault plan kills nodes also plays at camera rate.
    realtime = args.mode == "async" or (plan is not None and bool(plan.nodes))
    fps = args.fps if args.fps is not None else (data.fps if realtime else 0.0)
    sources = video_sources(args, data, out, n)  # renders into out/video; removes nothing
    cluster.plan_configs(config=args.config, sync_timeout_s=args.sync_timeout,
                         startup_timeout_s=args.startup_timeout, fps=fps, faults=faults_file,
                         sources=sources, extra=viz.node_toml)
    cluster.reset()  # the first change to the previous run's files
    cluster.write_configs()
    try:
        viz.open()  # spawn / serve: the viewer or server the nodes connect to
        cluster.start()
        viz.log_truth(data.frames)
        if args.detach:
            viz.close()
            print(f"started {n} nodes ({args.topology}, {args.mode}) in {out}")
            print(f"  sim_cluster status --out {args.out}   |   sim_cluster down --out {args.out}")
            cluster.detach()  # they are the cluster's now, not this launcher's
            return 0
        frames = data.frames
        update, close = progress_bar(f"cluster {args.topology}", frames, not args.quiet)

        def progress(running: list[int]) -> None:
            done = [node_status(cluster.state, i).get("frames_done", 0) for i in running]
            update(min(done or [frames]), frames)

        try:
            cluster.wait(plan=plan, on_poll=progress)
        finally:
            close()
        summary = cluster.gather(data.materialise(), frames, args.config)
        (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True))
        print(run_table(summary))
        print(latency_line(summary))
        print(f"wrote {out}/summary.json, tracks and logs under {out}")
        viz.finish(frames)
        return 0
    except KeyboardInterrupt:
        print("sim_cluster: interrupted: stopping the cluster", file=sys.stderr)
        return 130
    finally:
        try:
            viz.close()
        finally:
            cluster.stop()  # anything still running that this launcher owns: end it


def video_sources(args, data, out: Path, n: int) -> dict[int, str] | None:
    """``up --source video``: render each camera's video into ``out/video`` (reused when
    already there) and return each node's source TOML; ``None`` for ``--source scenario``."""
    if getattr(args, "source", "scenario") != "video":
        return None
    detector = getattr(args, "detector", "mog2") or "mog2"
    reid = getattr(args, "reid", "histogram") or "histogram"
    det_opts = parse_options(getattr(args, "detector_option", None) or [], "--detector-option")
    if getattr(args, "onnx_model", None):  # the older spelling of --detector-option model=...
        det_opts.setdefault("model", Path(args.onnx_model))
    reid_opts = {"weights": Path(args.reid_weights)} if getattr(args, "reid_weights", None) else {}
    tomls = {i: video_source_toml(data.cameras[i], out / "video" / f"c{i}.avi", None,
                                  detector=detector, reid=reid, detector_options=det_opts,
                                  reid_options=reid_opts, units_per_metre=data.units_per_metre)
             for i in range(n)}
    check_perception(tomls[0])  # a missing model or weights file fails here, before rendering
    if not getattr(args, "quiet", False):
        print(f"rendering {n} camera videos of {data.name} ({data.frames} frames) into {out / 'video'}")
    info = ensure_rendered(args.scenario, out / "video", args.seed, data.frames,
                           cameras=list(range(n)))
    return {i: video_source_toml(data.cameras[i], info["cameras"][str(i)]["frames"],
                                 info["cameras"][str(i)]["background"], detector=detector,
                                 reid=reid, detector_options=det_opts, reid_options=reid_opts,
                                 units_per_metre=data.units_per_metre)
            for i in range(n)}


def parse_options(items: list[str], flag: str) -> dict:
    """``KEY=VALUE`` pairs of a repeated flag; each value read as TOML (``0.4``, ``true``,
    ``[640, 640]``), else taken as a string (a path)."""
    out: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise RenderError(f"{flag} {item!r}: expected KEY=VALUE")
        try:
            out[key.strip()] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = value
    return out


def check_perception(source_toml: str) -> None:
    """Read a generated node's ``[perception]`` with the node's own reader: a bad option, a
    missing required one or a file that is not there is a RenderError naming the flag that
    sets it."""
    data = tomllib.loads(source_toml)
    p = data.get("perception", {})
    try:
        parse_perception(Table(p, "sim_cluster up", "perception"), Path.cwd())
    except SettingsError as e:
        table, _, key = (e.field or "").removeprefix("perception.").partition(".")
        if table and table == p.get("detector"):
            flag = f"--detector {table}", f"--detector-option {key or 'KEY'}=..."
        elif table:
            flag = f"--reid {p.get('reid')}", "--reid-weights FILE"
        else:
            raise RenderError(f"sim_cluster up: {e.message}") from None
        raise RenderError(f"{flag[0]}: {e.field} {e.message}; give it with {flag[1]}") from None


def status(args) -> int:
    print(Cluster.attach(args.out).status_table())
    return 0


def kill(args) -> int:
    pid = Cluster.attach(args.out).kill(args.node)
    print(f"killed node {args.node} (pid {pid})")
    return 0


def restart(args) -> int:
    pid = Cluster.attach(args.out).restart_node(args.node)
    print(f"restarted node {args.node} (pid {pid})")
    return 0


def down(args) -> int:
    stopped = Cluster.attach(args.out).down()
    print(f"stopped {stopped} node(s) of {args.out}")
    return 0
