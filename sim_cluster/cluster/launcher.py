"""A real cluster, one ``edge_node`` process per camera, on loopback: the :class:`Cluster` that
``sim_cluster up``, the cluster benchmark and the tests launch.

A cluster writes one camera config per node (free loopback ports, a listen endpoint per node and
connects on both ends of every link; ``configs.py``), spawns the processes, keeps its state file
``<out>/cluster.json`` (``state.py``), watches them until they finish (restarting nodes a fault
plan crashed, at the plan's frame), and gathers every node's tracks and wire counters into a
summary evaluated like ``sim_cluster run``'s. A detached cluster is reached again with
:meth:`Cluster.attach` (``status``, ``kill``, ``restart``, ``down``).

No process outlives its cluster: a failed start, a node that exits with an error, Ctrl-C and
``down`` all end every process the cluster started.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import time
import tomllib
from collections.abc import Callable, Sequence
from pathlib import Path

from edge_node.faults import FaultPlan
from edge_node.formats.tracks import read_tracks
from edge_node.runtime.config import parse_node_config
from edge_node.runtime.output import tracks_path
from sim_cluster.cluster.configs import node_config
from sim_cluster.cluster.processes import alive, free_ports, spawn, terminate
from sim_cluster.cluster.state import (STATE, ClusterError, ClusterState, NodeProc, node_counters,
                                       node_status, status_table)
from sim_cluster.evaluation.metrics import evaluate
from sim_cluster.network import topology as topo


class Cluster:
    """The processes of one cluster and its state file (module docstring).

    ``create`` (a new cluster in ``out``: ``prepare`` checks, ``reset`` clears the previous
    run's node files) or ``attach`` (an existing one), then ``plan_configs`` (checked, in
    memory) and ``write_configs``, ``start``, ``wait`` and ``stop`` (always, e.g. in
    ``finally``), and ``gather`` the results. ``detach`` hands the running processes over to
    the state file.
    """

    def __init__(self, state: ClusterState):
        self.state = state
        self.procs: dict[int, subprocess.Popen] = {}  # the processes this launcher owns
        self.spawned: dict[int, float] = {}  # node -> when it was (last) started
        self._configs: dict[int, str] = {}  # node -> its config TOML (plan_configs)

    # -- making one --------------------------------------------------------------------------
    @classmethod
    def prepare(cls, out: str | Path, *, network: str, scenario: str, seed: int,
                frames: int | None, mode: str, topology: str, nodes: int,
                data_root: str | None = None) -> "Cluster":
        """A new cluster of ``nodes`` nodes in ``out``, checked but not written: nothing in
        ``out`` is touched until :meth:`reset`. A bad topology is a ``TopologyError``, a
        cluster still running there a :class:`ClusterError`."""
        adjacency = topo.build(topology, nodes)
        out = Path(out).resolve()
        if (out / STATE).exists():
            running = Cluster.attach(out).running()
            if running:
                raise ClusterError(f"a cluster is still running in {out} (nodes {running}); "
                                   f"'sim_cluster down --out {out}' first")
        return cls(ClusterState(str(out), network, scenario, seed, frames, mode,
                                Path(topology).stem, {str(i): list(v) for i, v in adjacency.items()},
                                data_root=str(Path(data_root).resolve()) if data_root else None))

    def reset(self, clear_logs: bool = False) -> None:
        """Make the cluster's folders and remove the previous run's node files (and logs):
        the first write to ``out``, so everything that can be checked comes before it."""
        for sub in ("nodes", "configs", "logs"):
            (self.out / sub).mkdir(parents=True, exist_ok=True)
        for f in (self.out / "nodes").glob("*"):
            f.unlink()
        if clear_logs:
            for f in (self.out / "logs").glob("*"):
                f.unlink()

    @classmethod
    def create(cls, out: str | Path, *, clear_logs: bool = False, **kw) -> "Cluster":
        """:meth:`prepare` (same arguments) then :meth:`reset`."""
        cluster = cls.prepare(out, **kw)
        cluster.reset(clear_logs)
        return cluster

    @classmethod
    def attach(cls, out: str | Path) -> "Cluster":
        """The cluster whose state file is in ``out`` (processes it does not own)."""
        return cls(ClusterState.load(out))

    @property
    def out(self) -> Path:
        return Path(self.state.out)

    @property
    def size(self) -> int:
        return len(self.state.adjacency)

    def plan_configs(self, *, config: str, sync_timeout_s: float, startup_timeout_s: float,
                     fps: float = 0.0, faults: Path | None = None,
                     sources: dict[int, str] | None = None,
                     extra: Callable[[int], str] | None = None,
                     connect_first: Sequence[str] = (),
                     ports: Sequence[int] | None = None,
                     tracker: dict | None = None,
                     status_interval_s: float = 0.5) -> dict[int, str]:
        """Every node's config (``configs.node_config``) on free ports (or ``ports``): the
        tracker ``config``, timeouts, pacing, a fault plan, per-node ``sources`` (rendered
        video), ``extra`` tables per node (Rerun), endpoints ``connect_first`` and ``tracker``
        fields beside the ablation (``scope_hops``). Each is
        checked as its node will check it (``NodeConfigError``); nothing is written
        (:meth:`write_configs`). Returns the TOML texts by node."""
        ports_of = dict(enumerate(ports if ports is not None else free_ports(self.size)))
        sources = sources or {}
        texts = {}
        for i in range(self.size):
            cfg = self.out / "configs" / f"node{i}.toml"
            texts[i] = (node_config(i, self.state, ports_of, config=config,
                                    sync_timeout_s=sync_timeout_s,
                                    startup_timeout_s=startup_timeout_s, fps=fps, faults=faults,
                                    source_toml=sources.get(i), connect_first=connect_first,
                                    tracker=tracker, status_interval_s=status_interval_s)
                        + (extra(i) if extra is not None else ""))
            parse_node_config(tomllib.loads(texts[i]), cfg)
            self.state.nodes[str(i)] = NodeProc(i, str(cfg), str(self.out / "logs" / f"node{i}.log"),
                                                ports_of[i])
        self._configs = texts
        return texts

    def write_configs(self, **plan) -> None:
        """Write the configs :meth:`plan_configs` made (called here with ``plan`` when given)."""
        if plan:
            self.plan_configs(**plan)
        for i, text in self._configs.items():
            Path(self.state.nodes[str(i)].config).write_text(text)

    # -- running it --------------------------------------------------------------------------
    def start(self) -> None:
        """Spawn every node, then save the state file (their process ids)."""
        self.state.started_at = time.time()
        for p in self.state.nodes.values():
            self._spawn(p)
        self.state.save()

    def _spawn(self, p: NodeProc, join: bool = False) -> None:
        self.spawned[p.node] = time.time()
        self.procs[p.node] = spawn(p.config, p.log, join=join)
        p.pid = self.procs[p.node].pid

    def frame(self, node: int) -> int:
        """The frame node ``node`` is at (its status file; -1 before its first)."""
        f = node_status(self.state, node).get("frame")
        return -1 if f is None else int(f)

    def wait(self, *, plan: FaultPlan | None = None, poll_s: float = 0.05,
             timeout_s: float | None = None,
             on_poll: Callable[[list[int]], None] | None = None) -> None:
        """Until every node this launcher owns has exited. A node the fault ``plan`` crashes
        (SIGKILL) is restarted with ``--join`` once the others reach its restart frame; any
        other failure, or ``timeout_s`` passing, raises :class:`ClusterError`. ``on_poll``
        gets the running nodes every ``poll_s``."""
        deadline = None if timeout_s is None else time.time() + timeout_s
        crashed: dict[int, int | None] = {}  # node -> frame to restart it at (plan)
        while self.procs or crashed:
            for node, pr in list(self.procs.items()):
                code = pr.poll()
                if code is None:
                    continue
                del self.procs[node]
                planned = plan is not None and any(f.node == node for f in plan.nodes)
                if code == -signal.SIGKILL and planned:  # the fault plan's crash
                    crashed[node] = next((f.restart for f in plan.nodes
                                          if f.node == node and f.restart is not None
                                          and f.restart > self.frame(node)), None)
                    continue
                if code != 0:
                    log = self.state.nodes[str(node)].log
                    tail = "\n".join(Path(log).read_text(errors="replace").splitlines()[-8:])
                    raise ClusterError(f"node {node} exited with code {code}; its log ({log}) "
                                       f"ends:\n{tail}")
            running = list(self.procs)
            if crashed:
                now = max((self.frame(i) for i in running), default=-1)
                for node, at in list(crashed.items()):
                    if at is None or not running:
                        del crashed[node]  # stays dead (or nobody left to rejoin)
                    elif now >= at - 1:
                        self.restart_node(node)
                        del crashed[node]
            if on_poll is not None:
                on_poll(running)
            if deadline is not None and time.time() > deadline:
                raise ClusterError(f"{self.size}-node cluster did not finish within "
                                   f"{timeout_s:.0f} s (logs in {self.out / 'logs'})")
            time.sleep(poll_s)

    def detach(self) -> None:
        """Leave the running processes to the cluster (its state file): ``stop`` spares them."""
        self.procs = {}

    def stop(self) -> None:
        """End every process this launcher owns (SIGTERM, then SIGKILL) and reap it."""
        if self.procs:
            terminate([pr.pid for pr in self.procs.values()])
            for pr in self.procs.values():
                pr.wait()
            self.procs = {}

    # -- acting on a running cluster -----------------------------------------------------------
    def running(self) -> list[int]:
        return [p.node for p in self.state.nodes.values() if alive(p.pid)]

    def node(self, node: int) -> NodeProc:
        try:
            return self.state.nodes[str(node)]
        except KeyError:
            raise ClusterError(f"no node {node} in this cluster (nodes "
                               f"{sorted(int(k) for k in self.state.nodes)})") from None

    def kill(self, node: int) -> int:
        """SIGKILL node ``node``: a real crash, no flush, no goodbye. Returns its pid."""
        p = self.node(node)
        if not alive(p.pid):
            raise ClusterError(f"node {node} is not running")
        os.kill(p.pid, signal.SIGKILL)
        return p.pid

    def restart_node(self, node: int) -> int:
        """Start node ``node`` again (ending it first if it runs) with ``--join``: it rejoins
        the running network at its neighbours' frame. Returns its new pid. Refused (a
        :class:`ClusterError`) when there is nothing to rejoin: the node finished its run, or
        no other node of the cluster runs ('sim_cluster up' starts a new run)."""
        p = self.node(node)
        st = node_status(self.state, node)
        if st.get("phase") == "finished" and not alive(p.pid):
            raise ClusterError(f"node {node} finished its run (frame {st.get('frame')} of "
                               f"{st.get('frames_total')}): nothing to restart; 'sim_cluster up' "
                               "starts a new run")
        others = [i for i in self.running() if i != node]
        if self.size > 1 and not others:
            raise ClusterError(f"no other node of the cluster in {self.out} runs: node {node} "
                               "would have no network to rejoin; 'sim_cluster up' starts a new run")
        if alive(p.pid):
            terminate([p.pid])
        self._spawn(p, join=True)
        p.restarts += 1
        self.state.save()
        return p.pid

    def down(self) -> int:
        """End every node of the cluster, owned or not; returns how many were running."""
        pids = [p.pid for p in self.state.nodes.values() if alive(p.pid)]
        terminate(pids)
        left = self.running()
        if left:
            raise ClusterError(f"nodes {left} could not be stopped")
        return len(pids)

    def status_table(self) -> str:
        return status_table(self.state)

    # -- results -------------------------------------------------------------------------------
    def counters(self, node: int) -> dict:
        return node_counters(self.state, node)

    def status(self, node: int) -> dict:
        return node_status(self.state, node)

    def gather(self, data, frames: int, config: str = "") -> dict:
        return gather(self.state, data, frames, config)


def gather(state: ClusterState, data, frames: int, config: str = "") -> dict:
    """Every node's tracks and counters, evaluated like an in-process run: ``summary.json``."""
    out = Path(state.out)
    tracks = {p.node: read_tracks(tracks_path(out / "nodes", p.node), frames, camera=p.node)
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
