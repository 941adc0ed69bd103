"""``sim_cluster bench --cameras 4,16,64 [--layout corridor|grid]``: what a network of N cameras
costs each node, at the same density of people per camera (issue 15).

For each N it runs the in-process network (``run_network``, sync mode) on the generated layout
``<layout>-<N>`` (:mod:`sim_cluster.scenarios.synthetic.layout`: 6.25 people per camera, long
walks) with the layout's neighbour graph (a chain for a corridor, the 4-neighbour lattice for a
grid), and reports per N:

* **CPU ms per node-frame**: ``time.process_time`` around each node's ``prepare`` + ``update``
  (the codec and the world are not in it), median and p90 over every (node, frame);
* **trackers held per node**: ``len(node.trackers)`` after each update (reported and coasting
  ones), median and max over every (node, frame);
* **bytes per node-frame**: every encoded message's bytes / (nodes x frames);
* **ground MOTA / IDF1**: each node's whole track set against everybody in view within 1 m
  (the project's ground view; :class:`~sim_cluster.evaluation.online.OnlineGround`), median
  over nodes;
* **id kept on long walks** and **ids per long walk**
  (:mod:`sim_cluster.evaluation.walks`): for people who cross at least ``--long-walk-cameras``
  (4) cameras' views, the walk-weighted fraction of their frames matched to their dominant id,
  and their distinct ids; median over nodes. ``-`` when nobody walks that far in the run;
* **frames/s** of the whole simulated network (wall time of the run, world generation
  included, evaluation excluded), and the run's wall and CPU seconds.

Results go to ``<out>/scale.json`` (with the per-node metrics) and ``<out>/scale.csv``. The
tracker configuration is a :class:`TrackerConfig` (``--config`` and ``--tracker-config``, as
``sim_cluster run``), so a later option such as a hop limit is one more field.
"""
from __future__ import annotations

import csv
import json
import statistics
import time
from pathlib import Path

import numpy as np

from edge_node.core.config import TrackerConfig
from sim_cluster.evaluation.online import OnlineGround
from sim_cluster.evaluation.walks import WalkLog, walk_ids
from sim_cluster.network.inprocess import run_network
from sim_cluster.progress import progress_bar
from sim_cluster.scenarios.loader import open_scenario

COLUMNS = ("cameras", "frames", "people_per_frame", "cpu_ms_median", "cpu_ms_p90",
           "trackers_median", "trackers_max", "bytes_per_node_frame", "mota", "idf1",
           "long_walkers", "id_kept", "ids_per_walk", "frames_per_s", "wall_s", "cpu_s")


def scale_run(layout: str, cameras: int, cfg: TrackerConfig, *, frames: int | None = None,
              seed: int = 0, ground_threshold_m: float = 1.0, long_walk_cameras: int = 4,
              show_progress: bool = False) -> dict:
    """One size of the sweep: the row of the table (``COLUMNS``) plus ``per_node`` metrics."""
    data = open_scenario(f"{layout}-{cameras}", seed=seed, frames=frames)
    cpu_ms: list[float] = []
    held: list[int] = []
    people: list[int] = []
    ground = OnlineGround(data.units_per_metre, ground_threshold_m)
    walks = WalkLog()
    eval_s = 0.0

    def probe(k, node, cpu_s, camera_node) -> None:
        cpu_ms.append(1000.0 * cpu_s)
        held.append(len(camera_node.trackers))

    def on_frame(k, tracks) -> None:
        nonlocal eval_s
        t0 = time.perf_counter()
        truth = data.frame(k)
        walks.observe(truth)
        people.append(len(truth.ids))
        for node, ts in tracks.items():
            ground.add(node, k, ts, truth)
        eval_s += time.perf_counter() - t0

    update, close = progress_bar(f"{data.name}", data.frames, show_progress)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    try:
        result = run_network(data, data.neighbours, cfg, topology_name="layout", probe=probe,
                             on_frame=on_frame, progress=update)
    finally:
        close()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    t0 = time.perf_counter()
    metrics = ground.summary()
    walkers = walks.long_walkers(long_walk_cameras)
    per_walk = {str(n): walk_ids(ground.matches(n), walks.frames, walkers) for n in ground.nodes}
    eval_s += time.perf_counter() - t0
    n, f = data.num_cameras, result.frames
    kept = [w["id_kept"] for w in per_walk.values() if w["id_kept"] is not None]
    ids = [w["ids_per_walk"] for w in per_walk.values() if w["ids_per_walk"] is not None]
    run_s = max(wall - eval_s, 1e-9)
    return {
        "cameras": n, "frames": f, "people_per_frame": statistics.mean(people),
        "cpu_ms_median": statistics.median(cpu_ms),
        "cpu_ms_p90": float(np.percentile(cpu_ms, 90)),
        "trackers_median": statistics.median(held), "trackers_max": max(held),
        "bytes_per_node_frame": result.wire.total_bytes / (n * f),
        "mota": metrics["median"]["mota"], "idf1": metrics["median"]["idf1"],
        "long_walkers": len(walkers),
        "id_kept": statistics.median(kept) if kept else None,
        "ids_per_walk": statistics.median(ids) if ids else None,
        "frames_per_s": f / run_s, "wall_s": wall, "cpu_s": cpu,
        "per_node": {"ground": metrics["per_node"], "walks": per_walk},
        "scenario": data.name, "seed": seed, "config": cfg.ablation,
        "ground_threshold_m": ground_threshold_m, "long_walk_cameras": long_walk_cameras,
    }


def _cell(v, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def table(rows: list[dict]) -> str:
    """The printed table, one line per size."""
    head = (f"{'cameras':>7} {'frames':>6} {'people':>6} {'cpu ms':>7} {'p90':>7} "
            f"{'trackers':>8} {'max':>5} {'B/node-frame':>12} {'MOTA':>6} {'IDF1':>6} "
            f"{'walkers':>7} {'id kept':>7} {'ids/walk':>8} {'frames/s':>8}")
    lines = [head]
    for r in rows:
        lines.append(
            f"{r['cameras']:>7} {r['frames']:>6} {r['people_per_frame']:>6.0f} "
            f"{r['cpu_ms_median']:>7.2f} {r['cpu_ms_p90']:>7.2f} {r['trackers_median']:>8.0f} "
            f"{r['trackers_max']:>5} {r['bytes_per_node_frame']:>12.0f} {_cell(r['mota'], '6.3f')} "
            f"{_cell(r['idf1'], '6.3f')} {r['long_walkers']:>7} {_cell(r['id_kept'], '7.3f')} "
            f"{_cell(r['ids_per_walk'], '8.2f')} {r['frames_per_s']:>8.2f}")
    return "\n".join(lines)


def write_results(rows: list[dict], out: Path, meta: dict) -> None:
    """``scale.json`` (every figure, per-node metrics too) and ``scale.csv`` (the table)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "scale.json").write_text(json.dumps({**meta, "rows": rows}, indent=2, sort_keys=True))
    with open(out / "scale.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow(["" if r[c] is None else r[c] for c in COLUMNS])


def main(args, cfg: TrackerConfig) -> int:
    """``sim_cluster bench --cameras ...``."""
    sizes = [int(t) for t in str(args.cameras).split(",") if t.strip()]
    frames = args.frames or 300
    print(f"{args.layout}-N, layout neighbour graph, sync, {frames} frames, seed {args.seed}, "
          f"config {cfg.ablation}; cpu ms: prepare+update per node-frame (median, p90); trackers "
          f"held per node (median, max); long walks cross >= {args.long_walk_cameras} cameras")
    rows = []
    for n in sizes:
        rows.append(scale_run(args.layout, n, cfg, frames=frames, seed=args.seed,
                              ground_threshold_m=args.ground_threshold,
                              long_walk_cameras=args.long_walk_cameras,
                              show_progress=not args.quiet))
        print(table(rows).splitlines()[-1] if len(rows) > 1 else table(rows), flush=True)
        print(f"  ({args.layout}-{n}: wall {rows[-1]['wall_s']:.1f} s, "
              f"CPU {rows[-1]['cpu_s']:.1f} s)", flush=True)
    meta = {"layout": args.layout, "frames": frames, "seed": args.seed, "config": cfg.ablation}
    write_results(rows, Path(args.out), meta)
    print(f"wrote {args.out}/scale.json and scale.csv")
    return 0
