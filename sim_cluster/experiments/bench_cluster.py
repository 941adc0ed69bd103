"""``sim_cluster bench-cluster``: what a real cluster of edge_node processes costs on loopback.

For each node count N, ``repeats`` times, a cluster of N ``edge_node run`` processes (the
:class:`~sim_cluster.cluster.launcher.Cluster` that ``sim_cluster up`` runs, with the configs it
writes: one listen endpoint per node, connects on both ends of every link) plays
``frames`` frames of a scenario in sync mode, unpaced (as fast as it goes) or paced at a camera
rate (``--fps 25``: each node starts frame ``k`` no earlier than ``k / fps`` after its first),
and the benchmark measures:

latency
    one hop, from the sender's ``sent_at`` stamp (just before ``put``) to the receiving node's
    Zenoh callback. The nodes keep their samples but write only a summary (median, p99) to
    ``counters_node<i>.json``, so the figures are the **median of the node medians** and the
    **max of the node p99s** (not pooled percentiles). The passive subscriber below also stamps
    every message it receives; its pooled median / p99 (one hop into a process that does nothing
    else) is reported beside them.
frames per second
    the rate the cluster sustains in lock-step: ``(F - 1) / (t_last - t_first)`` where
    ``t_first`` is the moment the last node sent its frame 0 (from then on every node is
    running; earlier nodes were only waiting for a neighbour to come up) and ``t_last`` the
    moment the last node sent frame ``F - 1`` (``sent_at`` of the messages, seen on the wire).
    ``fps_wall`` = ``F / (last message received - first node's first frame start)`` includes that
    start-up skew. ``busy_ms_per_frame`` (median over nodes of ``(prepare + update) / frames``
    from ``timing_s``, wall time) says how much of a frame period is the tracker's own work;
    ``cpu_ms_per_frame`` (median over nodes of the process's CPU time from its first frame to its
    exit, all threads, Zenoh's included, / frames) what a frame costs the box;
    ``cpu_split_ms_per_frame`` where it goes (``CPU_PARTS``, medians over nodes, so they need
    not add up exactly): the frame loop thread's core (``prepare`` + ``update``), source
    (detections; here the simulated world) and sending (encode + publish), the rest of that
    thread, the Zenoh callbacks' receiving (checks and decoding), and the rest of the
    process's other threads (Zenoh's runtime).
timeouts
    the frames a node stopped waiting for a neighbour's message (summed over nodes).
bytes per link per frame
    counted by a **passive subscriber** (``sim_cluster/cluster/monitor.py``): the benchmark opens its own Zenoh peer session,
    subscribed to ``all_links_key(network)`` (``dmtt/<net>/link/**``) before any node starts its
    frames, and counts payload bytes and messages per key. Reported as the median over links of
    bytes / frames and as the network-wide total per frame, next to the same figures from the
    nodes' own ``bytes_per_link`` counters; the two must agree (per link: ``agree``).
start-up
    per node, wall time from ``spawn`` to the node's ``"starting"`` status (imports, scenario,
    Zenoh open: the process's own start), to its ``"running"`` status (start-up barrier passed:
    its first frame begins), and to its frame 0 on the wire; ``startup_s`` (the barrier alone)
    from the counters. Medians over nodes.

Why the monitor sees every message: a node publishes frame 0 as soon as its neighbours are
ready, which for the last node to start is a few milliseconds after its Zenoh session opened.
A subscriber that only connects to the nodes (retrying until their listen endpoints are up) can
miss those first messages. So the benchmark listens first, and every node's ``connect`` list
gets the monitor's endpoint too (both ends of the link connect, as for the cluster's own links):
the node opens its session connected to the monitor, learns its subscription in the handshake,
and only then runs its barrier. The monitor never publishes and declares no liveliness token,
so it changes nothing in the nodes' behaviour but one extra TCP connection each.

Figures vary with the machine and its load; quote medians over repeats.
"""
from __future__ import annotations

import json
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np

from sim_cluster.cluster.launcher import Cluster
from sim_cluster.cluster.monitor import LinkMonitor, LinkTally
from sim_cluster.cluster.processes import free_ports
from sim_cluster.cluster.state import STATE, ClusterError, ClusterState, node_counters, node_status
from sim_cluster.scenarios.loader import load_scenario

RESULT = "bench_cluster.json"
POLL_S = 0.01


# -- one cluster run -------------------------------------------------------------------------
def _median(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else None


def _percentile(xs, q):
    return float(np.percentile(np.asarray(xs, float), q)) if len(xs) else None


def run_cluster(scenario: str, n: int, frames: int, out: Path, *, topology: str = "ring",
                seed: int = 0, config: str = "dkf+lda+dtm", network: str | None = None,
                sync_timeout_s: float = 10.0, startup_timeout_s: float = 60.0,
                timeout_s: float | None = None, data_root: str | None = None,
                monitor_connect_back: bool = True, fps: float = 0.0, scope: int = 0,
                faults: Path | None = None) -> dict:
    """Start an ``n``-node cluster in sync mode (paced at ``fps``, 0: unpaced), run ``frames`` frames with the
    passive monitor attached, stop everything, and return the measured figures (module
    docstring). Raises :class:`ClusterError` when a node fails or the run takes longer than
    ``timeout_s`` (default: generous, from ``frames``). No process outlives this call."""
    network = network or f"bench{n}"
    cluster = Cluster.create(out, network=network, scenario=scenario, seed=seed, frames=frames,
                             mode="sync", topology=topology, nodes=n, data_root=data_root,
                             clear_logs=True)
    *node_ports, mon_port = free_ports(n + 1)
    mon_ep = f"tcp/127.0.0.1:{mon_port}"
    cluster.write_configs(config=config, sync_timeout_s=sync_timeout_s,
                          startup_timeout_s=startup_timeout_s, fps=fps, ports=node_ports,
                          # the monitor's endpoint first in every node's connect list
                          connect_first=[mon_ep] if monitor_connect_back else (),
                          tracker={"scope_hops": scope} if scope else None, faults=faults)
    timeout_s = timeout_s if timeout_s is not None else \
        startup_timeout_s + 60 + 0.5 * frames + (frames / fps if fps else 0.0)
    seen: dict[int, dict[str, float]] = {i: {} for i in range(n)}  # phase -> its updated_at

    def watch(running: list[int]) -> None:  # the short-lived "starting" and first "running"
        for i in running:
            if "running" in seen[i]:
                continue
            st = cluster.status(i)
            phase = st.get("phase")
            if phase == "starting":
                seen[i].setdefault("starting", st["updated_at"])
            elif phase == "running" and not st.get("frames_done"):
                seen[i]["running"] = st["updated_at"]

    monitor = None
    try:
        # the monitor listens before any node starts (they connect to it), and connects to
        # every node's endpoint as soon as it is up
        monitor = LinkMonitor(network, mon_ep, [f"tcp/127.0.0.1:{p}" for p in node_ports])
        cluster.start()
        cluster.wait(poll_s=POLL_S, timeout_s=timeout_s, on_poll=watch)
        # every node has finished, so every message reached its neighbour; give the monitor a
        # moment for the last ones in flight to it
        expected = sum(cluster.counters(i).get("messages_sent", 0) for i in range(n))
        settle = time.time() + 2.0
        while monitor.count() < expected and time.time() < settle:
            time.sleep(POLL_S)
    finally:
        cluster.stop()
        if monitor is not None:
            monitor.close()
    if cluster.running():
        raise ClusterError("a node could not be stopped")
    return _figures(cluster.state, n, frames, cluster.spawned, seen, monitor.tallies())


def _figures(state: ClusterState, n: int, frames: int, spawned: dict[int, float],
             seen: dict[int, dict[str, float]], tallies: dict[str, LinkTally]) -> dict:
    counters = {i: node_counters(state, i) for i in range(n)}
    for i, c in counters.items():
        if c.get("frames_done") != frames:
            raise ClusterError(f"node {i} did only {c.get('frames_done')} of {frames} frames")
    # -- latency (nodes' summaries) and the monitor's pooled samples
    lat = [c.get("latency") or {} for c in counters.values()]
    pooled = [s for t in tallies.values() for s in t.latency_s]
    latency = {
        "median_of_node_medians_ms": _median([x.get("median_ms") for x in lat]),
        "max_of_node_p99_ms": max((x["p99_ms"] for x in lat if x.get("p99_ms") is not None),
                                  default=None),
        "node_medians_ms": [x.get("median_ms") for x in lat],
        "node_p99_ms": [x.get("p99_ms") for x in lat],
        "samples": sum(x.get("count") or 0 for x in lat),
        "monitor_pooled_median_ms": _percentile([s * 1e3 for s in pooled], 50),
        "monitor_pooled_p99_ms": _percentile([s * 1e3 for s in pooled], 99),
    }
    # -- bytes per link: the monitor against the nodes' own counters
    ctr_bytes: dict[str, int] = {}
    ctr_msgs: dict[str, int] = {}
    for c in counters.values():
        ctr_bytes.update(c.get("bytes_per_link") or {})
        ctr_msgs.update(c.get("messages_per_link") or {})
    links = sorted(set(ctr_bytes) | set(tallies))
    per_link = {}
    for link in links:
        t = tallies.get(link, LinkTally())
        per_link[link] = {"monitor_bytes": t.bytes, "monitor_messages": t.messages,
                          "counter_bytes": ctr_bytes.get(link, 0),
                          "counter_messages": ctr_msgs.get(link, 0),
                          "missed_frames": sorted(set(range(frames)) - set(t.frames))[:10]}
    mon_b = [per_link[k]["monitor_bytes"] / frames for k in links]
    ctr_b = [per_link[k]["counter_bytes"] / frames for k in links]
    bandwidth = {
        "links": len(links),
        "monitor_bytes_per_link_frame_median": _median(mon_b),
        "counter_bytes_per_link_frame_median": _median(ctr_b),
        "monitor_bytes_per_frame_total": sum(mon_b),
        "counter_bytes_per_frame_total": sum(ctr_b),
        "monitor_messages": sum(t.messages for t in tallies.values()),
        "counter_messages": sum(ctr_msgs.values()),
        "agree": all(v["monitor_bytes"] == v["counter_bytes"]
                     and v["monitor_messages"] == v["counter_messages"]
                     for v in per_link.values()),
        "per_link": per_link,
    }
    # -- frame rate from the senders' stamps of frame f0 and frame F-1 (per node: any of its
    # links). f0 is 0 unless the monitor missed a sender's first frame (the start-up race):
    # then the first frame it saw from every sender.
    seen_frames: dict[int, dict[int, float]] = {}
    for link, t in tallies.items():
        src = int(link.split("->")[0])
        for f, ts in t.frames.items():
            seen_frames.setdefault(src, {}).setdefault(f, ts)
    fps = fps_wall = None
    first_sent: dict[int, float] = {}
    if len(seen_frames) == n and frames > 1:
        f0 = max(min(fs) for fs in seen_frames.values())
        if all(f0 in fs and frames - 1 in fs for fs in seen_frames.values()):
            first_sent = {src: fs[f0] for src, fs in seen_frames.items()}
            span = max(fs[frames - 1] for fs in seen_frames.values()) - max(first_sent.values())
            fps = (frames - 1 - f0) / span if span > 0 else None
            starts = [seen[i].get("running", first_sent[i]) for i in range(n)]
            end = max(t.last_recv for t in tallies.values())
            fps_wall = frames / (end - min(starts)) if end > min(starts) else None
    busy = [((c.get("timing_s") or {}).get("prepare", 0) + (c.get("timing_s") or {}).get("update", 0))
            / frames * 1e3 for c in counters.values()]
    wait = [(c.get("timing_s") or {}).get("wait", 0) / frames * 1e3 for c in counters.values()]
    cpu = [None if (c.get("cpu_s") or {}).get("frames") is None
           else c["cpu_s"]["frames"] / frames * 1e3 for c in counters.values()]
    parts = [{p: _cpu_part(c, p) for p in CPU_PARTS} for c in counters.values()]
    split = {p: _median([None if x[p] is None else x[p] / frames * 1e3 for x in parts])
             for p in CPU_PARTS}
    # -- start-up
    def since_spawn(ts: dict[int, float | None]) -> list[float | None]:
        return [None if ts.get(i) is None else ts[i] - spawned[i] for i in range(n)]

    # FrameLoop.started_at (in every status file): the Zenoh session is open, the barrier starts
    started = {i: node_status(state, i).get("started_at") or seen[i].get("starting")
               for i in range(n)}
    to_starting = since_spawn(started)
    to_running = since_spawn({i: seen[i].get("running") for i in range(n)})
    to_frame0 = since_spawn(first_sent)
    startup = {
        "spawn_to_first_frame_s": _median(to_frame0),
        "spawn_to_running_status_s": _median(to_running),
        "spawn_to_starting_status_s": _median(to_starting),
        "barrier_s": _median([c.get("startup_s") for c in counters.values()]),
        "per_node": {str(i): {"to_starting": to_starting[i], "to_running": to_running[i],
                              "to_frame0": to_frame0[i],
                              "barrier": counters[i].get("startup_s")} for i in range(n)},
    }
    problems = {k: sum(sum((c.get(k) or {}).values()) for c in counters.values())
                for k in ("timeouts", "late", "rejected", "duplicates", "overflow")}
    return {"nodes": n, "frames": frames, "topology": state.topology, "scenario": state.scenario,
            "fps": fps, "fps_wall": fps_wall,
            "busy_ms_per_frame": _median(busy), "wait_ms_per_frame": _median(wait),
            "cpu_ms_per_frame": _median(cpu), "cpu_split_ms_per_frame": split,
            "timeouts": problems["timeouts"],
            "latency": latency, "bandwidth": bandwidth, "startup": startup, "problems": problems}


CPU_PARTS = ("core", "source", "send", "loop_rest", "receive", "zenoh")


def _cpu_part(counters: dict, part: str) -> float | None:
    """One part of a node's CPU since its first frame (its counters file): the loop thread's
    ``core`` (prepare + update), ``source`` (detections) and ``send`` (encode and publish), the
    rest of that thread (``loop_rest``: track writer, status, waiting), the Zenoh callbacks'
    ``receive`` (checks and decoding) and the rest of the process's other threads
    (``zenoh``: its runtime)."""
    cpu = counters.get("cpu_s") or {}
    if cpu.get("loop") is None or cpu.get("frames") is None or "receive_cpu_s" not in counters:
        return None
    if part == "loop_rest":
        return cpu["loop"] - cpu["core"] - cpu["source"] - cpu["send"]
    if part == "receive":
        return counters["receive_cpu_s"]
    if part == "zenoh":
        return cpu["frames"] - cpu["loop"] - counters["receive_cpu_s"]
    return cpu[part]


# -- the command -----------------------------------------------------------------------------
HEADLINE = {  # name in the summary -> path in one run's figures
    "fps": ("fps",),
    "fps_wall": ("fps_wall",),
    "busy_ms_per_frame": ("busy_ms_per_frame",),
    "cpu_ms_per_frame": ("cpu_ms_per_frame",),
    **{f"cpu_{part}_ms_per_frame": ("cpu_split_ms_per_frame", part) for part in CPU_PARTS},
    "timeouts": ("timeouts",),
    "latency_median_ms": ("latency", "median_of_node_medians_ms"),
    "latency_p99_ms": ("latency", "max_of_node_p99_ms"),
    "monitor_latency_median_ms": ("latency", "monitor_pooled_median_ms"),
    "monitor_latency_p99_ms": ("latency", "monitor_pooled_p99_ms"),
    "bytes_per_link_frame_monitor": ("bandwidth", "monitor_bytes_per_link_frame_median"),
    "bytes_per_link_frame_counters": ("bandwidth", "counter_bytes_per_link_frame_median"),
    "bytes_per_frame_total_monitor": ("bandwidth", "monitor_bytes_per_frame_total"),
    "bytes_per_frame_total_counters": ("bandwidth", "counter_bytes_per_frame_total"),
    "spawn_to_first_frame_s": ("startup", "spawn_to_first_frame_s"),
    "spawn_to_starting_status_s": ("startup", "spawn_to_starting_status_s"),
    "barrier_s": ("startup", "barrier_s"),
}


def _get(d: dict, path: tuple[str, ...]):
    for p in path:
        d = d.get(p) if isinstance(d, dict) else None
    return d


def bench(node_counts: list[int], frames: int, repeats: int, topology: str, out: Path, *,
          scenario: str = "ring8-sim", seed: int = 0, config: str = "dkf+lda+dtm",
          sync_timeout_s: float = 10.0, startup_timeout_s: float = 60.0,
          data_root: str | None = None, pacing: tuple[float, ...] = (0.0,), scope: int = 0,
          faults: Path | None = None, log=print) -> dict:
    """Run every node count at every pacing (``0``: unpaced) ``repeats`` times; the summary
    holds each headline figure's median over repeats (``summary[key]``, key ``"<n>"`` unpaced,
    ``"<n>@<fps>"`` paced) and every run's full figures (``runs[key]``)."""
    data = load_scenario(scenario, seed=seed, frames=1, data_root=data_root)
    for n in node_counts:
        if n < 2:
            raise ClusterError(f"--nodes {n}: a cluster needs at least 2 nodes")
        if n > data.num_cameras:
            raise ClusterError(f"--nodes {n}: scenario {data.name} has only "
                               f"{data.num_cameras} cameras")
    log(f"bench-cluster: {scenario}, {topology}, nodes {node_counts}, pacing {list(pacing)}, "
        f"{frames} frames, {repeats} repeat(s), out {out}")
    out = Path(out)
    result = {"scenario": scenario, "seed": seed, "frames": frames, "repeats": repeats,
              "topology": topology, "mode": "sync", "pacing": list(pacing), "config": config,
              "scope_hops": scope, "faults": None if faults is None else str(faults),
              "cpus": os.cpu_count(), "load_average_at_start": list(os.getloadavg()),
              "runs": {}, "summary": {}}
    for n in node_counts:
        for fps in pacing:
            key = f"{n}@{fps:g}" if fps else str(n)
            runs = []
            for r in range(repeats):
                t0 = time.time()
                fig = run_cluster(scenario, n, frames, out / f"n{key}" / f"r{r}", topology=topology,
                                  seed=seed, config=config, network=f"bench{n}p{fps:g}r{r}".replace(".", "_"),
                                  sync_timeout_s=sync_timeout_s,
                                  startup_timeout_s=startup_timeout_s, data_root=data_root, fps=fps,
                                  scope=scope, faults=faults)
                fig["pacing_fps"] = fps
                runs.append(fig)
                log(f"  {key} nodes, run {r + 1}/{repeats}: {_fmt(fig['fps'], '.1f')} frames/s, "
                    f"latency {_fmt(_get(fig, HEADLINE['latency_median_ms']), '.2f')} / "
                    f"{_fmt(_get(fig, HEADLINE['latency_p99_ms']), '.2f')} ms, "
                    f"cpu {_fmt(fig['cpu_ms_per_frame'], '.2f')} ms/frame, "
                    f"{fig['timeouts']} timeouts, "
                    f"monitor {'agrees' if fig['bandwidth']['agree'] else 'DISAGREES'}, "
                    f"{time.time() - t0:.1f} s")
            result["runs"][key] = runs
            result["summary"][key] = {
                **{k: _median([_get(f, p) for f in runs]) for k, p in HEADLINE.items()},
                "nodes": n, "pacing_fps": fps,
                "monitor_agrees_in_every_run": all(f["bandwidth"]["agree"] for f in runs),
                "problems": {k: sum(f["problems"][k] for f in runs) for k in runs[0]["problems"]},
            }
    result["load_average_at_end"] = list(os.getloadavg())
    return result


def _fmt(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def table(result: dict) -> str:
    rows = [f"bench-cluster: {result['scenario']} seed {result['seed']}, {result['topology']}, "
            f"sync, scope_hops {result.get('scope_hops', 0)}, {result['frames']} frames, "
            f"median of {result['repeats']} repeat(s)",
            f"{'nodes':>7} {'pacing':>6} {'frames/s':>8} {'busy ms':>7} {'cpu ms':>6} "
            f"{'lat med':>7} {'lat p99':>7} {'timeouts':>8} "
            f"{'B/link/frame':>12} {'(counters)':>10} {'B/frame':>8} {'(counters)':>10} "
            f"{'to frame 0':>10} {'to start':>8} {'barrier':>7}",
            f"{'':>7} {'fps':>6} {'':>8} {'':>7} {'':>6} {'ms':>7} {'ms':>7} {'':>8} "
            f"{'monitor':>12} {'':>10} {'monitor':>8} {'':>10} {'s':>10} {'s':>8} {'s':>7}"]
    for key, s in result["summary"].items():
        pacing = s.get("pacing_fps") or 0
        rows.append(
            f"{s.get('nodes', key):>7} {('-' if not pacing else format(pacing, 'g')):>6} "
            f"{_fmt(s['fps'], '.1f'):>8} {_fmt(s['busy_ms_per_frame'], '.2f'):>7} "
            f"{_fmt(s.get('cpu_ms_per_frame'), '.2f'):>6} "
            f"{_fmt(s['latency_median_ms'], '.2f'):>7} {_fmt(s['latency_p99_ms'], '.2f'):>7} "
            f"{_fmt(s.get('timeouts'), '.0f'):>8} "
            f"{_fmt(s['bytes_per_link_frame_monitor'], '.0f'):>12} "
            f"{_fmt(s['bytes_per_link_frame_counters'], '.0f'):>10} "
            f"{_fmt(s['bytes_per_frame_total_monitor'], '.0f'):>8} "
            f"{_fmt(s['bytes_per_frame_total_counters'], '.0f'):>10} "
            f"{_fmt(s['spawn_to_first_frame_s'], '.2f'):>10} "
            f"{_fmt(s['spawn_to_starting_status_s'], '.2f'):>8} {_fmt(s['barrier_s'], '.2f'):>7}")
    rows.append("latency: one hop, median of node medians / max of node p99s (nodes write "
                "summaries only); frames/s: lock-step rate from the last node's frame 0 to its "
                "frame F-1; busy: prepare+update wall time per frame, cpu: the process's CPU "
                "time per frame, all threads (median node); timeouts: summed over nodes; to "
                "frame 0 / to start: spawn to the node's frame 0 on the wire / to its 'starting' "
                "status; barrier: the nodes' startup_s (medians over nodes)")
    for key, s in result["summary"].items():
        extra = [f"monitor pooled latency {_fmt(s['monitor_latency_median_ms'], '.2f')} / "
                 f"{_fmt(s['monitor_latency_p99_ms'], '.2f')} ms",
                 f"frames/s incl. start-up skew {_fmt(s['fps_wall'], '.1f')}",
                 "cpu ms by part: " + ", ".join(
                     f"{part.replace('_', ' ')} {_fmt(s.get(f'cpu_{part}_ms_per_frame'), '.2f')}"
                     for part in CPU_PARTS)]
        if not s["monitor_agrees_in_every_run"]:
            extra.append("MONITOR AND COUNTERS DISAGREE (see per_link in the JSON)")
        bad = {k: v for k, v in s["problems"].items() if v}
        if bad:
            extra.append(f"problems {bad}")
        rows.append(f"{key:>7} nodes: " + "; ".join(extra))
    return "\n".join(rows)


def main(args) -> int:
    try:
        counts = [int(x) for x in str(args.nodes).split(",") if x.strip()]
    except ValueError:
        raise ClusterError(f"--nodes {args.nodes!r}: give node counts like 4,8") from None
    if not counts or args.frames < 2 or args.repeats < 1:
        raise ClusterError("need at least one node count, --frames >= 2 and --repeats >= 1")
    out = Path(args.out)
    if (out / STATE).exists():
        raise ClusterError(f"{out} holds a cluster (sim_cluster up); use another --out")
    out.mkdir(parents=True, exist_ok=True)
    try:
        pacing = tuple(float(x) for x in str(args.fps).split(",") if x.strip())
    except ValueError:
        raise ClusterError(f"--fps {args.fps!r}: give frame rates like 0,25 (0: unpaced)") from None
    if not pacing or any(not (math.isfinite(f) and f >= 0) for f in pacing) \
            or len(set(pacing)) != len(pacing):
        raise ClusterError(f"--fps {args.fps!r}: give distinct frame rates >= 0 like 0,25 (0: "
                           "unpaced)")
    result = bench(counts, args.frames, args.repeats, args.topology, out, scenario=args.scenario,
                   seed=args.seed, sync_timeout_s=args.sync_timeout,
                   startup_timeout_s=args.startup_timeout, pacing=pacing,
                   scope=getattr(args, "scope", 0),
                   faults=Path(args.faults) if getattr(args, "faults", None) else None)
    (out / RESULT).write_text(json.dumps(result, indent=2, sort_keys=True))
    print(table(result))
    print(f"wrote {out / RESULT}")
    return 0
