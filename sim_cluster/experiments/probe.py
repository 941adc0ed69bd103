"""``sim_cluster probe KIND``: the zombie probes of the README's fault table, each measured on real
processes on loopback against its goal, printed as a table and written to
``<out>/probe_<kind>.json``.

``freeze``     SIGSTOP one node of a paced ring for each of ``--seconds`` (5, 30, 120, 600 s), in
               each of ``--modes`` (sync, async); after SIGCONT, the seconds until the frozen
               node is within one frame of its neighbours (goal: 2 s; of the span of their
               frames: async nodes keep their own clocks, so neighbours may be frames apart), and its neighbours' frame
               rate from the freeze to 10 s after it, in all and in the worst second (goal: at
               least 0.95 of camera rate).
``disk-full``  the nodes' output folder on a small tmpfs (root: it mounts one) that is filled
               mid-run; a node killed and restarted while the disk is full; then space freed:
               seconds until every node says ``degraded`` (goal: 2 s), frames and messages while
               full (goal: tracking and sending on), unreadable rows and (frame, id) rows written
               twice in the track files at the end (goal: none).
``restarts``   ``--kills`` (30) kill -9 at seeded random times, each node restarted as a
               supervisor would (``--join``): unreadable rows and (frame, id) rows twice (goal:
               none).
``flood``      one message of ``--phantoms`` (4,096) plausible phantom trackers under fresh ids
               of node 0, published on its link to node 1 by a session that is not node 0 (no
               access control here; with mTLS and the ACL only node 0's certificate could): the
               honest nodes' frame rate and resident memory before and after (goals: camera
               rate, +10 %), every node still sending, how many phantoms were taken, and the
               honest people's tracks against the in-process run without the flood (goal: the
               same ids, positions within ``HONEST_DEV_M``).
``boot``       a paced chain with its last camera absent: when each node completes its first
               second of frames after the first node started (goals: nodes not bordering the
               absent camera within 1 s, its neighbour within 5 s).

Each cluster plays terrace-sim at 25 frames/s (``--fps``) from the ``scenario`` source, so the
probes need no data.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.formats.tracks import iter_tracks
from edge_node.runtime.inbox import LOSS_RUN
from edge_node.runtime.output import tracks_path
from protocol import codec
from protocol.keys import link_key
from sim_cluster.cluster.launcher import Cluster
from sim_cluster.cluster.processes import spawn, terminate
from sim_cluster.cluster.state import ClusterError, node_counters, node_status
from sim_cluster.experiments.chaos import PHANTOM_COUNTER, fill, phantom_message, publish_once, rss_kb
from sim_cluster.experiments.provenance import provenance
from sim_cluster.network.inprocess import run_network
from sim_cluster.network.topology import build
from sim_cluster.scenarios.loader import open_scenario

KINDS = ("freeze", "disk-full", "restarts", "flood", "boot")
SCENARIO = "terrace-sim"
CONFIG = "dkf+lda+dtm"


# -- a cluster to probe ----------------------------------------------------------------------------
def _cluster(out: Path, *, nodes: int, topology: str, mode: str, fps: float, seconds: float,
             network: str = "probe") -> Cluster:
    """A cluster written (not started) in ``out``, long enough for ``seconds`` at ``fps``,
    its nodes writing their status every frame."""
    frames = int((seconds + 120) * fps)
    c = Cluster.prepare(out, network=network, scenario=SCENARIO, seed=0, frames=frames,
                        mode=mode, topology=topology, nodes=nodes)
    c.reset(clear_logs=True)
    c.write_configs(config=CONFIG, sync_timeout_s=1.0, startup_timeout_s=30.0, fps=fps,
                    status_interval_s=0.02)
    return c


class Sampler:
    """Every node's status (frame, phase, messages sent, when written) every ``every`` s, from
    a thread of its own."""

    def __init__(self, cluster: Cluster, every: float = 0.05):
        self.cluster, self.every = cluster, every
        self.rows: list[tuple[float, int, dict]] = []  # (monotonic, node, status)
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "Sampler":
        self._t.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._t.join()

    def _run(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            for i in range(self.cluster.size):
                self.rows.append((now, i, node_status(self.cluster.state, i)))
            self._stop.wait(self.every)

    def series(self, node: int, key: str) -> list[tuple[float, object]]:
        return [(t, st.get(key)) for t, n, st in self.rows if n == node and key in st]

    def frame_at(self, node: int, t: float) -> int | None:
        """The node's last frame by monotonic time ``t``."""
        best = None
        for tt, f in self.series(node, "frame"):
            if tt > t:
                break
            best = f
        return best


def _wait(pred: Callable[[], bool], timeout: float, what: str, every: float = 0.05) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return
        time.sleep(every)
    raise ClusterError(f"probe: {what} within {timeout:.0f} s")


def _frames(c: Cluster) -> list[int]:
    return [c.frame(i) for i in range(c.size)]


def _running(c: Cluster, min_frame: int = 25) -> None:
    _wait(lambda: min(_frames(c)) >= min_frame, 90, f"every node past frame {min_frame}")


def _file_rows(out: Path, node: int) -> tuple[int, int, bool]:
    """A node's track file: (unreadable rows, (frame, id) rows written twice, ends whole)."""
    path = tracks_path(out / "nodes", node)
    if not path.exists():
        return 0, 0, True
    bad: list[int] = []
    seen = Counter((t.frame, t.id) for t in iter_tracks(path, bad=bad))
    return len(bad), sum(n - 1 for n in seen.values() if n > 1), path.read_bytes().endswith(b"\n")


# -- freeze ------------------------------------------------------------------------------------------
def probe_freeze(out: Path, seconds: list[float], modes: list[str], *, nodes: int = 4,
                 topology: str = "ring", fps: float = 25.0, node: int = 1,
                 say: Callable[[str], None] = print) -> list[dict]:
    rows = []
    for mode in modes:
        for d in seconds:
            c = _cluster(out / f"freeze-{mode}-{d:g}s", nodes=nodes, topology=topology,
                         mode=mode, fps=fps, seconds=d + 40)
            neigh = list(c.state.adjacency[str(node)])
            say(f"freeze: {mode}, node {node} frozen {d:g} s ({nodes}-node {topology}, {fps:g} fps)")
            try:
                c.start()
                with Sampler(c) as s:
                    _running(c)
                    time.sleep(3.0)
                    pid = c.state.nodes[str(node)].pid
                    t_stop = time.monotonic()
                    os.kill(pid, signal.SIGSTOP)
                    try:
                        time.sleep(d)
                    finally:
                        os.kill(pid, signal.SIGCONT)
                    t_cont = time.monotonic()
                    time.sleep(10.0)
                    t_end = time.monotonic()
            finally:
                c.down()
            rows.append(_freeze_row(s, mode, d, node, neigh, fps, t_stop, t_cont, t_end,
                                    node_counters(c.state, node)))
            rows[-1]["world_walk_s"] = _world_walk_s(node, s.frame_at(node, t_stop),
                                                   s.frame_at(node, t_end))
            say(f"  caught up in {rows[-1]['catch_up_s']} s; neighbours at "
                f"{rows[-1]['neighbour_rate']} of camera rate (worst second "
                f"{rows[-1]['neighbour_worst_second']})")
    return rows


def _world_walk_s(node: int, before: int | None, frame: int | None) -> float | None:
    """CPU seconds the scenario source takes to make ``frame`` once it made ``before`` (where
    the node froze): part of a skip's catch-up time that only a simulated camera has (the
    synthetic world walks its people frame by frame to get there; a camera serves its current
    frame)."""
    if frame is None or before is None:
        return None
    spent = []
    for _ in range(2):  # the first pass pays one-off imports and caches the node had paid
        camera = open_scenario(SCENARIO, seed=0, frames=frame + 1).camera(node)  # node n: camera n
        camera(before)
        t0 = time.process_time()
        camera(frame)
        spent.append(time.process_time() - t0)
    return round(spent[-1], 2)


def _freeze_row(s: Sampler, mode: str, d: float, node: int, neigh: list[int], fps: float,
                t_stop: float, t_cont: float, t_end: float, counters: dict) -> dict:
    caught = None
    for t, n, st in s.rows:
        if n != node or t < t_cont or st.get("frame") is None:
            continue
        others = [s.frame_at(j, t) for j in neigh]
        if any(f is None for f in others):
            continue
        if min(others) - 1 <= st["frame"] <= max(others) + 1:  # within a frame of them
            caught = round(t - t_cont, 2)
            break
    rates, worst = [], []
    for j in neigh:
        f0, f1 = s.frame_at(j, t_stop), s.frame_at(j, t_end)
        if f0 is not None and f1 is not None:
            rates.append((f1 - f0) / (t_end - t_stop) / fps)
        t = t_stop
        while t + 1.0 <= t_end:
            a, b = s.frame_at(j, t), s.frame_at(j, t + 1.0)
            if a is not None and b is not None:
                worst.append((b - a) / fps)
            t += 0.5
    def offset(t: float) -> int | None:  # the node's frame less its neighbours' newest
        f, others = s.frame_at(node, t), [s.frame_at(j, t) for j in neigh]
        return None if f is None or None in others else f - max(others)

    cu = counters.get("catch_up") or {}
    return {"mode": mode, "freeze_s": d, "catch_up_s": caught,
            "offset_before": offset(t_stop - 0.5), "offset_end": offset(t_end),
            "neighbour_rate": round(min(rates), 3) if rates else None,
            "neighbour_worst_second": round(min(worst), 3) if worst else None,
            "catch_ups": cu.get("catch_ups"), "frames_skipped": cu.get("frames_skipped"),
            "core_restarts": cu.get("core_restarts"),
            # frames the node ran level with the network before its camera had an image again
            # (the simulated world walking there in the background: Source.seek)
            "frames_without_image": cu.get("frames_without_image"),
            "pass": caught is not None and caught <= 2.0 and bool(rates) and min(rates) >= 0.95}


# -- a full disk -------------------------------------------------------------------------------------
def _mount_tmpfs(where: Path, size: str) -> None:
    where.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise ClusterError(f"probe disk-full: cannot mount a tmpfs at {where} (it needs root): "
                           f"{r.stderr.strip()}")


def probe_disk_full(out: Path, *, nodes: int = 4, topology: str = "ring", fps: float = 25.0,
                    full_s: float = 20.0, say: Callable[[str], None] = print) -> list[dict]:
    c = Cluster.prepare(out / "disk-full", network="probe", scenario=SCENARIO, seed=0,
                        frames=int((full_s + 120) * fps), mode="sync", topology=topology,
                        nodes=nodes)
    mnt = c.out / "nodes"
    _mount_tmpfs(mnt, "4m")
    victim = 2
    try:
        c.reset(clear_logs=True)
        c.write_configs(config="dkf+lda+dtm", sync_timeout_s=1.0, startup_timeout_s=30.0,
                        fps=fps, status_interval_s=0.02)
        say(f"disk-full: {nodes}-node {topology} at {fps:g} fps, its output on a 4 MB tmpfs")
        c.start()
        with Sampler(c) as s:
            _running(c)
            time.sleep(3.0)
            t_full = time.monotonic()
            filler = fill(mnt)
            say("  disk full")
            time.sleep(full_s / 2)
            c.kill(victim)
            c.procs.pop(victim).wait()
            c.restart_node(victim)
            say(f"  node {victim} killed and restarted while the disk is full")
            time.sleep(full_s / 2)
            t_free = time.monotonic()
            filler.unlink()
            say("  space freed")
            time.sleep(15.0)
            t_end = time.monotonic()
    finally:
        try:
            c.down()
        finally:
            rows = _disk_rows(c, s, t_full, t_free, t_end, fps)
            subprocess.run(["umount", "-l", str(mnt)], capture_output=True)
    return rows


def _disk_rows(c: Cluster, s: Sampler, t_full: float, t_free: float, t_end: float,
               fps: float) -> list[dict]:
    rows = []
    for i in range(c.size):
        degraded = next((round(t - t_full, 2) for t, st in s.series(i, "phase")
                         if t >= t_full and st == "degraded"), None)
        recovered = next((round(t - t_free, 2) for t, st in s.series(i, "phase")
                          if t >= t_free and st == "running"), None)
        frames_full = [f for t, f in s.series(i, "frame")
                       if t_full <= t <= t_free and f is not None]
        sent = [m for t, m in s.series(i, "messages_sent") if t_full <= t <= t_free and m is not None]
        bad, twice, whole = _file_rows(c.out, i)
        rows.append({"node": i, "degraded_after_s": degraded, "running_after_freed_s": recovered,
                     "frames_while_full": (max(frames_full) - min(frames_full)) if frames_full else 0,
                     "messages_while_full": (max(sent) - min(sent)) if sent else 0,
                     "unreadable_rows": bad, "rows_twice": twice, "file_whole": whole,
                     "pass": (degraded is not None and degraded <= 2.0 and bool(frames_full)
                              and max(frames_full) > min(frames_full) and bad == 0
                              and twice == 0 and whole and recovered is not None)})
    return rows


# -- kills and restarts --------------------------------------------------------------------------------
def probe_restarts(out: Path, *, kills: int = 30, nodes: int = 4, topology: str = "ring",
                   fps: float = 25.0, seed: int = 0,
                   say: Callable[[str], None] = print) -> list[dict]:
    rng = np.random.default_rng(seed)
    gaps = rng.uniform(0.5, 4.0, size=kills)
    c = _cluster(out / "restarts", nodes=nodes, topology=topology, mode="sync", fps=fps,
                 seconds=float(gaps.sum()) + 30)
    say(f"restarts: {kills} kill -9 in a {nodes}-node {topology} at {fps:g} fps (seed {seed})")
    try:
        c.start()
        _running(c)
        for n, gap in enumerate(gaps):
            time.sleep(float(gap))
            victim = int(rng.integers(nodes))
            c.kill(victim)
            c.procs.pop(victim).wait()
            time.sleep(float(rng.uniform(0.0, 1.0)))
            c.restart_node(victim)
            if (n + 1) % 10 == 0:
                say(f"  {n + 1} kills")
        time.sleep(3.0)
    finally:
        c.down()
    rows = []
    for i in range(nodes):
        bad, twice, whole = _file_rows(c.out, i)
        rows.append({"node": i, "restarts": c.state.nodes[str(i)].restarts,
                     "unreadable_rows": bad, "rows_twice": twice, "file_whole": whole,
                     "pass": bad == 0 and twice == 0 and whole})
    return rows


# -- a phantom flood -------------------------------------------------------------------------------
def probe_flood(out: Path, *, phantoms: int = 4096, nodes: int = 4, topology: str = "ring",
                fps: float = 25.0, say: Callable[[str], None] = print) -> list[dict]:
    c = _cluster(out / "flood", nodes=nodes, topology=topology, mode="sync", fps=fps,
                 seconds=60)
    say(f"flood: one message of {phantoms} phantoms to node 1 as node 0 ({nodes}-node "
        f"{topology}, {fps:g} fps)")
    try:
        c.start()
        with Sampler(c) as s:
            _running(c)
            time.sleep(8.0)
            t0 = time.monotonic()
            rss0 = {i: rss_kb(c.state.nodes[str(i)].pid) for i in range(nodes)}
            k = c.frame(1) + int(fps)  # a second ahead: it waits in node 1's inbox for its frame
            msg = phantom_message(c.state.network, 0, k, phantoms)
            payload = codec.encode(msg)
            port = c.state.nodes["1"].port
            publish_once(c.state.network, [f"tcp/127.0.0.1:{port}"],
                         link_key(c.state.network, 0, 1), payload)
            t1 = time.monotonic()
            say(f"  sent ({len(payload)} bytes) for frame {k}")
            time.sleep(10.0)
            t2 = time.monotonic()
            rss1 = {i: rss_kb(c.state.nodes[str(i)].pid) for i in range(nodes)}
    finally:
        c.down()
    honest = _honest_tracks(c, nodes, topology, k)
    rows = []
    for i in range(nodes):
        def rate(a, b):
            fa, fb = s.frame_at(i, a), s.frame_at(i, b)
            return None if fa is None or fb is None else round((fb - fa) / (b - a) / fps, 3)

        sent = s.series(i, "messages_sent")
        after = [m for t, m in sent if t >= t2 - 2.0]
        before = [m for t, m in sent if t1 <= t <= t1 + 2.0]
        cnt = node_counters(c.state, i)
        rej = cnt.get("rejected") or {}
        r0, r1 = rss0[i], rss1[i]
        growth = None if not r0 or not r1 else round(r1 / r0 - 1.0, 3)
        rows.append({"node": i, "rate_before": rate(t0 - 5.0, t0), "rate_after": rate(t1, t2),
                     "rss_mb_before": None if r0 is None else round(r0 / 1024, 1),
                     "rss_growth": growth,
                     "still_sending": bool(after and before and max(after) > max(before)),
                     "too_many_trackers": rej.get("too_many_trackers", 0),
                     "adoption_rate": rej.get("adoption_rate", 0),
                     "trackers_cut": cnt.get("trackers_cut"), "encode_errors": cnt.get("encode_errors"),
                     "implausible_birth": rej.get("implausible_birth", 0),
                     **honest[i],
                     "pass": (growth is not None and growth <= 0.10
                              and (rate(t1, t2) or 0) >= 0.95 and bool(after and before
                                                                        and max(after) > max(before))
                              and honest[i]["id_frames_changed"] == 0
                              and (honest[i]["dev_after_m"] or 0.0) <= HONEST_DEV_M)})
    return rows


HONEST_DEV_M = 0.25  # m, half a person's width. Not 0: the forged message takes the place of
# node 0's own message of its frame (first come; the real one then comes late), and node 1 takes
# node 0's messages of the LOSS_RUN frames before it for lost (a link delivers in order), so
# node 1 fuses up to five frames without node 0's measurements: a loss, not the phantoms


def _honest_tracks(c: Cluster, nodes: int, topology: str, k_flood: int) -> dict[int, dict]:
    """Each node's tracks of honest people (ids that are not the phantoms') against the
    in-process run of the same frames without the flood (the sync shells agree track for track,
    ``tests/test_cluster.py``): before the flood the largest position difference (0 when the
    comparison is valid: no sync timeout); from ``LOSS_RUN`` frames before the flood's frame
    on, the frames whose honest ids differ and the largest position difference of the ids both
    hold (``HONEST_DEV_M``)."""
    def honest(ts) -> dict:
        return {t.id: np.asarray(t.x[:2], float) for t in ts if t.id[1] < PHANTOM_COUNTER}

    got: dict[int, dict[int, dict]] = {i: {} for i in range(nodes)}
    for i in range(nodes):
        path = tracks_path(c.out / "nodes", i)
        for t in (iter_tracks(path) if path.exists() else ()):
            row = got[i].setdefault(t.frame, {})
            if t.id[1] < PHANTOM_COUNTER:
                row[t.id] = np.asarray(t.x[:2], float)
    last = min((max(g) for g in got.values() if g), default=-1)
    ref: dict[int, dict[int, dict]] = {i: {} for i in range(nodes)}

    def on_frame(k: int, tracks: dict) -> None:
        for i, ts in tracks.items():
            ref[i][k] = honest(ts)

    if last >= 0:
        stream = open_scenario(SCENARIO, seed=0, frames=last + 1).first_cameras(nodes)
        run_network(stream, build(topology, nodes), TrackerConfig.for_ablation(CONFIG),
                    frames=last + 1, on_frame=on_frame)
    k_from = k_flood - LOSS_RUN
    out = {}
    for i in range(nodes):
        before, after, changed = 0.0, 0.0, 0
        for k in range(last + 1):
            a, b = got[i].get(k, {}), ref[i].get(k, {})
            if k >= k_from and set(a) != set(b):
                changed += 1
            dev = max((float(np.hypot(*(a[t] - b[t]))) for t in set(a) & set(b)), default=0.0)
            if k < k_from:
                before = max(before, dev)
            else:
                after = max(after, dev)
        out[i] = {"dev_before_m": round(before, 6), "id_frames_changed": changed,
                  "dev_after_m": round(after, 4), "frames_compared": last + 1 - k_from}
    return out


# -- boot with a camera absent -------------------------------------------------------------------------
def probe_boot(out: Path, *, nodes: int = 4, fps: float = 25.0,
               say: Callable[[str], None] = print) -> list[dict]:
    c = Cluster.prepare(out / "boot", network="probe", scenario=SCENARIO, seed=0,
                        frames=int(120 * fps), mode="sync", topology="chain", nodes=nodes)
    c.reset(clear_logs=True)
    c.write_configs(config="dkf+lda+dtm", sync_timeout_s=1.0, startup_timeout_s=5.0, fps=fps,
                    status_interval_s=0.02)
    absent = nodes - 1
    say(f"boot: a {nodes}-node chain at {fps:g} fps without camera {absent} (startup_timeout_s 5)")
    procs = [spawn(c.state.nodes[str(i)].config, c.state.nodes[str(i)].log)
             for i in range(absent)]
    try:
        with Sampler(c, every=0.02) as s:
            _wait(lambda: all(c.frame(i) >= fps for i in range(absent)), 90,
                  "every present node a second into its frames")
    finally:
        terminate([p.pid for p in procs])
        for p in procs:
            p.wait()
    first = {}
    for i in range(absent):
        # when it started its frames: the first status with a frame, less the frames it had
        # done at camera rate by then
        for t, f in s.series(i, "frame"):
            if f is not None:
                first[i] = t - f / fps
                break
    t0 = min(first.values())
    rows = []
    for i in range(absent):
        borders = absent in c.state.adjacency[str(i)]
        goal = 5.0 if borders else 1.0
        late = round(first[i] - t0, 2)
        rows.append({"node": i, "borders_absent": borders, "started_after_s": late,
                     "goal_s": goal, "pass": late <= goal})
    return rows


# -- the command -----------------------------------------------------------------------------------------
def _table(kind: str, rows: list[dict]) -> str:
    keys = [k for k in rows[0] if k != "pass"] + ["pass"]
    lines = ["  ".join(f"{k:>{max(len(k), 6)}}" for k in keys)]
    for r in rows:
        lines.append("  ".join(f"{str(r[k]):>{max(len(k), 6)}}" for k in keys))
    return f"probe {kind}:\n" + "\n".join(lines)


def main(args) -> int:
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    work = Path(args.work).resolve() if args.work else out  # where the probes' clusters run
    work.mkdir(parents=True, exist_ok=True)

    def say(text: str) -> None:
        if not args.quiet:
            print(f"probe: {text}", file=sys.stderr, flush=True)

    kind = args.kind
    if kind == "freeze":
        rows = probe_freeze(work, [float(x) for x in args.seconds.split(",")],
                            args.modes.split(","), nodes=args.nodes, fps=args.fps, say=say)
    elif kind == "disk-full":
        rows = probe_disk_full(work, nodes=args.nodes, fps=args.fps, say=say)
    elif kind == "restarts":
        rows = probe_restarts(work, kills=args.kills, nodes=args.nodes, fps=args.fps,
                              seed=args.seed, say=say)
    elif kind == "flood":
        rows = probe_flood(work, phantoms=args.phantoms, nodes=args.nodes, fps=args.fps, say=say)
    else:
        rows = probe_boot(work, nodes=args.nodes, fps=args.fps, say=say)
    report = {"kind": kind, "rows": rows, "pass": all(r["pass"] for r in rows),
              "meta": {"provenance": provenance()}}
    (out / f"probe_{kind}.json").write_text(json.dumps(report, indent=1))
    print(_table(kind, rows))
    print(f"{'PASS' if report['pass'] else 'FAIL'}; wrote {out / f'probe_{kind}.json'}")
    return 0 if report["pass"] else 1
