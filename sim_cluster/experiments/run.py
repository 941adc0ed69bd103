"""``sim_cluster run``: a camera network in one process, evaluated; and :func:`run_once`, the
run plus evaluation every experiment (ablation, fault report) is made of.

The in-process run is the reference: the same core as the camera processes, fed by the
in-process network (``sim_cluster/network/inprocess.py``), deterministic from the scenario's
seed. ``run`` writes every node's track file (``edge_node/formats/tracks.py``) and
``summary.json`` and prints the per-node table (``sim_cluster/evaluation/report.py``).
"""
from __future__ import annotations

import json
from pathlib import Path

from edge_node.core.config import TrackerConfig
from edge_node.core.trigger import TriggerConfig
from edge_node.faults import NO_FAULTS, FaultPlan, FaultPlanError, Network
from edge_node.formats.tracks import write_tracks
from edge_node.settings import Table, read_toml
from sim_cluster.evaluation import metrics
from sim_cluster.evaluation.report import run_table
from sim_cluster.network import topology as topo
from sim_cluster.network.inprocess import CENTRALIZED, RunResult, run_network
from sim_cluster.progress import progress_bar
from sim_cluster.scenarios.data import ScenarioData
from sim_cluster.scenarios.loader import scenario_from_args
from sim_cluster.scenarios.scale import scenario_scale
from sim_cluster.viz import record_run, spec_from_args


#: ``--topology layout``: the scenario's neighbour graph (``ScenarioData.neighbours``)
LAYOUT = "layout"


def tracker_config(ablation: str, file: str | Path | None = None) -> TrackerConfig:
    """The ``ablation`` configuration (``dkf``, ``dkf+lda``, ``dkf+lda+dtm``) with the
    parameters of ``file`` over it: a ``[tracker]`` table, or a file of tracker parameters only.
    Errors name the file and the field (``edge_node/settings.py``)."""
    base = TrackerConfig.for_ablation(ablation)
    if not file:
        return base
    path = Path(file)
    raw = read_toml(path, file=str(path), what="tracker config")
    t = Table(raw.get("tracker", raw), str(path), "tracker")
    return t.built(lambda: TrackerConfig.for_ablation(ablation, **t.data))


def is_det_files(scenario: str) -> bool:
    """Whether ``--scenario`` names a det-files folder (or its calibration.json) or another
    tool's files: data whose ``units_per_metre`` a user declared, not a preset."""
    p = Path(str(scenario))
    return p.is_dir() or p.suffix == ".json"


def geometry_only(data: ScenarioData, cfg: TrackerConfig) -> tuple[TrackerConfig, str | None]:
    """Without a descriptor in any detection, ``cfg`` without appearance (``dkf+lda+dtm`` ->
    ``dkf+dtm``, ``dkf+lda`` -> ``dkf``: the summary names what ran) and the one line that says
    so; else ``cfg`` and None."""
    if data.has_descriptors():
        return cfg, None
    line = (f"{data.name}: no appearance descriptors in the detections: tracking by geometry "
            "only (duplicates merged by co-motion, re-identification by place)")
    if not cfg.use_appearance:
        return cfg, line
    new = cfg.with_(use_appearance=False)
    return new, line.replace("geometry only", f"geometry only, {cfg.ablation} -> {new.ablation}")


def load_faults(path: str | Path | None, data: ScenarioData, topology: str,
                order=None) -> FaultPlan | None:
    """The fault plan file ``path`` (None: no plan) checked against the network ``topology``
    builds on ``data``'s cameras and against its frames. The centralized baseline has no links
    and no camera nodes, so a plan with faults is an error there."""
    if not path:
        return None
    if topology == CENTRALIZED:
        plan = FaultPlan.load(path)
        if not plan.empty:
            raise FaultPlanError(str(path), None, "the centralized topology has no links or "
                                 "camera nodes to fault: pick another topology or drop --faults")
        return plan
    return FaultPlan.load(path, Network(adjacency(data, topology, order), data.frames))


def adjacency(data: ScenarioData, topology: str, order=None):
    """The network ``topology`` names on ``data``'s cameras: a name (``topology.TOPOLOGIES``),
    ``centralized``, ``layout`` (the scenario's own neighbour graph) or an edge-list file."""
    if topology == LAYOUT:  # the scenario's own neighbour graph (a generated layout's lattice)
        if data.neighbours is None:
            raise topo.TopologyError(f"scenario {data.name} has no layout: topology 'layout' is "
                                     "for corridor-<N> / grid-<N>")
        return data.neighbours
    return CENTRALIZED if topology == CENTRALIZED else topo.build(topology, data.num_cameras, order)


def run_once(data: ScenarioData, topology: str, cfg: TrackerConfig, *, order=None,
             show_progress: bool = False, evaluate: bool = True,
             ground_threshold_m: float = 1.0, mode: str = "sync",
             faults: FaultPlan | None = None,
             trigger: TriggerConfig | None = None) -> tuple[RunResult, dict]:
    """One in-process run plus its evaluation; returns ``(RunResult, summary dict)``.

    ``topology`` is a name (``topology.TOPOLOGIES``), ``centralized``, ``layout`` (the scenario's
    own neighbour graph) or an edge-list file; ``order``
    the camera ordering of a ring or chain; ``trigger`` the event trigger's settings in async
    mode (its defaults when ``None``)."""
    adj = adjacency(data, topology, order)
    update, close = progress_bar(f"{data.name} {topology}", data.frames, show_progress)
    try:
        result = run_network(data, adj, cfg, topology_name=Path(topology).stem
                             if topology not in (*topo.TOPOLOGIES.names(), CENTRALIZED, LAYOUT)
                             else topology,
                             progress=update, mode=mode, faults=faults or NO_FAULTS,
                             trigger=trigger)
    finally:
        close()
    summary = result.summary()
    if order is not None:
        summary["order"] = list(order)
    if evaluate:
        summary["metrics"] = metrics.evaluate(result.tracks, data,
                                              ground_threshold_m=ground_threshold_m)
    return result, summary


def main(args) -> int:
    """``sim_cluster run``."""
    rerun = spec_from_args(getattr(args, "rerun", None))  # checked before any work
    data = scenario_from_args(args)
    cfg = tracker_config(args.config, getattr(args, "tracker_config", None))
    faults = load_faults(args.faults, data, args.topology)
    for note in data.notes:
        print(note)
    if is_det_files(args.scenario):  # a scale the user declared (or left at 1): check it
        warning = scenario_scale(data).warning()
        if warning:
            print(f"{data.name}: {warning}")
    cfg, note = geometry_only(data, cfg)
    if note:
        print(note)
    result, summary = run_once(data, args.topology, cfg, show_progress=not args.quiet,
                               ground_threshold_m=args.ground_threshold, mode=args.mode,
                               faults=faults)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for node, frames in result.tracks.items():
        write_tracks(out / f"tracks_node{node}.csv", frames, camera=node)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True))
    print(run_table(summary))
    print(f"wrote {out}/summary.json and {len(result.tracks)} track files")
    if rerun.enabled:
        record_run(rerun, result, data)
    return 0
