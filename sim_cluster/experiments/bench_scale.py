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
* **ground MOTA / IDF1**, global and regional, median over nodes: global is each node's whole
  track set against everybody in view within 1 m (the project's ground view;
  :class:`~sim_cluster.evaluation.online.OnlineGround`); regional scores node ``i`` only inside
  the ground its own and its neighbours' cameras see (people and tracks outside are ignored;
  :mod:`sim_cluster.evaluation.region`), which is what a node under regional scope, or any
  node of a large network, can be asked for;
* **id kept on long walks** and **ids per long walk**
  (:mod:`sim_cluster.evaluation.walks`): for people who cross at least ``--long-walk-cameras``
  (4) cameras' views, the walk-weighted fraction of their frames matched to their dominant id,
  and their distinct ids; median over nodes; global (the whole walk, global matches) and
  regional (the walk's frames inside the node's region, regional matches). ``-`` when nobody
  walks that far in the run;
* **frames/s** of the whole simulated network (wall time of the run, world generation
  included, evaluation excluded), and the run's wall and CPU seconds.

With ``--scope 0,1,2`` each size runs once per hop limit (``TrackerConfig.scope_hops``; 0 is
the paper's every-node-holds-every-tracker), one row per (cameras, scope).

Results go to ``<out>/scale.json`` (with the per-node metrics), ``<out>/scale.csv`` and the plot
``<out>/scale.png`` (per-node CPU, trackers held, bytes and regional scores against the number
of cameras, a line per scope; the legend gives each scope's CPU at the largest size over the
smallest, issue 15's "64 over 4 cameras" ratio). The
tracker configuration is a :class:`TrackerConfig` (``--config`` and ``--tracker-config``, as
``sim_cluster run``); ``--scope`` overrides its ``scope_hops``.
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
from sim_cluster.evaluation.region import RegionalGround, Regions
from sim_cluster.evaluation.walks import WalkLog, walk_ids
from sim_cluster.network.inprocess import run_network
from sim_cluster.progress import progress_bar
from sim_cluster.scenarios.loader import open_scenario

COLUMNS = ("cameras", "scope", "frames", "people_per_frame", "cpu_ms_median", "cpu_ms_p90",
           "trackers_median", "trackers_max", "bytes_per_node_frame", "mota", "idf1",
           "mota_region", "idf1_region", "long_walkers", "id_kept", "ids_per_walk",
           "id_kept_region", "ids_per_walk_region", "frames_per_s", "wall_s", "cpu_s")


def scale_run(layout: str, cameras: int, cfg: TrackerConfig, *, frames: int | None = None,
              seed: int = 0, ground_threshold_m: float = 1.0, long_walk_cameras: int = 4,
              show_progress: bool = False) -> dict:
    """One size and scope of the sweep (``cfg.scope_hops``): the row of the table
    (``COLUMNS``) plus ``per_node`` metrics."""
    data = open_scenario(f"{layout}-{cameras}", seed=seed, frames=frames)
    cpu_ms: list[float] = []
    held: list[int] = []
    people: list[int] = []
    ground = OnlineGround(data.units_per_metre, ground_threshold_m)
    regional = RegionalGround(Regions(data.cameras, data.neighbours), data.units_per_metre,
                              ground_threshold_m)
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
            regional.add(node, k, ts, truth)
        eval_s += time.perf_counter() - t0

    update, close = progress_bar(f"{data.name}", data.frames, show_progress)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    try:
        result = run_network(data, data.neighbours, cfg, topology_name="layout", probe=probe,
                             on_frame=on_frame, progress=update)
    finally:
        close()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    run_s = max(wall - eval_s, 1e-9)  # the run without the evaluation done beside it
    t0 = time.perf_counter()
    metrics, metrics_region = ground.summary(), regional.summary()
    walkers = walks.long_walkers(long_walk_cameras)
    per_walk = {str(n): walk_ids(ground.matches(n), walks.frames, walkers) for n in ground.nodes}
    per_walk_region = {}
    for n in regional.nodes:
        inside = regional.walk_frames.get(n, {})
        per_walk_region[str(n)] = walk_ids(regional.matches(n), inside,
                                           {p for p in walkers if inside.get(p)})
    eval_s += time.perf_counter() - t0
    n, f = data.num_cameras, result.frames
    return {
        "cameras": n, "scope": cfg.scope_hops, "frames": f,
        "people_per_frame": statistics.mean(people),
        "cpu_ms_median": statistics.median(cpu_ms),
        "cpu_ms_p90": float(np.percentile(cpu_ms, 90)),
        "trackers_median": statistics.median(held), "trackers_max": max(held),
        "bytes_per_node_frame": result.wire.total_bytes / (n * f),
        "mota": metrics["median"]["mota"], "idf1": metrics["median"]["idf1"],
        "mota_region": metrics_region["median"]["mota"],
        "idf1_region": metrics_region["median"]["idf1"],
        "long_walkers": len(walkers),
        "id_kept": _median_of(per_walk, "id_kept"),
        "ids_per_walk": _median_of(per_walk, "ids_per_walk"),
        "id_kept_region": _median_of(per_walk_region, "id_kept"),
        "ids_per_walk_region": _median_of(per_walk_region, "ids_per_walk"),
        "frames_per_s": f / run_s, "wall_s": wall, "cpu_s": cpu,
        "per_node": {"ground": metrics["per_node"], "walks": per_walk,
                     "ground_region": metrics_region["per_node"],
                     "walks_region": per_walk_region},
        "scenario": data.name, "seed": seed, "config": cfg.ablation,
        "ground_threshold_m": ground_threshold_m, "long_walk_cameras": long_walk_cameras,
    }


def _median_of(per_node: dict, key: str) -> float | None:
    values = [w[key] for w in per_node.values() if w[key] is not None]
    return statistics.median(values) if values else None


def _cell(v, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def table(rows: list[dict]) -> str:
    """The printed table, one line per (size, scope); ``global/regional`` pairs."""
    head = (f"{'cameras':>7} {'scope':>5} {'frames':>6} {'people':>6} {'cpu ms':>7} {'p90':>7} "
            f"{'trackers':>8} {'max':>5} {'B/node-frame':>12} {'MOTA glob/reg':>13} "
            f"{'IDF1 glob/reg':>13} {'walkers':>7} {'id kept g/r':>11} {'ids/walk g/r':>11} "
            f"{'frames/s':>8}")
    lines = [head]
    for r in rows:
        lines.append(
            f"{r['cameras']:>7} {r['scope']:>5} {r['frames']:>6} {r['people_per_frame']:>6.0f} "
            f"{r['cpu_ms_median']:>7.2f} {r['cpu_ms_p90']:>7.2f} {r['trackers_median']:>8.0f} "
            f"{r['trackers_max']:>5} {r['bytes_per_node_frame']:>12.0f} "
            f"{_cell(r['mota'], '6.3f'):>6}/{_cell(r['mota_region'], '.3f'):<6} "
            f"{_cell(r['idf1'], '6.3f'):>6}/{_cell(r['idf1_region'], '.3f'):<6} "
            f"{r['long_walkers']:>7} {_cell(r['id_kept'], '5.3f'):>5}/{_cell(r['id_kept_region'], '.3f'):<5} "
            f"{_cell(r['ids_per_walk'], '5.2f'):>5}/{_cell(r['ids_per_walk_region'], '.2f'):<5} "
            f"{r['frames_per_s']:>8.2f}")
    return "\n".join(lines)


def write_results(rows: list[dict], out: Path, meta: dict) -> None:
    """``scale.json`` (every figure, per-node metrics too), ``scale.csv`` (the table) and
    ``scale.png`` (:func:`plot`)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "scale.json").write_text(json.dumps({**meta, "rows": rows}, indent=2, sort_keys=True))
    with open(out / "scale.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow(["" if r[c] is None else r[c] for c in COLUMNS])
    plot(rows, out / "scale.png", meta)


def size_ratios(rows: list[dict]) -> dict[int, float]:
    """Per scope: median CPU ms per node-frame at the largest size over the smallest (scopes
    run at one size only are left out)."""
    out = {}
    for h in sorted({r["scope"] for r in rows}):
        mine = sorted((r for r in rows if r["scope"] == h), key=lambda r: r["cameras"])
        if len(mine) > 1 and mine[0]["cpu_ms_median"] > 0:
            out[h] = mine[-1]["cpu_ms_median"] / mine[0]["cpu_ms_median"]
    return out


def plot(rows: list[dict], path: Path, meta: dict) -> None:
    """``scale.png``: against the number of cameras (log scale), a line per scope: CPU ms per
    node-frame (median; the band up to p90), trackers held per node (median; dotted: max),
    bytes per node-frame, regional MOTA (solid) and IDF1 (dashed)."""
    import matplotlib  # plotting only here: keeps matplotlib out of every other command

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after use("Agg"): no display needed

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    (cpu, held), (sent, score) = axes
    ratios = size_ratios(rows)
    colors = plt.get_cmap("tab10")
    sizes = sorted({r["cameras"] for r in rows})
    for i, h in enumerate(sorted({r["scope"] for r in rows})):
        mine = sorted((r for r in rows if r["scope"] == h), key=lambda r: r["cameras"])
        n = [r["cameras"] for r in mine]
        c = colors(i)
        label = "scope 0 (every node holds all)" if h == 0 else f"scope {h}"
        if h in ratios:
            label += f": CPU {n[-1]}/{n[0]} cameras {ratios[h]:.2f}x"
        cpu.plot(n, [r["cpu_ms_median"] for r in mine], "o-", color=c, label=label)
        cpu.fill_between(n, [r["cpu_ms_median"] for r in mine], [r["cpu_ms_p90"] for r in mine],
                         color=c, alpha=0.15, lw=0)
        held.plot(n, [r["trackers_median"] for r in mine], "o-", color=c)
        held.plot(n, [r["trackers_max"] for r in mine], ":", color=c)
        sent.plot(n, [r["bytes_per_node_frame"] for r in mine], "o-", color=c)
        for key, style in (("mota_region", "o-"), ("idf1_region", "s--")):
            pts = [(x, r[key]) for x, r in zip(n, mine) if r[key] is not None]
            if pts:
                score.plot(*zip(*pts), style, color=c, ms=4)
    for ax, title in ((cpu, "CPU ms of prepare + update per node-frame (median; band to p90)"),
                      (held, "trackers held per node (median; dotted: max)"),
                      (sent, "bytes sent per node-frame"),
                      (score, "regional ground MOTA (solid) / IDF1 (dashed), median node")):
        ax.set_xscale("log", base=2)
        ax.set_xticks(sizes, [str(s) for s in sizes])
        ax.minorticks_off()
        ax.set_xlabel("cameras")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    cpu.set_ylim(bottom=0)
    held.set_ylim(bottom=0)
    sent.set_yscale("log")
    score.set_ylim(min(0.0, score.get_ylim()[0]), 1.0)
    cpu.legend(fontsize=8, loc="upper left")
    density = statistics.median(r["people_per_frame"] / r["cameras"] for r in rows)
    fig.suptitle(f"{meta.get('layout', '?')}-N: {meta.get('frames', '?')} frames, seed "
                 f"{meta.get('seed', '?')}, {meta.get('config', '?')}, {density:.1f} people in view "
                 "per camera (sim_cluster bench --cameras)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(args, cfg: TrackerConfig) -> int:
    """``sim_cluster bench --cameras ... [--scope ...]``."""
    sizes = [int(t) for t in str(args.cameras).split(",") if t.strip()]
    scopes = [int(t) for t in str(getattr(args, "scope", None) or cfg.scope_hops).split(",")
              if t.strip()]
    frames = args.frames or 300
    print(f"{args.layout}-N, layout neighbour graph, sync, {frames} frames, seed {args.seed}, "
          f"config {cfg.ablation}; cpu ms: prepare+update per node-frame (median, p90); trackers "
          f"held per node (median, max); MOTA, IDF1, id kept, ids per walk: global/regional "
          f"(region: a node's and its neighbours' views); long walks cross >= "
          f"{args.long_walk_cameras} cameras", flush=True)
    rows = []
    for n in sizes:
        for h in scopes:
            rows.append(scale_run(args.layout, n, cfg.with_(scope_hops=h),
                                  frames=frames, seed=args.seed,
                                  ground_threshold_m=args.ground_threshold,
                                  long_walk_cameras=args.long_walk_cameras,
                                  show_progress=not args.quiet))
            print(table(rows).splitlines()[-1] if len(rows) > 1 else table(rows), flush=True)
            print(f"  ({args.layout}-{n}, scope {h}: wall {rows[-1]['wall_s']:.1f} s, "
                  f"CPU {rows[-1]['cpu_s']:.1f} s)", flush=True)
    meta = {"layout": args.layout, "frames": frames, "seed": args.seed, "config": cfg.ablation,
            "scopes": scopes}
    write_results(rows, Path(args.out), meta)
    ratios = size_ratios(rows)
    if ratios:
        print("per-node CPU at the largest size over the smallest: " + ", ".join(
            f"scope {h} {r:.2f}x" for h, r in ratios.items()))
    print(f"wrote {args.out}/scale.json, scale.csv and scale.png")
    return 0
