"""``sim_cluster``: run camera networks in one process (reference runs, experiments, benchmarks).

    sim_cluster run --scenario terrace-sim --topology ring --config dkf+lda+dtm --seed 0 --out DIR
    sim_cluster bench
    sim_cluster scenarios
    sim_cluster export-detections --scenario terrace-sim --out DIR
    sim_cluster up --topology chain [--detach]; status | kill N | restart N | down
    sim_cluster ablation --scenarios terrace-sim,lab-sim --seeds 0-4 --out DIR
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from edge_node.core.config import ABLATIONS, ConfigError, TrackerConfig
from edge_node.settings import SettingsError, Table, read_toml


class CliError(Exception):
    """A user error: printed as one line, exit status 2."""


def _scenario(args):
    from sim_cluster.scenario import ScenarioError, load_scenario

    try:
        return load_scenario(args.scenario, seed=args.seed, frames=args.frames,
                             data_root=getattr(args, "data_root", None))
    except (ScenarioError, OSError) as e:
        raise CliError(str(e)) from None


def _tracker_config(args) -> TrackerConfig:
    """``--config`` (an ablation) with ``--tracker-config FILE`` (a ``[tracker]`` table, or a
    file holding only tracker parameters) over it."""
    try:
        base = TrackerConfig.for_ablation(args.config)
    except ConfigError as e:
        raise CliError(str(e)) from None
    if not getattr(args, "tracker_config", None):
        return base
    path = Path(args.tracker_config)
    raw = read_toml(path, file=str(path), what="tracker config")
    t = Table(raw.get("tracker", raw), str(path), "tracker")
    return t.built(lambda: TrackerConfig.from_dict({**base.to_dict(), **t.data}))


def run_once(data, topology: str, cfg: TrackerConfig, *, order=None, show_progress: bool = False,
             evaluate: bool = True, ground_threshold_m: float = 1.0, mode: str = "sync",
             faults=None):
    """One in-process run plus its evaluation; returns ``(RunResult, summary dict)``."""
    from edge_node.faults import NO_FAULTS

    from sim_cluster import topology as topo
    from sim_cluster.network import CENTRALIZED, run_network
    from sim_cluster.progress import progress_bar

    adj = CENTRALIZED if topology == CENTRALIZED else topo.build(topology, data.num_cameras, order)
    update, close = progress_bar(f"{data.name} {topology}", data.frames, show_progress)
    try:
        result = run_network(data, adj, cfg, topology_name=Path(topology).stem
                             if topology not in topo.NAMES + (CENTRALIZED,) else topology,
                             progress=update, mode=mode, faults=faults or NO_FAULTS)
    finally:
        close()
    summary = result.summary()
    if order is not None:
        summary["order"] = list(order)
    if evaluate:
        from sim_cluster.evaluation import evaluate as ev

        summary["metrics"] = ev(result.tracks, data, ground_threshold_m=ground_threshold_m)
    return result, summary


def cmd_run(args) -> int:
    from sim_cluster.report import run_table
    from edge_node.formats.tracks import write_tracks

    rerun = _rerun_spec(args)
    data = _scenario(args)
    cfg = _tracker_config(args)
    faults = None
    if args.faults:
        from edge_node.faults import FaultPlan, FaultPlanError

        try:
            faults = FaultPlan.load(args.faults)
        except FaultPlanError as e:
            raise CliError(str(e)) from None
    result, summary = run_once(data, args.topology, cfg, show_progress=not args.quiet,
                               ground_threshold_m=args.ground_threshold, mode=args.mode,
                               faults=faults)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for node, frames in result.tracks.items():
        write_tracks(out / f"tracks_node{node}.csv", frames)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True))
    print(run_table(summary))
    print(f"wrote {out}/summary.json and {len(result.tracks)} track files")
    if rerun.enabled:
        from sim_cluster.viz import VizError, record_run

        try:
            record_run(rerun, result, data)
        except VizError as e:
            raise CliError(str(e)) from None
    return 0


def _rerun_spec(args):
    """``--rerun`` checked before any work (Rerun itself is imported only when it is used)."""
    from sim_cluster.viz import VizError, spec_from_args

    try:
        return spec_from_args(getattr(args, "rerun", None))
    except VizError as e:
        raise CliError(str(e)) from None


def _rerun_arg(sp) -> None:
    sp.add_argument("--rerun", nargs="+", default=None, metavar="MODE",
                    help="Rerun view: off (default) | spawn | connect [ADDR] | save FILE.rrd | "
                         "serve [PORT]; all nodes in one recording")


def cmd_export(args) -> int:
    from sim_cluster.detfiles import export_detections

    data = _scenario(args)
    path = export_detections(data, Path(args.out),
                             descriptor_dtype="float32" if args.float32 else "float16")
    print(f"wrote {data.num_cameras} cameras x {data.frames} frames to {args.out} "
          f"(replay: sim_cluster run --scenario {path})")
    return 0


def _cluster(name: str):
    def cmd(args) -> int:
        from sim_cluster import cluster

        try:
            return getattr(cluster, name)(args)
        except cluster.ClusterError as e:
            raise CliError(str(e)) from None
    return cmd


def cmd_fault_report(args) -> int:
    from sim_cluster.faultreport import main as report_main

    return report_main(args)


def cmd_scenarios(args) -> int:
    from sim_cluster.scenario import list_presets

    for name in list_presets():
        print(name)
    return 0


def cmd_bench(args) -> int:
    from sim_cluster.bench import main as bench_main

    return bench_main(args)


def cmd_bench_cluster(args) -> int:
    from sim_cluster.bench_cluster import main as bench_cluster_main
    from sim_cluster.cluster import ClusterError

    try:
        return bench_cluster_main(args)
    except ClusterError as e:
        raise CliError(str(e)) from None


def cmd_ablation(args) -> int:
    from sim_cluster.ablation import AblationError, main as ablation_main

    try:
        return ablation_main(args)
    except AblationError as e:
        raise CliError(str(e)) from None


def _source_args(sp) -> None:
    """``up --source video``: every node runs from its camera's rendered frames
    (sim_cluster/render.py, edge_node/perception)."""
    sp.add_argument("--source", default="scenario", choices=("scenario", "video"),
                    help="scenario: each node replays the scenario's simulated detections; "
                         "video: render each camera's frames, nodes run detector + re-id on them")
    sp.add_argument("--detector", default="mog2", choices=("mog2", "hog", "onnx"),
                    help="--source video: the people detector (default mog2)")
    sp.add_argument("--reid", default="histogram",
                    choices=("histogram", "osnet_x1_0", "osnet_x0_25", "none"),
                    help="--source video: the appearance descriptor (default histogram)")
    sp.add_argument("--reid-weights", default=None, help="torchreid checkpoint for --reid osnet_*")
    sp.add_argument("--onnx-model", default=None, help="ONNX person detector for --detector onnx")


def cmd_render(args) -> int:
    from sim_cluster.render import render_scenario

    info = render_scenario(args.scenario, Path(args.out), seed=args.seed, frames=args.frames,
                           fmt="png" if args.png else "avi", noise=args.noise)
    for c, v in info["cameras"].items():
        print(f"camera {c}: {v['frames']} (background {v['background']})")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sim_cluster", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)

    def scenario_args(sp, frames_help="frames to run (default: the scenario's)"):
        sp.add_argument("--scenario", default="terrace-sim",
                        help="preset name (sim_cluster scenarios) or path to a scenario TOML")
        sp.add_argument("--seed", type=int, default=0)
        sp.add_argument("--frames", type=int, default=None, help=frames_help)
        sp.add_argument("--data-root", default=None,
                        help="folder holding epfl_pom/ (default: $DMTT_DATA or ../shared/data)")

    r = sub.add_parser("run", help="run a network in one process and evaluate it")
    scenario_args(r)
    r.add_argument("--topology", default="ring",
                   help="complete | ring | chain | disconnected | star | centralized | edge-list file")
    r.add_argument("--config", default="dkf+lda+dtm", choices=ABLATIONS)
    r.add_argument("--tracker-config", default=None, help="TOML file overriding tracker parameters")
    r.add_argument("--ground-threshold", type=float, default=1.0,
                   help="ground matching threshold in metres (default 1)")
    r.add_argument("--mode", default="sync", choices=("sync", "async"),
                   help="sync: fuse frame-k messages at k; async: event-triggered, latest messages")
    r.add_argument("--faults", default=None, help="fault plan TOML (loss, delay, partitions, crashes)")
    r.add_argument("--out", default="runs/latest")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    _rerun_arg(r)
    r.set_defaults(func=cmd_run)

    u = sub.add_parser("up", help="start one edge_node process per camera on loopback (Zenoh)")
    scenario_args(u)
    u.add_argument("--topology", default="chain",
                   help="complete | ring | chain | disconnected | star | edge-list file")
    u.add_argument("-n", "--nodes", type=int, default=None,
                   help="number of nodes (default: one per camera of the scenario)")
    u.add_argument("--mode", default="sync", choices=("sync", "async"))
    u.add_argument("--config", default="dkf+lda+dtm", choices=ABLATIONS)
    u.add_argument("--network", default="sim", help="network name (a Zenoh key chunk)")
    u.add_argument("--out", default="runs/cluster")
    u.add_argument("--detach", action="store_true", help="return once the processes run")
    u.add_argument("--sync-timeout", type=float, default=1.0,
                   help="sync mode: seconds frame k waits for a live neighbour")
    u.add_argument("--startup-timeout", type=float, default=30.0,
                   help="seconds a node waits for its neighbours at start-up")
    u.add_argument("--faults", default=None,
                   help="fault plan TOML: link loss/delay/partitions applied by the nodes, "
                        "kills and restarts by the launcher")
    u.add_argument("--fps", type=float, default=None,
                   help="frame pacing (default: the scenario's fps in async mode, "
                        "as fast as possible in sync mode)")
    u.add_argument("--quiet", action="store_true")
    _rerun_arg(u)
    _source_args(u)
    u.set_defaults(func=_cluster("up"))
    for name, what in (("status", "list a cluster's nodes"), ("down", "stop every node")):
        c = sub.add_parser(name, help=what)
        c.add_argument("--out", default="runs/cluster")
        c.set_defaults(func=_cluster(name))
    for name, what in (("kill", "SIGKILL one node (a crash)"), ("restart", "start a node again")):
        c = sub.add_parser(name, help=what)
        c.add_argument("node", type=int)
        c.add_argument("--out", default="runs/cluster")
        c.set_defaults(func=_cluster(name))

    fr = sub.add_parser("fault-report", help="standard faults (kill, restart, loss, delay, "
                        "partition) against the fault-free run")
    scenario_args(fr)
    fr.add_argument("--out", default="runs/faults")
    fr.add_argument("--quiet", action="store_true")
    fr.set_defaults(func=cmd_fault_report)

    e = sub.add_parser("export-detections",
                       help="write a scenario's detections (det.txt + .npy), truth and calibration")
    scenario_args(e)
    e.add_argument("--out", required=True, help="folder to write (one c<i>/ per camera)")
    e.add_argument("--float32", action="store_true", help="descriptors as float32 (default float16)")
    e.set_defaults(func=cmd_export)

    rd = sub.add_parser("render", help="render each camera's frames of a synthetic scenario "
                        "(MJPG .avi or PNG folders, plus the empty background)")
    scenario_args(rd)
    rd.add_argument("--out", required=True, help="folder to write")
    rd.add_argument("--png", action="store_true", help="PNG folders c<i>/ instead of c<i>.avi")
    rd.add_argument("--noise", type=float, default=2.0, help="sensor noise sigma (grey levels)")
    rd.set_defaults(func=cmd_render)

    s = sub.add_parser("scenarios", help="list the scenario presets")
    s.set_defaults(func=cmd_scenarios)

    b = sub.add_parser("bench", help="time prepare+update per node per frame; bytes per tracker")
    b.add_argument("--targets", default="5,20,50")
    b.add_argument("--neighbours", type=int, default=4)
    b.add_argument("--frames", type=int, default=60)
    b.add_argument("--repeats", type=int, default=3)
    b.set_defaults(func=cmd_bench)

    bc = sub.add_parser("bench-cluster", help="real clusters of N processes: frames/s, one-hop "
                        "latency, bytes per link (passive subscriber), start-up time")
    bc.add_argument("--nodes", default="4,8", help="comma-separated node counts (default 4,8)")
    bc.add_argument("--frames", type=int, default=300)
    bc.add_argument("--repeats", type=int, default=3)
    bc.add_argument("--topology", default="ring", help="complete | ring | chain | star")
    bc.add_argument("--scenario", default="ring8-sim", help="preset or scenario TOML with at "
                    "least max(--nodes) cameras (a node count N uses cameras 0..N-1)")
    bc.add_argument("--seed", type=int, default=0)
    bc.add_argument("--sync-timeout", type=float, default=10.0)
    bc.add_argument("--startup-timeout", type=float, default=60.0)
    bc.add_argument("--out", default="runs/bench-cluster")
    bc.set_defaults(func=cmd_bench_cluster)

    a = sub.add_parser("ablation", help="configs x topologies x seeds over scenarios (paper Fig. 3)")
    a.add_argument("--scenarios", default="terrace-sim,lab-sim,campus-sim,terrace-gt,campus-gt",
                   help="comma-separated presets or scenario files (missing data: skipped)")
    a.add_argument("--seeds", default="0-4", help="e.g. 0-4 or 0,2,5 (default 0-4)")
    a.add_argument("--configs", default=",".join(ABLATIONS),
                   help=f"comma-separated, from {', '.join(ABLATIONS)} (default: all)")
    a.add_argument("--topologies", default="complete,ring,chain,disconnected,centralized",
                   help="comma-separated: complete, ring, chain, disconnected, star, centralized")
    a.add_argument("--orderings", type=int, default=3,
                   help="distinct camera orderings per ring / chain, averaged per seed (default 3)")
    a.add_argument("--frames", type=int, default=None, help="frames per run (default: the scenario's)")
    a.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    a.add_argument("--data-root", default=None,
                   help="folder holding epfl_pom/ (default: $DMTT_DATA or ../shared/data)")
    a.add_argument("--out", default="runs/ablation")
    a.add_argument("--quiet", action="store_true", help="no progress")
    a.set_defaults(func=cmd_ablation)
    return p


def _input_errors() -> tuple[type[BaseException], ...]:
    """Errors that mean "your input is wrong" (a message, not a traceback)."""
    from edge_node.core.config import ConfigError
    from edge_node.faults import FaultPlanError
    from edge_node.geometry import GeometryError
    from sim_cluster.appearance import AppearanceError
    from sim_cluster.detector_model import DetectorParamsError
    from sim_cluster.detfiles import DetFilesError
    from sim_cluster.epfl import EpflFormatError
    from sim_cluster.scenario import ScenarioError
    from sim_cluster.topology import TopologyError
    from sim_cluster.world import WorldError
    from sim_cluster.render import RenderError

    return (CliError, SettingsError, ConfigError, FaultPlanError, GeometryError, AppearanceError,
            DetectorParamsError, DetFilesError, EpflFormatError, ScenarioError, TopologyError,
            WorldError, RenderError, OSError)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except _input_errors() as e:
        print(f"sim_cluster: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sim_cluster: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
