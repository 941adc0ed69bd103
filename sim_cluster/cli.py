"""``sim_cluster``: run camera networks in one process (reference runs, experiments, benchmarks)
and as real processes on loopback.

    sim_cluster run --scenario terrace-sim --topology ring --config dkf+lda+dtm --seed 0 --out DIR
    sim_cluster bench [--cameras 4,16,64 --scope 0,1,2 --layout corridor]
    sim_cluster scenarios
    sim_cluster export-detections --scenario terrace-sim --out DIR
    sim_cluster import-detections DIR --homographies H.json --out DIR2
    sim_cluster check-scale --scenario DIR     # units_per_metre against the people in the data
    sim_cluster up --topology chain [--detach]; status | kill N | restart N | down
    sim_cluster ablation --scenarios terrace-sim,lab-sim --seeds 0-4 --out DIR
    sim_cluster bandwidth-sweep --out DIR     # bytes vs MOTA/IDF1 over the trigger's gain
    sim_cluster reid-sweep --scenarios terrace-sim,campus-sim --seeds 0-1 --out DIR
    sim_cluster bench-detectors               # recall/precision of MOG2 and ssdlite, rendered
    sim_cluster report [--check]              # the docs' tables from docs/results/*, CLI reference
"""
from __future__ import annotations

import argparse
import math
import sys

from edge_node.core.config import ABLATIONS, CONFIG_NAMES
from edge_node.formats.layouts import LAYOUTS
from edge_node.perception.detectors import DETECTORS
from edge_node.perception.reid import REID
from protocol.errors import DmttError
from protocol.keys import is_valid_network
from sim_cluster.cluster import commands as cluster
from sim_cluster.experiments import (ablation, bandwidth, bench, bench_cluster, faultreport,
                                     fuzz, probe, reid_sweep, run, soak, trust)
from sim_cluster.experiments import bench_detectors, report
from sim_cluster.network import topology as topo
from sim_cluster.scenarios import commands as scenarios
from sim_cluster.scenarios.scale import scale_doc

#: Errors that mean "your input is wrong": one line on stderr, exit status 2 (not a traceback).
#: Every error the project raises derives from the root (protocol/errors.py), so a new one needs
#: no entry here; every file reader's error is one (edge_node/formats/text.py: bytes that are not
#: UTF-8 too).
INPUT_ERRORS = (DmttError, OSError)


class _Parser(argparse.ArgumentParser):
    """A bad command line is one line on stderr naming the option, and exit status 2."""

    def error(self, message: str):
        sys.stderr.write(f"sim_cluster: error: {message}\n")
        raise SystemExit(2)


def integer(lo: int):
    """An argparse type: a whole number ``>= lo``."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            v = None
        if v is None or v < lo:
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}, got {text!r}")
        return v
    return parse


def number(lo: float, *, above: bool = False):
    """An argparse type: a finite number ``>= lo`` (``> lo`` when ``above``)."""
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not math.isfinite(v) or v < lo or (above and v == lo):
            raise argparse.ArgumentTypeError(
                f"must be a number {'>' if above else '>='} {lo:g}, got {text!r}")
        return v
    return parse


def integers(lo: int):
    """An argparse type: comma-separated whole numbers ``>= lo`` (at least one), kept as text."""
    one = integer(lo)

    def parse(text: str) -> str:
        parts = [t.strip() for t in text.split(",") if t.strip()]
        if not parts:
            raise argparse.ArgumentTypeError(f"must be integers >= {lo} like 5,20, got {text!r}")
        for t in parts:
            try:
                one(t)
            except argparse.ArgumentTypeError:
                raise argparse.ArgumentTypeError(f"must be integers >= {lo} like 5,20, got "
                                                 f"{text!r}") from None
        return text
    return parse


def network_name(text: str) -> str:
    """An argparse type: a network name (one Zenoh key chunk, ``protocol/keys.py``)."""
    if not is_valid_network(text):
        raise argparse.ArgumentTypeError("must be a non-empty name without '/', '*', '$', '?', "
                                         f"'#' or spaces (at most 64 bytes), got {text!r}")
    return text


def image_size(text: str) -> tuple[int, int]:
    """An argparse type: ``WxH`` in pixels, e.g. ``1920x1080``."""
    parts = text.lower().split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        w = h = 0
    if len(parts) != 2 or w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"must be WIDTHxHEIGHT in pixels like 1920x1080, got "
                                         f"{text!r}")
    return w, h


SCENARIO_FORMS = f"""\
--scenario accepts:
  a preset name               terrace-sim, lab-sim, ... (sim_cluster scenarios)
  corridor-<N>, grid-<N>      a generated layout with N cameras
  FILE.toml                   a scenario file ([source] kind synthetic, epfl-gt or det-files)
  DIR or DIR/calibration.json a det-files folder (export-detections or import-detections
                              writes one)
  DIR                         another tool's detection files, below

{LAYOUTS}

Without descriptors the run says so in one line and tracks by geometry only (configuration
dkf+lda+dtm becomes dkf+dtm, dkf+lda becomes dkf): duplicates merged by co-motion,
re-identification by place."""


def _import_args(sp) -> None:
    """The options of a folder of another tool's detection files (``SCENARIO_FORMS``)."""
    g = sp.add_argument_group("another tool's detection files (a folder without calibration.json)")
    g.add_argument("--homographies", default=None, metavar="FILE",
                   help="image-to-ground homographies, .json / .npy / .npz (default: "
                        "DIR/homographies.*)")
    g.add_argument("--ground-truth", default=None, metavar="FILE",
                   help="ground truth frame,id,X,Y (or frame,id,X,Y,w,h) in ground units "
                        "(default: DIR/gt_ground.csv, else from the cameras' gt boxes)")
    g.add_argument("--units-per-metre", type=number(0, above=True), default=None, metavar="U",
                   help="ground units per metre (default: the homographies JSON's, else 1; "
                        "sim_cluster check-scale estimates it)")
    g.add_argument("--fps", dest="fps_override", type=number(0, above=True), default=None,
                   metavar="FPS",
                   help="frame rate (default: seqinfo.ini, the JSON's, else 25)")
    g.add_argument("--image-size", type=image_size, default=None, metavar="WxH",
                   help="image size of every camera (default: seqinfo.ini or the JSON's)")


def _rerun_arg(sp) -> None:
    sp.add_argument("--rerun", nargs="+", default=None, metavar="MODE",
                    help="Rerun view: off (default) | spawn | connect [ADDR] | save FILE.rrd | "
                         "serve [PORT]; all nodes in one recording")


def _source_args(sp) -> None:
    """``up --source video``: every node runs from its camera's rendered frames
    (sim_cluster/scenarios/synthetic/render.py, edge_node/perception)."""
    sp.add_argument("--source", default="scenario", choices=("scenario", "video"),
                    help="scenario: each node replays the scenario's simulated detections; "
                         "video: render each camera's frames, nodes run detector + re-id on them")
    sp.add_argument("--detector", default="mog2", choices=DETECTORS.names(),
                    help="--source video: the people detector (default mog2)")
    sp.add_argument("--detector-option", action="append", default=None, metavar="KEY=VALUE",
                    help="--source video: an option of the detector's [perception.<detector>] "
                         "table (repeatable; the value is read as TOML, else as a string), e.g. "
                         "--detector-option tiles=2")
    sp.add_argument("--reid", default="histogram", choices=REID.names(),
                    help="--source video: the appearance descriptor (default histogram)")
    sp.add_argument("--reid-weights", default=None, help="torchreid checkpoint for --reid osnet_*")
    sp.add_argument("--onnx-model", default=None,
                    help="ONNX person detector for --detector onnx (= --detector-option model=FILE)")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="sim_cluster", description=__doc__,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)

    def scenario_args(sp, frames_help="frames to run (default: the scenario's)"):
        sp.add_argument("--scenario", default="terrace-sim",
                        help="preset name (sim_cluster scenarios), corridor-<N> / grid-<N>, a "
                             "scenario TOML, a det-files folder with calibration.json, or a "
                             "folder of another tool's MOTChallenge det files (sim_cluster run "
                             "--help lists every form)")
        sp.add_argument("--seed", type=integer(0), default=0)
        sp.add_argument("--frames", type=integer(1), default=None, help=frames_help)
        sp.add_argument("--data-root", default=None,
                        help="folder holding epfl_pom/ (default: $DMTT_DATA or ../shared/data)")

    r = sub.add_parser("run", help="run a network in one process and evaluate it",
                       epilog=SCENARIO_FORMS, formatter_class=argparse.RawDescriptionHelpFormatter)
    scenario_args(r)
    _import_args(r)
    r.add_argument("--topology", default="ring",
                   help=topo.help_text("centralized", "layout (a corridor-<N> / grid-<N> "
                                                      "scenario's lattice)"))
    r.add_argument("--config", default="dkf+lda+dtm", choices=CONFIG_NAMES)
    r.add_argument("--tracker-config", default=None, help="TOML file overriding tracker parameters")
    r.add_argument("--reid-rank1", type=number(0, above=True), default=None, metavar="R",
                   help="re-id quality of the simulated descriptors: cross-camera rank-1 in "
                        "(0, 1] with 20 people, 1 perfect (default: the scenario's [appearance]; "
                        "the presets' confuse look-alikes as a rank-1 of 0.8 does)")
    r.add_argument("--ground-threshold", type=number(0, above=True), default=1.0,
                   help="ground matching threshold in metres (default 1)")
    r.add_argument("--mode", default="sync", choices=("sync", "async"),
                   help="sync: fuse frame-k messages at k; async: event-triggered, latest messages")
    r.add_argument("--faults", default=None, help="fault plan TOML (loss, delay, partitions, crashes)")
    r.add_argument("--out", default="runs/run",
                   help="folder to write (default runs/run; make run's cluster writes runs/latest)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    _rerun_arg(r)
    r.set_defaults(func=run.main)

    u = sub.add_parser("up", help="start one edge_node process per camera on loopback (Zenoh)")
    scenario_args(u)
    u.add_argument("--topology", default="chain",
                   help=topo.help_text())
    u.add_argument("-n", "--nodes", type=integer(1), default=None,
                   help="number of nodes (default: one per camera of the scenario)")
    u.add_argument("--mode", default="sync", choices=("sync", "async"))
    u.add_argument("--config", default="dkf+lda+dtm", choices=CONFIG_NAMES)
    u.add_argument("--network", type=network_name, default="sim",
                   help="network name (a Zenoh key chunk)")
    u.add_argument("--out", default="runs/cluster")
    u.add_argument("--detach", action="store_true", help="return once the processes run")
    u.add_argument("--sync-timeout", type=number(0, above=True), default=1.0,
                   help="sync mode: seconds frame k waits for a live neighbour")
    u.add_argument("--startup-timeout", type=number(0, above=True), default=30.0,
                   help="seconds a node waits for its neighbours at start-up")
    u.add_argument("--faults", default=None,
                   help="fault plan TOML: link loss/delay/partitions applied by the nodes, "
                        "kills and restarts by the launcher")
    u.add_argument("--fps", type=number(0), default=None,
                   help="frame pacing (default: the scenario's fps in async mode, "
                        "as fast as possible in sync mode)")
    u.add_argument("--quiet", action="store_true")
    _rerun_arg(u)
    _source_args(u)
    u.set_defaults(func=cluster.up)
    for name, what in (("status", "list a cluster's nodes"), ("down", "stop every node")):
        c = sub.add_parser(name, help=what)
        c.add_argument("--out", default="runs/cluster")
        c.set_defaults(func=getattr(cluster, name))
    for name, what in (("kill", "SIGKILL one node (a crash)"), ("restart", "start a node again")):
        c = sub.add_parser(name, help=what)
        c.add_argument("node", type=int)
        c.add_argument("--out", default="runs/cluster")
        c.set_defaults(func=getattr(cluster, name))

    fr = sub.add_parser("fault-report", help="standard faults (kill, restart, loss, delay, "
                        "partition) against the fault-free run")
    scenario_args(fr)
    _import_args(fr)
    fr.add_argument("--out", default="runs/faults")
    fr.add_argument("--quiet", action="store_true")
    fr.set_defaults(func=faultreport.main)

    tr = sub.add_parser("trust-report", help="one faulty node (hijack, phantom, bumped, "
                        "hallucinate, stale, forged_merge) in a ring against the fault-free run: "
                        "honest nodes' MOTA/IDF1, far tracks, frames to quarantine, ids kept")
    tr.add_argument("--scenarios", default="terrace-sim,ring8-sim",
                    help="comma-separated presets (default terrace-sim,ring8-sim)")
    tr.add_argument("--seeds", default="0-2", help="e.g. 0-2 or 0,3 (default 0-2)")
    tr.add_argument("--kinds", default="", help="comma-separated faulty kinds (default: all)")
    tr.add_argument("--config", default="dkf+lda+dtm", choices=CONFIG_NAMES)
    tr.add_argument("--tracker-config", default=None, metavar="FILE",
                    help="TOML file overriding tracker parameters (every run)")
    tr.add_argument("--baseline", action="store_true",
                    help="also run every faulty kind with the trust role off")
    tr.add_argument("--baseline-from", default=None, metavar="FILE",
                    help="with --baseline: take the trust-off runs from an earlier trust.json")
    tr.add_argument("--jobs", type=integer(1), default=1, help="worker processes (default 1)")
    tr.add_argument("--out", default="docs/results/trust")
    tr.add_argument("--quiet", action="store_true")
    tr.set_defaults(func=trust.main)

    fz = sub.add_parser("fuzz", help="wire-valid hostile messages into two running nodes through "
                        "Zenoh: no crash, every rejection counted, tracks as without the attacker")
    fz.add_argument("--messages", type=integer(100), default=10_000,
                    help="hostile messages to send, at least (40 a frame, over at least 20 "
                         "frames, and a tenth more frames for a victim that falls behind: "
                         "--messages 100 sends 800)")
    fz.add_argument("--scenario", default="lab-sim")
    fz.add_argument("--fps", type=number(0, above=True), default=50.0, help="victims' pacing")
    fz.add_argument("--seed", type=integer(0), default=0)
    fz.add_argument("--out", default="runs/fuzz")
    fz.add_argument("--quiet", action="store_true")
    fz.set_defaults(func=fuzz.main)

    sk = sub.add_parser("soak", help="real processes at camera rate for minutes, with seeded "
                        "kills, restarts, freezes, loss and partitions: RSS, frame rate, "
                        "timeouts, rejections, exits and ground MOTA/IDF1 per minute (PNG + JSON)")
    sk.add_argument("--minutes", type=integer(1), default=30)
    sk.add_argument("-n", "--nodes", type=integer(2), default=4)
    sk.add_argument("--chaos", type=integer(0), default=None, metavar="SEED",
                    help="inject the seeded fault schedule (default: no faults)")
    sk.add_argument("--every", type=integer(1), default=3, help="minutes between faults")
    sk.add_argument("--scenario", default=None,
                    help="default: terrace-sim for <= 4 nodes, ring8-sim for <= 8")
    sk.add_argument("--topology", default="ring", help=topo.help_text() + " (default ring)")
    sk.add_argument("--config", default="dkf+lda+dtm", choices=CONFIG_NAMES)
    sk.add_argument("--fps", type=number(0, above=True), default=None,
                    help="camera rate (default: the scenario's)")
    sk.add_argument("--seed", type=integer(0), default=0)
    sk.add_argument("--no-reference", action="store_true",
                    help="skip the fault-free in-process run the MOTA check compares with")
    sk.add_argument("--out", default="runs/soak")
    sk.add_argument("--quiet", action="store_true")
    sk.set_defaults(func=soak.main)

    pr = sub.add_parser("probe", help="the zombie probes (freeze, full disk, kill -9 and "
                        "restarts, a phantom flood, a camera absent at boot) on real processes, "
                        "each against its goal (docs/faults.md)")
    pr.add_argument("kind", choices=probe.KINDS)
    pr.add_argument("--out", default="runs/probe", help="where probe_<kind>.json goes")
    pr.add_argument("--work", default=None,
                    help="where the probe's clusters run (default: --out)")
    pr.add_argument("--nodes", type=integer(2), default=4)
    pr.add_argument("--fps", type=number(0, above=True), default=25.0)
    pr.add_argument("--seconds", default="5,30,120,600",
                    help="freeze: how long to freeze, comma-separated seconds")
    pr.add_argument("--modes", default="sync,async", help="freeze: runtime modes")
    pr.add_argument("--kills", type=integer(1), default=30, help="restarts: how many kill -9")
    pr.add_argument("--phantoms", type=integer(1), default=4096, help="flood: trackers in it")
    pr.add_argument("--seed", type=int, default=0)
    pr.add_argument("--quiet", action="store_true")
    pr.set_defaults(func=probe.main)

    e = sub.add_parser("export-detections",
                       help="write a scenario's detections (det.txt + .npy), truth and calibration")
    scenario_args(e)
    e.add_argument("--out", required=True, help="folder to write (one c<i>/ per camera)")
    e.add_argument("--float32", action="store_true", help="descriptors as float32 (default float16)")
    e.add_argument("--no-descriptors", action="store_true",
                   help="no appearance: the detections of a detector without re-id")
    _import_args(e)
    e.set_defaults(func=scenarios.export)

    im = sub.add_parser("import-detections",
                        help="read another tool's detection files (MOTChallenge det.txt per "
                             "camera, homographies, ground truth) and write a det-files folder",
                        epilog=SCENARIO_FORMS,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    im.add_argument("source", help="the folder of detection files (layouts below)")
    im.add_argument("--out", required=True, help="det-files folder to write")
    im.add_argument("--frames", type=integer(1), default=None,
                    help="frames to import (default: up to the last frame in the files)")
    _import_args(im)
    im.set_defaults(func=scenarios.import_detections)

    cs = sub.add_parser("check-scale",
                        help="estimate units_per_metre from the people in a scenario (box "
                             "heights, walking speed) and warn when the declared value "
                             "disagrees by more than 20%%",
                        description=scale_doc())
    scenario_args(cs)
    _import_args(cs)
    cs.set_defaults(func=scenarios.check_scale)

    rd = sub.add_parser("render", help="render each camera's frames of a synthetic scenario "
                        "(MJPG .avi or PNG folders, plus the empty background)")
    scenario_args(rd)
    rd.add_argument("--out", required=True, help="folder to write")
    rd.add_argument("--png", action="store_true", help="PNG folders c<i>/ instead of c<i>.avi")
    rd.add_argument("--noise", type=number(0), default=2.0,
                    help="sensor noise sigma (grey levels)")
    rd.set_defaults(func=scenarios.render)

    s = sub.add_parser("scenarios", help="list the scenario presets")
    s.set_defaults(func=scenarios.scenarios)

    b = sub.add_parser("bench", help="time prepare+update per node per frame; bytes per tracker; "
                       "with --cameras: the scale sweep over generated layouts")
    b.add_argument("--targets", type=integers(0), default="5,20,50")
    b.add_argument("--neighbours", type=integer(0), default=4)
    b.add_argument("--frames", type=integer(1), default=None,
                   help="frames per run (default 60; with --cameras 300)")
    b.add_argument("--repeats", type=integer(1), default=3)
    b.add_argument("--cameras", type=integers(1), default=None,
                   help="scale sweep: comma-separated camera counts, e.g. 4,16,64 (scenarios "
                        "<layout>-<N>, 6.25 people per camera, the layout's neighbour graph)")
    b.add_argument("--scope", type=integers(0), default=None,
                   help="--cameras: regional scope hop limits to sweep, e.g. 0,1,2 (one row per "
                        "cameras x scope; 0 = every node holds every tracker; default: the "
                        "tracker config's scope_hops)")
    b.add_argument("--layout", default="corridor", choices=("corridor", "grid"),
                   help="--cameras: cameras in a line or on a square lattice (N a square)")
    b.add_argument("--seed", type=integer(0), default=0, help="--cameras: the scenario seed")
    b.add_argument("--config", default="dkf+lda+dtm", choices=CONFIG_NAMES)
    b.add_argument("--tracker-config", default=None, help="TOML file overriding tracker parameters")
    b.add_argument("--ground-threshold", type=number(0, above=True), default=1.0,
                   help="--cameras: ground matching threshold in metres (default 1)")
    b.add_argument("--long-walk-cameras", type=integer(1), default=4,
                   help="--cameras: a long walk crosses at least this many cameras' views")
    b.add_argument("--out", default="runs/bench-scale", help="--cameras: scale.json, scale.csv, scale.png")
    b.add_argument("--json", default=None, metavar="FILE",
                   help="without --cameras: also write the figures, the machine and the commit "
                        "to FILE (docs/results/bench/core.json is what the docs render)")
    b.add_argument("--quiet", action="store_true", help="no progress")
    b.set_defaults(func=bench.main)

    bc = sub.add_parser("bench-cluster", help="real clusters of N processes: frames/s, one-hop "
                        "latency, bytes per link (passive subscriber), start-up time")
    bc.add_argument("--nodes", default="4,8", help="comma-separated node counts (default 4,8)")
    bc.add_argument("--frames", type=integer(2), default=300)
    bc.add_argument("--repeats", type=integer(1), default=3)
    bc.add_argument("--topology", default="ring", help=topo.help_text() + " (default ring)")
    bc.add_argument("--scenario", default="ring8-sim", help="preset or scenario TOML with at "
                    "least max(--nodes) cameras (a node count N uses cameras 0..N-1)")
    bc.add_argument("--seed", type=integer(0), default=0)
    bc.add_argument("--sync-timeout", type=number(0, above=True), default=10.0)
    bc.add_argument("--startup-timeout", type=number(0, above=True), default=60.0)
    bc.add_argument("--fps", default="0", help="comma-separated pacings, frames/s per node; "
                    "0 = unpaced (default 0; e.g. 0,25)")
    bc.add_argument("--scope", type=integer(0), default=0,
                    help="the nodes' scope_hops (regional scope; default 0: every node holds "
                         "every tracker)")
    bc.add_argument("--faults", default=None, metavar="FILE",
                    help="fault plan TOML the nodes apply (e.g. a [[faulty]] node: the honest "
                         "nodes' frame rate during an attack)")
    bc.add_argument("--out", default="runs/bench-cluster")
    bc.set_defaults(func=bench_cluster.main)

    a = sub.add_parser("ablation", help="configs x topologies x seeds over scenarios (paper Fig. 3)")
    a.add_argument("--scenarios", default="terrace-sim,lab-sim,campus-sim,terrace-gt,campus-gt",
                   help="comma-separated presets or scenario files (missing data: skipped)")
    a.add_argument("--seeds", default="0-4", help="e.g. 0-4 or 0,2,5 (default 0-4)")
    a.add_argument("--configs", default=",".join(ABLATIONS),
                   help=f"comma-separated, from {', '.join(CONFIG_NAMES)} (default: the paper's "
                        f"{', '.join(ABLATIONS)})")
    a.add_argument("--topologies", default="complete,ring,chain,disconnected,centralized",
                   help="comma-separated: " + ", ".join(ablation.topology_names()))
    a.add_argument("--orderings", type=int, default=3,
                   help="distinct camera orderings per ring / chain, averaged per seed (default 3)")
    a.add_argument("--frames", type=int, default=None, help="frames per run (default: the scenario's)")
    a.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    a.add_argument("--data-root", default=None,
                   help="folder holding epfl_pom/ (default: $DMTT_DATA or ../shared/data)")
    a.add_argument("--out", default="runs/ablation")
    a.add_argument("--quiet", action="store_true", help="no progress")
    a.set_defaults(func=ablation.main)

    bw = sub.add_parser("bandwidth-sweep", help="bytes per frame against ground MOTA/IDF1 over "
                        "the async trigger's gain, sync as the reference (CSV, PNG, tables)")
    bw.add_argument("--scenarios", default=",".join(bandwidth.DEFAULT_SCENARIOS),
                    help="comma-separated presets or scenario files (missing data: skipped; "
                         f"default {','.join(bandwidth.DEFAULT_SCENARIOS)})")
    bw.add_argument("--topology", default="ring",
                    help=topo.help_text("centralized") + " (default ring)")
    bw.add_argument("--config", default=bandwidth.CONFIG, choices=CONFIG_NAMES)
    bw.add_argument("--gains", default=",".join(f"{g:g}" for g in bandwidth.DEFAULT_GAINS),
                    help="comma-separated trigger gains in nats for the async runs (default "
                         "%(default)s)")
    bw.add_argument("--late", default=",".join(f"{g:g}" for g in bandwidth.DEFAULT_LATE),
                    metavar="GAINS",
                    help="gains of the async runs with every message 1-4 frames late (default "
                         "%(default)s; none: skip them)")
    bw.add_argument("--seed", type=integer(0), default=0)
    bw.add_argument("--frames", type=integer(1), default=None,
                    help="frames per run (default: the scenario's)")
    bw.add_argument("--jobs", type=integer(1), default=1,
                    help="worker processes (default 1; runs take seconds each)")
    bw.add_argument("--data-root", default=None,
                    help="folder holding epfl_pom/ (default: $DMTT_DATA or ../shared/data)")
    bw.add_argument("--out", default="docs/results/bandwidth")
    bw.add_argument("--quiet", action="store_true", help="no progress")
    bw.set_defaults(func=bandwidth.main)
    rs = sub.add_parser("reid-sweep", help="tracking quality against re-id quality (rank-1 "
                        "from perfect to none): CSV, PNG, table")
    rs.add_argument("--scenarios", default=reid_sweep.DEFAULT_SCENARIOS,
                    help="comma-separated presets or scenario files that simulate descriptors "
                         f"(default {reid_sweep.DEFAULT_SCENARIOS})")
    rs.add_argument("--levels", default=reid_sweep.DEFAULT_LEVELS,
                    help="comma-separated cross-camera rank-1 levels in (0, 1] (with 20 people) "
                         f"and 'none' for no descriptors (default {reid_sweep.DEFAULT_LEVELS})")
    rs.add_argument("--seeds", default="0-1", help="e.g. 0-4 or 0,2,5 (default 0-1)")
    rs.add_argument("--topologies", "--topology", dest="topologies", default="ring",
                    help="comma-separated: " + " | ".join(ablation.topology_names())
                    + " (default ring)")
    rs.add_argument("--config", default="dkf+lda+dtm", choices=CONFIG_NAMES,
                    help="tracker configuration at the rank-1 levels ('none' drops appearance: "
                         "dkf+lda+dtm becomes dkf+dtm)")
    rs.add_argument("--tracker-config", default=None, metavar="FILE",
                    help="TOML file overriding tracker parameters (e.g. merge_appearance)")
    rs.add_argument("--frames", type=int, default=None,
                    help="frames per run (default: the scenario's)")
    rs.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    rs.add_argument("--out", default="docs/results/reid")
    rs.add_argument("--quiet", action="store_true", help="no progress")
    rs.set_defaults(func=reid_sweep.main)

    bd = sub.add_parser("bench-detectors", help="recall and precision of the people detectors "
                        "(MOG2, ssdlite) on rendered frames, their cost, and ssdlite's two "
                        "backends timed alternately (detectors.json)")
    bd.add_argument("--scenarios", default="terrace-sim,lab-sim,campus-sim",
                    help="comma-separated synthetic presets (default terrace-sim,lab-sim,campus-sim)")
    bd.add_argument("--frames", type=integer(2), default=200, help="frames rendered per camera")
    bd.add_argument("--stride", type=integer(1), default=10, help="score every N-th frame")
    bd.add_argument("--warmup", type=integer(0), default=20,
                    help="frames MOG2 sees before scoring starts")
    bd.add_argument("--iou", type=number(0, above=True), default=0.5,
                    help="IoU for a detection to match a person (default 0.5)")
    bd.add_argument("--rounds", type=integer(1), default=5,
                    help="alternating rounds timing the two ssdlite backends")
    bd.add_argument("--out", default="docs/results/perception")
    bd.add_argument("--quiet", action="store_true")
    bd.set_defaults(func=bench_detectors.main)

    rp = sub.add_parser("report", help="render the docs' results and benchmark tables from "
                        "their data files (docs/results/) and the CLI reference from these "
                        "parsers; --check: change nothing, exit 1 naming what is stale")
    rp.add_argument("--docs", default="docs", help="the docs folder (default docs)")
    rp.add_argument("--results", default=None, help="the data files (default DOCS/results)")
    rp.add_argument("--check", action="store_true",
                    help="exit 1 if a generated block differs from its data")
    rp.set_defaults(func=report.main)
    return p


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:  # --help (0), or a bad command line (2, reported by _Parser)
        return e.code if isinstance(e.code, int) else 2
    try:
        return args.func(args)
    except INPUT_ERRORS as e:
        print(f"sim_cluster: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sim_cluster: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
