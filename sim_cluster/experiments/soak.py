"""``sim_cluster soak``: real camera processes at camera rate for minutes, with seeded chaos.

``sim_cluster soak --minutes M --nodes N [--chaos SEED]`` starts N ``edge_node`` processes (one
per camera of a streaming scenario long enough never to end during the soak), paced at the
scenario's frame rate, and keeps them running for M minutes. With ``--chaos SEED`` it injects a
seeded schedule of faults (:func:`chaos_schedule`), one every ``--every`` minutes from minute 2:

``kill``         SIGKILL a node, restart it 5-20 s later (``--join``, as a supervisor would)
``freeze``       SIGSTOP a node for 2-8 s, then SIGCONT (a box that hangs)
``loss``         20-50 % of the messages on every link of one node lost for 20-40 s
``partition``    the network cut in two halves for 10-30 s
``long_freeze``  SIGSTOP a node for 30 s or 2 min (longer than its inbox window: it must learn
                 the network's frame and skip there)
``disk_full``    the nodes' output disk full for 20-40 s (the output folder is a tmpfs of the
                 soak's own, so it needs root; without, the fault is skipped and said so): every
                 node must say ``degraded`` within 2 s and go on tracking
``flood``        one message of 4,096 plausible phantom trackers to a node, as one of its
                 neighbours (``sim_cluster probe flood``)
``faulty``       one node faulty for 20-40 s, of a seeded kind (``hijack``, ``phantom``,
                 ``bumped``, ``hallucinate``, ``stale``, ``forged_merge``: edge_node/forgery.py);
                 its neighbours must not follow it (``edge_node/core/trust.py``)

Kills and freezes are signals from this driver at wall-clock times; loss, partitions and faulty
nodes are the nodes' own fault layer (``edge_node/faults.py``), written as a fault plan in frames (the frame a
second maps to at camera rate from frame 0). A node that exits when nobody killed it is an
*unplanned exit*: counted, logged and restarted (a supervisor would).

Every minute it samples each process: RSS (``/proc``), frames processed per second, sync
timeouts, late and rejected messages (the nodes' status files). After the soak each node's track
file is scored per minute on the ground (MOTA / IDF1 against the scenario's ground truth,
frames ``[m * 60 * fps, (m + 1) * 60 * fps)``), and so is a fault-free in-process run of the same
stream (``--no-reference`` skips it), which runs beside the soak at the lowest priority (it is
deterministic; the live nodes keep their CPU): the network at its best on that minute's people. A minute
*passes* when the survivors' (nodes no kill or freeze hit in that minute) mean ground MOTA is at
least 0.9 x the reference's; minutes with a planned fault and the minute after are exempt.
``soak.json`` and ``soak.png`` (the curves) go to ``--out``.
"""
from __future__ import annotations

import json
import math
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import motmetrics as mm
import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.faults import FAULTY_KINDS, FaultPlan, Network
from edge_node.formats.tracks import ID_BASE, iter_tracks
from edge_node.runtime.output import tracks_path
from protocol import codec
from protocol.keys import link_key
from sim_cluster.cluster.launcher import Cluster
from sim_cluster.cluster.state import ClusterError, node_status
from sim_cluster.evaluation.metrics import ground_distances, summarize
from sim_cluster.experiments.chaos import fill, phantom_message, publish_once, rss_kb
from sim_cluster.network.inprocess import run_network
from sim_cluster.scenarios.loader import open_scenario

KINDS = ("kill", "freeze", "loss", "partition", "long_freeze", "disk_full", "flood", "faulty")
#: the kinds the nodes apply themselves from the plan file (the others the soak does)
PLANNED = ("loss", "partition", "faulty")
DISK_MB = 1024  # the soak's output tmpfs (RAM-backed: only what the nodes write lives there)
DEGRADED_WITHIN_S = 2.0  # a full disk: every node says so within this long
RATIO = 0.9  # survivors' ground MOTA >= RATIO x the fault-free run's, outside exempt minutes


@dataclass(frozen=True)
class Fault:
    """One planned fault: ``kind`` at ``at_s`` seconds after frame 0, for ``duration_s``."""

    kind: str
    at_s: float
    duration_s: float
    node: int | None = None  # kill, freeze, loss
    groups: tuple[tuple[int, ...], ...] = ()  # partition
    loss: float = 0.0
    faulty: str = ""  # faulty: what the node does wrong (edge_node/faults.py FAULTY_KINDS)

    def minutes(self, minute_s: float = 60.0) -> set[int]:
        """The minutes it touches and the minute after (exempt from the MOTA check)."""
        first, last = int(self.at_s // minute_s), int((self.at_s + self.duration_s) // minute_s)
        return set(range(first, last + 2))


def chaos_schedule(seed: int, minutes: int, nodes: int, every: int = 3, first: int = 2,
                   minute_s: float = 60.0) -> list[Fault]:
    """One fault every ``every`` minutes from minute ``first``, kinds in a seeded shuffled cycle,
    targets, start seconds (5-20 s into the minute) and durations drawn from ``seed``. The same
    seed gives the same schedule. ``minute_s`` shrinks every time and duration (tests)."""
    rng = np.random.default_rng([seed, 0x50AC])
    out: list[Fault] = []
    cycle: list[str] = []
    for m in range(first, minutes, every):
        if not cycle:
            cycle = [KINDS[i] for i in rng.permutation(len(KINDS))]
        kind = cycle.pop()
        u = minute_s / 60.0
        at = minute_s * m + u * float(rng.uniform(5, 20))
        node = int(rng.integers(nodes))
        if kind == "kill":
            out.append(Fault(kind, at, u * float(rng.uniform(5, 20)), node=node))
        elif kind == "freeze":
            out.append(Fault(kind, at, u * float(rng.uniform(2, 8)), node=node))
        elif kind == "long_freeze":
            out.append(Fault(kind, at, u * float(rng.choice([30.0, 120.0])), node=node))
        elif kind == "disk_full":
            out.append(Fault(kind, at, u * float(rng.uniform(20, 40))))
        elif kind == "flood":
            out.append(Fault(kind, at, 0.0, node=node))
        elif kind == "faulty":
            out.append(Fault(kind, at, u * float(rng.uniform(20, 40)), node=node,
                             faulty=FAULTY_KINDS[int(rng.integers(len(FAULTY_KINDS)))]))
        elif kind == "loss":
            out.append(Fault(kind, at, u * float(rng.uniform(20, 40)), node=node,
                             loss=round(float(rng.uniform(0.2, 0.5)), 2)))
        else:
            half = nodes // 2
            out.append(Fault(kind, at, u * float(rng.uniform(10, 30)),
                             groups=(tuple(range(half)), tuple(range(half, nodes)))))
    return out


def stops_node(kind: str) -> bool:
    """Whether a fault of ``kind`` takes its node out for its duration (not a survivor)."""
    return kind in ("kill", "freeze", "long_freeze")


def fault_plan(faults: list[Fault], adjacency: dict[int, list[int]], fps: float,
               seed: int) -> dict:
    """The nodes' part of the schedule (loss, partitions) as a fault plan dict, in frames."""
    links, parts, faulty = [], [], []
    for f in faults:
        start, stop = round(f.at_s * fps), round((f.at_s + f.duration_s) * fps)
        if f.kind == "loss":
            for j in adjacency[f.node]:
                for a, b in ((f.node, j), (j, f.node)):
                    links.append({"src": a, "dst": b, "start": start, "stop": stop, "loss": f.loss})
        elif f.kind == "faulty":
            faulty.append({"node": f.node, "kind": f.faulty, "start": start, "stop": stop})
        elif f.kind == "partition" and all(f.groups):
            parts.append({"groups": [list(g) for g in f.groups], "start": start, "stop": stop})
    plan: dict = {"seed": int(seed)}
    if links:
        plan["link"] = links
    if parts:
        plan["partition"] = parts
    if faulty:
        plan["faulty"] = faulty
    return plan


def default_scenario(nodes: int) -> str:
    if nodes <= 4:
        return "terrace-sim"
    if nodes <= 8:
        return "ring8-sim"
    raise ClusterError(f"--nodes {nodes}: no preset has that many cameras; pass --scenario")


# -- the run ------------------------------------------------------------------------------------
class Soak:
    """Drives one soak: the cluster, the schedule, the per-minute samples."""

    def __init__(self, cluster: Cluster, faults: list[Fault], fps: float,
                 say: Callable[[str], None], minute_s: float = 60.0, disk: Path | None = None):
        self.cluster, self.faults, self.fps, self.say = cluster, faults, fps, say
        self.minute_s = minute_s
        self.disk = disk  # the nodes' output tmpfs (a disk_full fault fills it), or None
        self._filler: Path | None = None
        self._full: tuple[float, float, dict[int, float]] | None = None  # (from, until, degraded)
        self.events: list[dict] = []  # what happened, when (s after frame 0)
        self.unplanned: list[dict] = []
        self.samples: list[dict] = []
        self._dead: dict[int, float] = {}  # killed by the plan -> restart time
        self._frozen: dict[int, float] = {}  # frozen -> thaw time
        self._last: dict[int, dict] = {}
        self._todo = sorted((f for f in faults if f.kind not in PLANNED),
                            key=lambda f: f.at_s)

    def run(self, seconds: float) -> None:
        """Start the cluster, drive it for ``seconds`` after frame 0, stop it (never leaving a
        process stopped by SIGSTOP, whatever happens)."""
        c = self.cluster
        try:
            c.start()
            t0 = self._wait_frame0()
            self._sample(0.0, first=True)
            next_sample = self.minute_s
            while True:
                now = time.monotonic() - t0
                if now >= seconds:
                    break
                self._check_exits(now)
                self._act(now)
                if now >= next_sample:
                    self._sample(now)
                    next_sample += self.minute_s
                time.sleep(0.1)
            self._sample(time.monotonic() - t0)
        finally:
            for node in list(self._frozen):
                self._signal(node, signal.SIGCONT)
            if self._filler is not None:
                self._filler.unlink(missing_ok=True)
            c.stop()

    def _wait_frame0(self, timeout_s: float = 60.0) -> float:
        c = self.cluster
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(c.frame(i) >= 0 for i in range(c.size)):
                return time.monotonic() - (min(c.frame(i) for i in range(c.size)) / self.fps)
            for node, pr in c.procs.items():
                if pr.poll() is not None:
                    raise ClusterError(f"node {node} exited with code {pr.returncode} before its "
                                       f"first frame (log {c.state.nodes[str(node)].log})")
            time.sleep(0.05)
        raise ClusterError(f"the cluster did not reach frame 0 within {timeout_s:.0f} s")

    def _signal(self, node: int, sig: int) -> None:
        pid = self.cluster.state.nodes[str(node)].pid
        try:
            os.kill(pid, sig)
        except OSError:
            pass
        if sig == signal.SIGCONT:
            self._frozen.pop(node, None)

    def _act(self, now: float) -> None:
        c = self.cluster
        while self._todo and self._todo[0].at_s <= now:
            f = self._todo.pop(0)
            if f.node is not None and (f.node in self._dead or f.node in self._frozen):
                continue
            event = {"t_s": round(now, 2), "kind": f.kind, "node": f.node,
                     "duration_s": round(f.duration_s, 2)}
            self.events.append(event)
            self.say(f"{now:7.1f} s: {f.kind}" + (f" node {f.node}" if f.node is not None else "")
                     + f" for {f.duration_s:.1f} s")
            if f.kind == "disk_full":
                if self.disk is None or self._filler is not None:
                    event["skipped"] = "no tmpfs of its own (it needs root)"
                    self.say(f"{now:7.1f} s: disk_full skipped: {event['skipped']}")
                else:
                    t0 = time.monotonic()
                    self._filler = fill(self.disk)
                    full_at = now + (time.monotonic() - t0)  # the nodes' clock starts when it is full
                    event["fill_s"] = round(full_at - now, 2)
                    self._full = (full_at, now + f.duration_s, {})
                    event["degraded_after_s"] = self._full[2]
                continue
            if f.kind == "flood":
                event["sent_as"] = self._flood(f.node)
                continue
            if f.kind == "kill":
                c.kill(f.node)
                pr = c.procs.pop(f.node, None)
                if pr is not None:
                    pr.wait()
                self._dead[f.node] = now + f.duration_s
            else:
                self._signal(f.node, signal.SIGSTOP)
                self._frozen[f.node] = now + f.duration_s
        for node, at in list(self._dead.items()):
            if now >= at:
                c.restart_node(node)
                del self._dead[node]
                self.events.append({"t_s": round(now, 2), "kind": "restart", "node": node})
                self.say(f"{now:7.1f} s: restart node {node}")
        for node, at in list(self._frozen.items()):
            if now >= at:
                self._signal(node, signal.SIGCONT)
                self.events.append({"t_s": round(now, 2), "kind": "thaw", "node": node})
        if self._full is not None:
            start, until, degraded = self._full
            for i in range(c.size):
                if i not in degraded and node_status(c.state, i).get("phase") == "degraded":
                    degraded[i] = round(now - start, 2)
            if now >= until:
                self._filler.unlink(missing_ok=True)
                self._filler, self._full = None, None
                self.events.append({"t_s": round(now, 2), "kind": "disk_freed", "node": None})
                self.say(f"{now:7.1f} s: disk freed; degraded after {degraded} s")

    def _flood(self, node: int) -> int:
        """One message of 4,096 phantoms to ``node`` as its first neighbour; returns that
        neighbour's id."""
        c = self.cluster
        src = sorted(c.state.adjacency[str(node)])[0]
        k = max(c.frame(node), 0) + int(self.fps)  # it waits in the inbox for its frame
        payload = codec.encode(phantom_message(c.state.network, src, k, 4096))
        publish_once(c.state.network, [f"tcp/127.0.0.1:{c.state.nodes[str(node)].port}"],
                     link_key(c.state.network, src, node), payload)
        return src

    def _check_exits(self, now: float) -> None:
        c = self.cluster
        for node, pr in list(c.procs.items()):
            code = pr.poll()
            if code is None:
                continue
            del c.procs[node]
            log = c.state.nodes[str(node)].log
            tail = Path(log).read_text(errors="replace").splitlines()[-5:]
            self.unplanned.append({"t_s": round(now, 2), "node": node, "exit_code": code,
                                   "log_tail": tail})
            self.say(f"{now:7.1f} s: UNPLANNED exit of node {node} (code {code}); restarting")
            c.restart_node(node)

    def _sample(self, now: float, first: bool = False) -> None:
        c = self.cluster
        row: dict = {"t_s": round(now, 2), "nodes": {}}
        for i in range(c.size):
            p = c.state.nodes[str(i)]
            st = node_status(c.state, i)
            cur = {"pid": p.pid, "rss_mb": None if (r := rss_kb(p.pid)) is None else r / 1024,
                   "frame": st.get("frame"), "frames_done": st.get("frames_done", 0),
                   "timeouts": st.get("timeouts", 0), "late": st.get("late", 0),
                   "rejected": sum((st.get("rejected") or {}).values())}
            prev = self._last.get(i)
            same = prev is not None and prev["pid"] == cur["pid"]
            dt = now - prev["t"] if prev else 0.0
            delta = {k: cur[k] - (prev[k] if same else 0)
                     for k in ("frames_done", "timeouts", "late", "rejected")}
            row["nodes"][str(i)] = {
                "pid": cur["pid"], "rss_mb": cur["rss_mb"], "frame": cur["frame"],
                "age_s": round(time.time() - c.spawned.get(i, time.time()), 1),
                "fps": delta["frames_done"] / dt if dt > 0 and not first else None,
                **{k: delta[k] for k in ("timeouts", "late", "rejected")}}
            self._last[i] = {**cur, "t": now}
        self.samples.append(row)
        if not first:
            fr = [n["frame"] for n in row["nodes"].values()]
            rss = [n["rss_mb"] for n in row["nodes"].values()]
            self.say(f"{now:7.1f} s: frames {fr}, RSS MB "
                     f"{[None if r is None else round(r) for r in rss]}")


# -- scoring -------------------------------------------------------------------------------------
def frames_of(path: Path) -> Iterator[tuple[int, list[tuple[int, float, float]]]]:
    """``(frame, [(id, x, y)])`` groups of a node's track file in file order (every life of the
    node: a restarted one appends from a later frame)."""
    if not path.exists():
        return
    k, rows = None, []
    for t in iter_tracks(path):  # a torn or stray row is skipped and reported
        if t.frame != k and rows:
            yield k, rows
            rows = []
        k = t.frame
        rows.append((t.id[0] * ID_BASE + t.id[1], float(t.x[0]), float(t.x[1])))
    if rows:
        yield k, rows


class MinuteScore:
    """Ground MOTA / IDF1 per node per minute window (py-motmetrics accumulators)."""

    def __init__(self, stream, frames_per_minute: int, threshold_m: float = 1.0):
        self.stream, self.fpm, self.threshold_m = stream, frames_per_minute, threshold_m
        self.acc: dict[tuple[int, int], mm.MOTAccumulator] = {}

    def add(self, node: int, k: int, hyp: list[tuple[int, float, float]]) -> None:
        m = k // self.fpm
        acc = self.acc.setdefault((node, m), mm.MOTAccumulator(auto_id=False))
        f = self.stream.frame(k)
        hxy = np.array([(x, y) for _, x, y in hyp]).reshape(-1, 2)
        d2 = ground_distances(f.xy, hxy, self.stream.units_per_metre, self.threshold_m)
        acc.update([int(i) for i in f.ids], [h[0] for h in hyp], d2, frameid=k)

    def table(self) -> dict[int, dict[int, dict]]:
        """``minute -> node -> {"mota", "idf1"}``."""
        out: dict[int, dict[int, dict]] = {}
        for (node, m), acc in sorted(self.acc.items()):
            s = summarize(acc, "ground")
            out.setdefault(m, {})[node] = {"mota": s["mota"], "idf1": s["idf1"]}
        return out


def score_nodes(out: Path, stream, nodes: int, frames: int, fpm: int) -> dict[int, dict[int, dict]]:
    """Every node's track file scored per minute (frames in order, one pass over the stream)."""
    sc = MinuteScore(stream, fpm)
    files = [frames_of(tracks_path(out / "nodes", i)) for i in range(nodes)]
    head = [next(f, None) for f in files]
    for k in range(frames):
        for i in range(nodes):
            while head[i] is not None and head[i][0] < k:
                head[i] = next(files[i], None)
            rows = head[i][1] if head[i] is not None and head[i][0] == k else []
            sc.add(i, k, rows)
    return sc.table()


def score_reference(stream, adjacency: dict[int, list[int]], config: str, frames: int, fpm: int,
                    say: Callable[[str], None]) -> dict[int, dict[int, dict]]:
    """The same stream, fault-free, in one process (the sync network the nodes run)."""
    sc = MinuteScore(stream, fpm)
    t0 = time.monotonic()

    def on_frame(k: int, tracks: dict) -> None:
        for i, ts in tracks.items():
            sc.add(i, k, [(t.id[0] * ID_BASE + t.id[1], float(t.x[0]), float(t.x[1])) for t in ts])
        if (k + 1) % fpm == 0:
            say(f"reference: minute {(k + 1) // fpm} of {math.ceil(frames / fpm)} "
                f"({time.monotonic() - t0:.0f} s)")

    run_network(stream, adjacency, TrackerConfig.for_ablation(config), frames=frames,
                on_frame=on_frame)
    return sc.table()


def verdict(minutes: int, faults: list[Fault], nodes: dict[int, dict[int, dict]],
            reference: dict[int, dict[int, dict]] | None, samples: list[dict], unplanned: int,
            minute_s: float = 60.0, events: list[dict] = ()) -> dict:
    """Per minute: survivors' mean ground MOTA / IDF1 against the reference, exempt minutes;
    overall: pass when no unplanned exit, every process's RSS after its first minute within 10 %
    of its value then (a restarted process is a new one: its own first minute is its warm-up),
    every non-exempt minute's MOTA ratio >= ``RATIO``, and at every full disk every node said
    ``degraded`` within ``DEGRADED_WITHIN_S`` (``events``)."""
    exempt: set[int] = set()
    hit: dict[int, set[int]] = {}
    for f in faults:
        exempt |= f.minutes(minute_s)
        if stops_node(f.kind):
            for m in f.minutes(minute_s):
                hit.setdefault(m, set()).add(f.node)
    per_minute = []
    ok = True
    for m in range(minutes):
        row = nodes.get(m, {})
        live = [n for n in sorted(row) if n not in hit.get(m, set())]
        motas = [row[n]["mota"] for n in live if row[n]["mota"] is not None]
        idf1s = [row[n]["idf1"] for n in live if row[n]["idf1"] is not None]
        mota = float(np.mean(motas)) if motas else None
        ref = reference.get(m, {}) if reference else {}
        ref_m = [v["mota"] for v in ref.values() if v["mota"] is not None]
        ref_i = [v["idf1"] for v in ref.values() if v["idf1"] is not None]
        ref_mota = float(np.mean(ref_m)) if ref_m else None
        ratio = mota / ref_mota if mota is not None and ref_mota else None
        good = m in exempt or ratio is None or ratio >= RATIO
        ok &= good
        per_minute.append({"minute": m, "survivors": live, "mota": mota,
                           "idf1": float(np.mean(idf1s)) if idf1s else None,
                           "reference_mota": ref_mota,
                           "reference_idf1": float(np.mean(ref_i)) if ref_i else None,
                           "ratio": ratio, "exempt": m in exempt, "pass": good})
    lives: dict[tuple[str, int], list[float]] = {}  # (node, pid) -> RSS once a minute old
    for s in samples[1:]:
        for n, v in s["nodes"].items():
            if v["rss_mb"] is not None and v.get("age_s", minute_s) >= minute_s:
                lives.setdefault((n, v["pid"]), []).append(v["rss_mb"])
    drift: dict[str, float] = {}
    for (n, _), rss in lives.items():
        if len(rss) >= 2:  # against its first sample a minute or more into its life
            drift[n] = max(drift.get(n, 0.0), max(abs(r / rss[0] - 1.0) for r in rss))
    rss_ok = bool(drift) and all(d <= 0.10 for d in drift.values())
    nodes_n = len(samples[0]["nodes"]) if samples else 0
    disk = [e for e in events if e["kind"] == "disk_full" and "skipped" not in e]
    disk_ok = all(len(e["degraded_after_s"]) == nodes_n
                  and max(e["degraded_after_s"].values()) <= DEGRADED_WITHIN_S for e in disk)
    return {"minutes": per_minute, "rss_drift_after_warmup": drift, "rss_flat": rss_ok,
            "unplanned_exits": unplanned, "degraded_in_time": disk_ok,
            "pass": bool(ok and rss_ok and disk_ok and unplanned == 0 and reference is not None)}


# -- the plot -----------------------------------------------------------------------------------
def plot(report: dict, path: Path) -> None:
    import matplotlib  # plotting only here: keeps matplotlib out of every other command
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after use("Agg"): no display needed

    samples = report["samples"][1:]
    ms = report.get("minute_s", 60.0)
    t = [s["t_s"] / ms for s in samples]
    nodes = sorted(samples[0]["nodes"], key=int) if samples else []
    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    for n in nodes:
        ax[0].plot(t, [s["nodes"][n]["rss_mb"] for s in samples], marker=".", label=f"node {n}")
        ax[1].plot(t, [s["nodes"][n]["fps"] for s in samples], marker=".")
        ax[2].plot(t, [(s["nodes"][n]["timeouts"] or 0) + (s["nodes"][n]["rejected"] or 0)
                       for s in samples], marker=".")
    ax[0].set_ylabel("RSS (MB)")
    ax[0].legend(fontsize=7, ncol=4)
    ax[1].set_ylabel("frames / s")
    ax[1].axhline(report["fps"], color="grey", lw=0.8, ls="--")
    ax[2].set_ylabel("timeouts + rejected\n per minute")
    mins = report["verdict"]["minutes"]
    x = [m["minute"] + 1 for m in mins]
    ax[3].plot(x, [m["mota"] for m in mins], marker="o", label="survivors' ground MOTA")
    ax[3].plot(x, [m["reference_mota"] for m in mins], marker="s", ls="--",
               label="fault-free (in-process)")
    ax[3].plot(x, [m["idf1"] for m in mins], marker=".", alpha=0.6, label="survivors' IDF1")
    ax[3].set_ylabel("per minute")
    ax[3].set_xlabel("minutes (a minute's scores are plotted at its end)")
    ax[3].legend(fontsize=7)
    for e in report["events"]:
        if stops_node(e["kind"]) or e["kind"] == "disk_full":
            for a in ax:
                a.axvspan(e["t_s"] / ms, (e["t_s"] + e["duration_s"]) / ms, color="red",
                          alpha=0.15)
    for f in report["faults"]:
        if f["kind"] in PLANNED:
            for a in ax:
                a.axvspan(f["at_s"] / ms, (f["at_s"] + f["duration_s"]) / ms, color="orange",
                          alpha=0.15)
    fig.suptitle(f"soak: {report['nodes']} nodes, {report['topology']}, {report['minutes']} min, "
                 f"chaos seed {report['chaos']} (red: kill / freeze / full disk, orange: loss / "
                 "partition / a faulty node)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# -- the command --------------------------------------------------------------------------------
def soak(minutes: int, nodes: int, out: str | Path, *, chaos: int | None = None,
         scenario: str | None = None, topology: str = "ring", fps: float | None = None,
         seed: int = 0, config: str = "dkf+lda+dtm", every: int = 3, reference: bool = True,
         sync_timeout_s: float = 1.0, minute_s: float = 60.0,
         say: Callable[[str], None] = print) -> dict:
    """Run a soak (see the module docstring) and return its report (also ``soak.json``).
    ``minute_s``: the length of a "minute" (tests shrink it; the schedule shrinks with it)."""
    scenario = scenario or default_scenario(nodes)
    probe = open_scenario(scenario, seed=seed, frames=1)
    fps = float(fps or probe.fps)
    frames = int(math.ceil((minutes * minute_s + 120) * fps))  # never ends during the soak
    fpm = int(round(minute_s * fps))
    cluster = Cluster.prepare(out, network="soak", scenario=scenario, seed=seed, frames=frames,
                              mode="sync", topology=topology, nodes=nodes)
    out = cluster.out
    adjacency = {int(i): list(v) for i, v in cluster.state.adjacency.items()}
    faults = (chaos_schedule(chaos, minutes, nodes, every, minute_s=minute_s)
              if chaos is not None else [])
    faults = [f for f in faults if f.kind != "partition" or all(f.groups)]
    plan = fault_plan(faults, adjacency, fps, chaos or 0)
    cluster.reset(clear_logs=True)
    fault_file = None
    if any(key in plan for key in ("link", "partition", "faulty")):
        fault_file = out / "chaos.toml"
        fault_file.write_text(_toml(plan))
        FaultPlan.load(fault_file, Network(adjacency, frames))  # as the nodes will check it
    cluster.write_configs(config=config, sync_timeout_s=sync_timeout_s, startup_timeout_s=30.0,
                          fps=fps, faults=fault_file)
    say(f"soak: {nodes} nodes ({topology}, sync, {fps:g} fps, scenario {scenario}) for "
        f"{minutes} min in {out}; {len(faults)} planned faults")
    disk = _own_disk(out / "nodes", say) if any(f.kind == "disk_full" for f in faults) else None
    driver = Soak(cluster, faults, fps, say, minute_s, disk=disk)
    done = minutes * fpm
    ref_file = out / "reference.json"
    ref_file.unlink(missing_ok=True)
    background = None
    if reference:  # deterministic, so it runs beside the soak at the lowest priority
        say(f"fault-free reference: {done} frames in process, in the background (nice 19)")
        background = multiprocessing.get_context("fork").Process(
            target=_reference_job, args=(ref_file, scenario, seed, frames, nodes, adjacency,
                                         config, done, fpm), daemon=True)
        background.start()
    try:
        driver.run(minutes * minute_s)
    finally:
        if disk is not None:
            _leave_disk(disk)
    stream = open_scenario(scenario, seed=seed, frames=frames).first_cameras(nodes)
    say("scoring the nodes' tracks per minute")
    node_scores = score_nodes(out, stream, nodes, done, fpm)
    ref_scores = None
    if background is not None:
        say("waiting for the fault-free reference")
        background.join()
        if background.exitcode != 0 or not ref_file.exists():
            raise ClusterError(f"the fault-free reference run failed (exit {background.exitcode})")
        ref_scores = {int(m): {int(n): v for n, v in row.items()}
                      for m, row in json.loads(ref_file.read_text()).items()}
    report = {
        "minutes": minutes, "nodes": nodes, "topology": topology, "scenario": scenario,
        "seed": seed, "fps": fps, "chaos": chaos, "config": config, "minute_s": minute_s,
        "faults": [asdict(f) for f in faults], "events": driver.events,
        "unplanned": driver.unplanned, "samples": driver.samples,
        "scores": {str(m): {str(n): v for n, v in row.items()} for m, row in node_scores.items()},
        "reference": ({str(m): {str(n): v for n, v in row.items()}
                       for m, row in ref_scores.items()} if ref_scores else None),
        "verdict": verdict(minutes, faults, node_scores, ref_scores, driver.samples,
                           len(driver.unplanned), minute_s, driver.events),
    }
    (out / "soak.json").write_text(json.dumps(report, indent=1))
    plot(report, out / "soak.png")
    return report


def _own_disk(where: Path, say: Callable[[str], None]) -> Path | None:
    """Mount a tmpfs of ``DISK_MB`` at ``where`` (the nodes' output folder) for the disk_full
    faults to fill; ``None`` when it cannot (not root)."""
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK_MB}m", "tmpfs", str(where)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        say(f"no tmpfs for the disk_full faults ({r.stderr.strip() or 'mount failed'}): skipped")
        return None
    return where


def _leave_disk(where: Path) -> None:
    """Unmount the soak's tmpfs, its files kept in the folder beneath."""
    keep = Path(tempfile.mkdtemp(prefix="soak-nodes-", dir=where.parent))
    for f in where.iterdir():
        if not f.name.startswith(".filler"):
            shutil.move(str(f), keep / f.name)
    subprocess.run(["umount", "-l", str(where)], capture_output=True)
    for f in keep.iterdir():
        shutil.move(str(f), where / f.name)
    keep.rmdir()


def _reference_job(path: Path, scenario: str, seed: int, frames: int, nodes: int,
                   adjacency: dict[int, list[int]], config: str, done: int, fpm: int) -> None:
    """The fault-free reference in a child process at the lowest priority: the live nodes
    keep the CPU they need; its scores go to ``path`` (JSON)."""
    os.nice(19)
    stream = open_scenario(scenario, seed=seed, frames=frames).first_cameras(nodes)
    table = score_reference(stream, adjacency, config, done, fpm, lambda _: None)
    path.write_text(json.dumps({str(m): {str(n): v for n, v in row.items()}
                                for m, row in table.items()}))


def _toml(plan: dict) -> str:
    lines = [f"seed = {plan['seed']}"]
    for key in ("link", "partition", "faulty"):
        for rule in plan.get(key, []):
            lines.append(f"\n[[{key}]]")
            lines += [f"{k} = {json.dumps(v)}" for k, v in rule.items()]
    return "\n".join(lines) + "\n"


def summary_lines(report: dict) -> list[str]:
    v = report["verdict"]
    lines = [f"{'min':>3} {'RSS MB (per node)':>28} {'fps':>11} {'tmo':>4} {'rej':>4} "
             f"{'MOTA':>6} {'ref':>6} {'ratio':>6} {'IDF1':>6}  note"]
    samples = report["samples"][1:]
    for m in v["minutes"]:
        s = samples[m["minute"]] if m["minute"] < len(samples) else None
        nodes = s["nodes"] if s else {}
        rss = " ".join(f"{n['rss_mb']:.0f}" if n["rss_mb"] else "-" for n in nodes.values())
        fpss = [n["fps"] for n in nodes.values() if n["fps"] is not None]
        fps = f"{min(fpss):.1f}-{max(fpss):.1f}" if fpss else "-"
        tmo = sum(n["timeouts"] or 0 for n in nodes.values())
        rej = sum(n["rejected"] or 0 for n in nodes.values())
        f = lambda x: "-" if x is None else f"{x:.3f}"  # noqa: E731
        ms = report.get("minute_s", 60.0)
        events = [f"{e['kind']} {'' if e.get('node') is None else e['node']}".strip()
                  for e in report["events"] if int(e["t_s"] // ms) == m["minute"]
                  and (stops_node(e["kind"]) or e["kind"] in ("disk_full", "flood"))]
        events += [f"{f['kind']} {f['faulty']} {f['node']}" if f["kind"] == "faulty" else f["kind"]
                   for f in report["faults"]
                   if f["kind"] in PLANNED and int(f["at_s"] // ms) == m["minute"]]
        note = ", ".join(events) + (" (exempt)" if m["exempt"] else "")
        lines.append(f"{m['minute'] + 1:>3} {rss:>28} {fps:>11} {tmo:>4} {rej:>4} "
                     f"{f(m['mota']):>6} {f(m['reference_mota']):>6} {f(m['ratio']):>6} "
                     f"{f(m['idf1']):>6}  {note}")
    drift = ", ".join(f"node {n} {100 * d:.1f}%" for n, d in
                      sorted(v["rss_drift_after_warmup"].items(), key=lambda kv: int(kv[0])))
    lines.append(f"unplanned exits {v['unplanned_exits']}; largest RSS change after a process's "
                 f"first minute: {drift}; "
                 f"{'PASS' if v['pass'] else 'FAIL'}")
    return lines


def main(args) -> int:
    def say(text: str) -> None:
        if not args.quiet:
            print(f"soak: {text}", file=sys.stderr, flush=True)

    report = soak(args.minutes, args.nodes, args.out, chaos=args.chaos, scenario=args.scenario,
                  topology=args.topology, fps=args.fps, seed=args.seed, config=args.config,
                  every=args.every, reference=not args.no_reference, say=say)
    print("\n".join(summary_lines(report)))
    print(f"wrote {Path(args.out) / 'soak.json'} and soak.png")
    return 0 if report["verdict"]["pass"] else 1
