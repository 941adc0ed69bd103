"""``sim_cluster up``: a real cluster, one ``edge_node`` process per camera, on loopback.

``up`` writes one camera config per node (free loopback ports, a listen endpoint per node and
connects on both ends of every link), spawns the processes, shows progress, waits, gathers every
node's tracks and wire counters, and evaluates them like ``sim_cluster run``. With ``--detach``
it returns once the processes are started; ``status``, ``kill``, ``restart`` and ``down`` then
act on the cluster through its state file ``<out>/cluster.json``.

No process outlives its cluster: a failed start, a node that exits with an error, Ctrl-C and
``down`` all end every process the cluster started.
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

STATE = "cluster.json"
TERM_GRACE_S = 5.0


class ClusterError(Exception):
    """A cluster that cannot be started or acted on; the message says why."""


@dataclass
class NodeProc:
    node: int
    config: str
    log: str
    port: int
    pid: int | None = None
    restarts: int = 0


@dataclass
class ClusterState:
    out: str
    network: str
    scenario: str
    seed: int
    frames: int | None
    mode: str
    topology: str
    adjacency: dict[str, list[int]]
    nodes: dict[str, NodeProc] = field(default_factory=dict)
    started_at: float = 0.0
    data_root: str | None = None

    def save(self) -> None:
        path = Path(self.out) / STATE
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(self), indent=2))
        os.replace(tmp, path)

    @classmethod
    def load(cls, out: str | Path) -> "ClusterState":
        path = Path(out) / STATE
        try:
            d = json.loads(path.read_text())
        except FileNotFoundError:
            raise ClusterError(f"no cluster at {out} (no {STATE}); start one with "
                               f"'sim_cluster up --out {out}'") from None
        except json.JSONDecodeError as e:
            raise ClusterError(f"{path}: not a cluster state file ({e})") from None
        d["nodes"] = {k: NodeProc(**v) for k, v in d["nodes"].items()}
        return cls(**d)


# -- processes -----------------------------------------------------------------------------------
def free_ports(n: int) -> list[int]:
    """``n`` distinct free TCP ports on 127.0.0.1 (held open together so they differ)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def alive(pid: int | None) -> bool:
    """Whether ``pid`` is a running (not zombie) process."""
    if not pid:
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return True


def spawn(proc: NodeProc, join: bool = False) -> subprocess.Popen:
    """Start one ``edge_node run`` in its own session (Ctrl-C on the launcher's terminal reaches
    the launcher, which ends its nodes in order). ``join``: a restart into a running network."""
    log = open(proc.log, "ab")
    try:
        return subprocess.Popen([sys.executable, "-m", "edge_node.cli", "run", "--config",
                                 proc.config, *(["--join"] if join else [])],
                                stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    finally:
        log.close()


def _signal(pids: list[int], sig: int) -> None:
    for pid in pids:
        if alive(pid):
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass


def terminate(pids: list[int], grace: float = TERM_GRACE_S) -> None:
    """SIGTERM (a node finishes its frame and flushes), then SIGKILL whatever is left."""
    _signal(pids, signal.SIGTERM)
    deadline = time.time() + grace
    while time.time() < deadline and any(alive(p) for p in pids):
        time.sleep(0.05)
    _signal(pids, signal.SIGKILL)


# -- configs -------------------------------------------------------------------------------------
def _toml_str(v: str) -> str:
    return json.dumps(v)  # a JSON string is a valid TOML basic string


def node_config(i: int, state: ClusterState, ports: dict[int, int], *, config: str,
                sync_timeout_s: float, startup_timeout_s: float, fps: float = 0.0,
                faults: Path | None = None, source_toml: str | None = None) -> str:
    """The TOML of node ``i`` (schema: ``edge_node/runtime/config.py``)."""
    neighbours = state.adjacency[str(i)]
    listen = [f"tcp/127.0.0.1:{ports[i]}"]
    connect = [f"tcp/127.0.0.1:{ports[j]}" for j in neighbours]
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
    if source_toml is not None:  # frames rendered for this camera (sim_cluster/render.py)
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
    lines += ["", "[tracker]", f"ablation = {_toml_str(config)}", "", "[output]",
              f"dir = {_toml_str(str(Path(state.out) / 'nodes'))}", "status_interval_s = 0.5", ""]
    return "\n".join(lines)


# -- reading a cluster's results -----------------------------------------------------------------
def node_status(state: ClusterState, node: int) -> dict:
    from edge_node.runtime.output import status_path

    try:
        return json.loads(status_path(Path(state.out) / "nodes", node).read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def node_counters(state: ClusterState, node: int) -> dict:
    from edge_node.runtime.output import counters_path

    try:
        return json.loads(counters_path(Path(state.out) / "nodes", node).read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def status_table(state: ClusterState) -> str:
    rows = [f"cluster {state.out}: {len(state.nodes)} nodes, {state.topology}, {state.mode}, "
            f"scenario {state.scenario} seed {state.seed}",
            f"{'node':>4} {'pid':>7} {'alive':>5} {'frame':>6} {'trackers':>8} {'bytes sent':>11} "
            f"{'rejected':>8} {'late':>5} {'timeouts':>8} {'phase':>9}"]
    reasons = []  # hostile or broken input, by ProtocolError reason (protocol/errors.py)
    for key, p in sorted(state.nodes.items(), key=lambda kv: int(kv[0])):
        st = node_status(state, p.node)
        rejected = sum((st.get("rejected") or {}).values())
        if rejected:
            reasons.append(f"node {p.node} rejected: " + ", ".join(
                f"{r} {n}" for r, n in sorted(st["rejected"].items())))
        frame = st.get("frame")
        rows.append(f"{p.node:>4} {p.pid or '-':>7} {'yes' if alive(p.pid) else 'no':>5} "
                    f"{'-' if frame is None else frame:>6} {st.get('trackers', '-'):>8} "
                    f"{st.get('bytes_sent', '-'):>11} {rejected:>8} {st.get('late', '-'):>5} "
                    f"{st.get('timeouts', '-'):>8} {st.get('phase', '-'):>9}")
    return "\n".join(rows + reasons)


def gather(state: ClusterState, data, frames: int, config: str = "") -> dict:
    """Every node's tracks and counters, evaluated like an in-process run: ``summary.json``."""
    from edge_node.runtime.output import tracks_path
    from sim_cluster.evaluation import evaluate
    from edge_node.formats.tracks import read_tracks

    out = Path(state.out)
    tracks = {p.node: read_tracks(tracks_path(out / "nodes", p.node), frames)
              for p in state.nodes.values()}
    counters = {p.node: node_counters(state, p.node) for p in state.nodes.values()}
    per_link: dict[str, float] = {}
    total = app = entries = app_entries = 0
    latency = {}
    for node, c in sorted(counters.items()):
        for link, b in (c.get("bytes_per_link") or {}).items():
            per_link[link] = b / max(frames, 1)
        total += c.get("bytes_sent", 0)
        app += c.get("appearance_bytes", 0)
        entries += c.get("tracker_entries", 0)
        app_entries += c.get("appearance_entries", 0)
        latency[str(node)] = c.get("latency")
    ids = {str(n): len({t.id for f in fr for t in f}) for n, fr in tracks.items()}
    summary = {
        "scenario": data.name, "topology": state.topology,
        "config": config,
        "seed": state.seed, "frames": frames, "nodes": len(tracks), "mode": state.mode,
        "bandwidth": {
            "bytes_per_frame": total / max(frames, 1),
            "bytes_per_tracker_frame": (total - app) / entries if entries else 0.0,
            "appearance_bytes_per_new_tracker": app / app_entries if app_entries else 0.0,
            "per_link": dict(sorted(per_link.items())),
            "messages": sum(c.get("messages_sent", 0) for c in counters.values()),
        },
        "tracks": {"ids_per_node": ids},
        "processes": {str(n): {k: c.get(k) for k in ("exit_code", "frames_done", "startup_s",
                                                       "latency", "rejected", "late", "timeouts",
                                                       "bytes_saved", "frames_skipped")}
                      for n, c in sorted(counters.items())},
    }
    summary["metrics"] = evaluate(tracks, data)
    return summary


# -- commands ------------------------------------------------------------------------------------
def up(args) -> int:
    from sim_cluster import topology as topo
    from sim_cluster.cli import CliError, _scenario
    from sim_cluster.progress import progress_bar
    from sim_cluster.report import run_table

    data = _scenario(args)
    n = data.num_cameras if args.nodes is None else args.nodes
    if not 1 <= n <= data.num_cameras:
        raise CliError(f"--nodes {n}: scenario {data.name} has {data.num_cameras} cameras")
    if n < data.num_cameras:
        data.cameras = data.cameras[:n]
        data.detections = [d[:n] for d in data.detections]
        data.truth.boxes = data.truth.boxes[:n]
    adjacency = topo.build(args.topology, n)
    out = Path(args.out).resolve()
    (out / "nodes").mkdir(parents=True, exist_ok=True)
    (out / "configs").mkdir(exist_ok=True)
    (out / "logs").mkdir(exist_ok=True)
    if (out / STATE).exists():
        old = ClusterState.load(out)
        running = [p.node for p in old.nodes.values() if alive(p.pid)]
        if running:
            raise CliError(f"a cluster is still running in {out} (nodes {running}); "
                           f"'sim_cluster down --out {args.out}' first")
    for f in (out / "nodes").glob("*"):
        f.unlink()
    viz = _cluster_viz(args, out, n, data)  # --rerun (sim_cluster/viz.py)
    state = ClusterState(str(out), args.network, args.scenario, args.seed, args.frames,
                         args.mode, Path(args.topology).stem,
                         {str(i): list(v) for i, v in adjacency.items()},
                         data_root=str(Path(args.data_root).resolve()) if args.data_root else None)
    plan = None
    faults_file = None
    if getattr(args, "faults", None):
        from edge_node.faults import FaultPlan, FaultPlanError

        faults_file = Path(args.faults).resolve()
        try:
            plan = FaultPlan.load(faults_file)
        except FaultPlanError as e:
            raise CliError(str(e)) from None
    ports = dict(enumerate(free_ports(n)))
    # Pacing: a synchronous cluster runs in lock-step as fast as it can; an asynchronous one
    # never waits, so it plays frames at the cameras' rate (as real cameras deliver them).
    # Crashes and restarts happen in wall-clock time too (a process takes a second or two to
    # start), so a cluster whose fault plan kills nodes also plays at camera rate.
    realtime = args.mode == "async" or (plan is not None and bool(plan.nodes))
    fps = args.fps if args.fps is not None else (data.fps if realtime else 0.0)
    from sim_cluster.render import cluster_video_sources  # --source video: render, then configs

    videos = cluster_video_sources(args, data, out, n) or {}
    for i in range(n):
        cfg = out / "configs" / f"node{i}.toml"
        cfg.write_text(node_config(i, state, ports, config=args.config,
                                   sync_timeout_s=args.sync_timeout,
                                   startup_timeout_s=args.startup_timeout, fps=fps,
                                   faults=faults_file, source_toml=videos.get(i))
                       + viz.node_toml(i))
        state.nodes[str(i)] = NodeProc(i, str(cfg), str(out / "logs" / f"node{i}.log"), ports[i])
    procs: dict[int, subprocess.Popen] = {}
    state.started_at = time.time()
    try:
        viz.open()  # spawn / serve: the viewer or server the nodes connect to
        for p in state.nodes.values():
            procs[p.node] = spawn(p)
            p.pid = procs[p.node].pid
        state.save()
        viz.log_truth(data.frames)
        if args.detach:
            viz.close()
            print(f"started {n} nodes ({args.topology}, {args.mode}) in {out}")
            print(f"  sim_cluster status --out {args.out}   |   sim_cluster down --out {args.out}")
            procs = {}  # they are the cluster's now, not this launcher's
            return 0
        frames = data.frames
        update, close = progress_bar(f"cluster {args.topology}", frames, not args.quiet)
        try:
            crashed: dict[int, int | None] = {}  # node -> frame to restart it at (plan)
            while procs or crashed:
                for node, pr in list(procs.items()):
                    code = pr.poll()
                    if code is None:
                        continue
                    del procs[node]
                    planned = plan is not None and any(f.node == node for f in plan.nodes)
                    if code == -signal.SIGKILL and planned:  # the fault plan's crash
                        crashed[node] = next((f.restart for f in plan.nodes
                                              if f.node == node and f.restart is not None
                                              and f.restart > _frame(state, node)), None)
                        continue
                    if code != 0:
                        tail = Path(state.nodes[str(node)].log).read_text(errors="replace")
                        tail = "\n".join(tail.splitlines()[-8:])
                        raise CliError(f"node {node} exited with code {code}; its log "
                                       f"({state.nodes[str(node)].log}) ends:\n{tail}")
                running = [i for i in procs]
                done = [node_status(state, i).get("frames_done", 0) for i in running] or [frames]
                now = max((_frame(state, i) for i in running), default=frames)
                for node, at in list(crashed.items()):
                    if at is None or not running:
                        del crashed[node]  # stays dead (or nobody left to rejoin)
                    elif now >= at - 1:
                        p = state.nodes[str(node)]
                        procs[node] = spawn(p, join=True)
                        p.pid, p.restarts = procs[node].pid, p.restarts + 1
                        state.save()
                        del crashed[node]
                update(min(done), frames)
                time.sleep(0.05)
        finally:
            close()
        summary = gather(state, data, frames, args.config)
        (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True))
        print(run_table(summary))
        lat = [v.get("median_ms") for v in (p["latency"] or {} for p in
                                             summary["processes"].values()) if v]
        if lat:
            print(f"one-hop latency: median of node medians {sorted(lat)[len(lat) // 2]:.2f} ms")
        print(f"wrote {out}/summary.json, tracks and logs under {out}")
        viz.finish(frames)
        return 0
    except KeyboardInterrupt:
        print("sim_cluster: interrupted: stopping the cluster", file=sys.stderr)
        return 130
    finally:
        viz.close()
        if procs:  # anything still running that this launcher owns: end it
            terminate([pr.pid for pr in procs.values()])
            for pr in procs.values():
                pr.wait()


def _cluster_viz(args, out: Path, n: int, data):
    from sim_cluster.viz import ClusterViz, spec_from_args

    return ClusterViz(spec_from_args(getattr(args, "rerun", None)), out, n, data,
                      detach=bool(getattr(args, "detach", False)))


def _frame(state: ClusterState, node: int) -> int:
    f = node_status(state, node).get("frame")
    return -1 if f is None else int(f)


def status(args) -> int:
    print(status_table(ClusterState.load(args.out)))
    return 0


def kill(args) -> int:
    state = ClusterState.load(args.out)
    p = _node(state, args.node)
    if not alive(p.pid):
        raise ClusterError(f"node {args.node} is not running")
    os.kill(p.pid, signal.SIGKILL)  # a real crash: no flush, no goodbye
    print(f"killed node {args.node} (pid {p.pid})")
    return 0


def restart(args) -> int:
    state = ClusterState.load(args.out)
    p = _node(state, args.node)
    if alive(p.pid):
        terminate([p.pid])
    pr = spawn(p, join=True)
    p.pid, p.restarts = pr.pid, p.restarts + 1
    state.save()
    print(f"restarted node {args.node} (pid {p.pid})")
    return 0


def down(args) -> int:
    state = ClusterState.load(args.out)
    pids = [p.pid for p in state.nodes.values() if alive(p.pid)]
    terminate(pids)
    left = [p.node for p in state.nodes.values() if alive(p.pid)]
    if left:
        raise ClusterError(f"nodes {left} could not be stopped")
    print(f"stopped {len(pids)} node(s) of {args.out}")
    return 0


def _node(state: ClusterState, node: int) -> NodeProc:
    try:
        return state.nodes[str(node)]
    except KeyError:
        raise ClusterError(f"no node {node} in this cluster (nodes "
                           f"{sorted(int(k) for k in state.nodes)})") from None
