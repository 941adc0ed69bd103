"""``sim_cluster reid-sweep``: tracking quality against re-id quality, from perfect re-id to none.

    sim_cluster reid-sweep --scenarios terrace-sim,campus-sim --seeds 0-1 --out docs/results/reid \\
        [--levels 1,0.99,0.98,0.95,0.9,0.8,0.7,0.6,0.5,0.4,0.3,none] [--topologies ring,chain]
        [--tracker-config FILE] [--frames N] [--jobs N]

Each level is a stated cross-camera rank-1 of the simulated descriptors (``[appearance] rank1``,
``AppearanceParams.from_quality``: measured with ``appearance.QUALITY_PEOPLE`` people); ``none``
runs the same detections without descriptors, which takes the geometry-only path
(``dkf+lda+dtm`` becomes ``dkf+dtm``: duplicates merged by co-motion, re-identification by
place). Every other setting is the scenario's and the tracker's default (or ``--tracker-config``'s:
the appearance thresholds ``merge_appearance``, ``appearance_gate``, ``epsilon`` decide how a
tracker copes with look-alikes), so the curve shows what a given re-id model buys with the tracker
as configured: the curve a user needs to pick one.

Beside the stated level each run records the re-id quality of its own scene's descriptors
(``evaluation.reid.scenario_reid``: two detections per person and camera), which differs from the
stated one where the scene has another number of people.

Outputs in ``--out``: ``reid_sweep.csv`` (one row per run), ``reid_sweep.md`` (per scenario, mean
± std over seeds), ``reid_sweep.png`` (ground and image MOTA and IDF1 against rank-1, ``none`` a
dashed line) and ``summary.json`` (the aggregates and the command's settings). Each scenario and
topology is one group (``terrace-sim/ring``); beside each level the tables give its ground IDF1
minus that of ``none`` in the same group (the question "is this re-id worth having at all":
negative means the descriptors cost identity). Runs execute in a
process pool (``--jobs``), results ordered by the plan, so the outputs do not depend on ``--jobs``.
"""
from __future__ import annotations

import csv
import functools
import json
import os
import statistics
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from edge_node.core.config import CONFIG_NAMES
from sim_cluster.evaluation.reid import scenario_reid
from sim_cluster.experiments.ablation import (GROUND_COLS, IDENTITY_COLS, IMAGE_COLS,
                                              AblationError, _csv_value, _hms, topology_names,
                                              _md_table, _num, execute, parse_list, parse_seeds,
                                              probe)
from sim_cluster.experiments.provenance import provenance
from sim_cluster.experiments.run import geometry_only, run_once, tracker_config
from sim_cluster.scenarios.files import read_scenario_toml, resolve_scenario_path, scenario_table
from sim_cluster.scenarios.loader import load_scenario
from sim_cluster.scenarios.synthetic.appearance import (QUALITY_PEOPLE, AppearanceParams,
                                                        effective_dimension)
from sim_cluster.scenarios.synthetic.schema import appearance_params_from_table

NONE = "none"
DEFAULT_LEVELS = "1,0.99,0.98,0.95,0.9,0.8,0.7,0.6,0.5,0.4,0.3,none"
DEFAULT_SCENARIOS = "terrace-sim,campus-sim"

KEY_COLS = ("scenario", "seed", "level", "rank1", "decay", "effective_dim", "scene_rank1",
            "scene_mean_ap", "scene_people", "config", "topology", "frames", "nodes")
METRIC_COLS = (tuple(c for c, _ in GROUND_COLS) + tuple(c for c, _ in IMAGE_COLS)
               + tuple(c for c, _ in IDENTITY_COLS) + ("bytes_per_frame",))
CSV_COLS = KEY_COLS + METRIC_COLS
#: columns aggregated over seeds (mean ± std)
AGG_COLS = ("scene_rank1", "scene_mean_ap") + METRIC_COLS
#: the markdown table: (column, header, format)
TABLE = (("scene_rank1", "scene rank-1", "{:.2f}"), ("scene_mean_ap", "scene mAP", "{:.2f}"),
         ("ground_mota", "ground MOTA", "{:.3f}"), ("ground_idf1", "ground IDF1", "{:.3f}"),
         ("image_mota", "image MOTA", "{:.3f}"), ("image_idf1", "image IDF1", "{:.3f}"),
         ("ground_ids_per_person", "ids/person", "{:.2f}"),
         ("ground_num_switches", "ID switches", "{:.1f}"))


@dataclass(frozen=True)
class Task:
    """One run: ``level`` a rank-1 in (0, 1] or ``None`` (no descriptors)."""

    index: int
    scenario: str
    seed: int
    level: float | None
    topology: str
    config: str
    frames: int | None
    tracker_config: str | None = None


def parse_levels(text: str) -> list[float | None]:
    """``"1,0.8,none"`` -> [1.0, 0.8, None]: rank-1 levels in (0, 1], ``none`` for no
    descriptors; order kept, duplicates dropped."""
    out: list[float | None] = []
    for part in (p.strip().lower() for p in str(text).split(",")):
        if not part:
            continue
        if part == NONE:
            v = None
        else:
            try:
                v = float(part)
            except ValueError:
                v = -1.0
            if not 0.0 < v <= 1.0:
                raise AblationError(f"bad --levels item {part!r}: a rank-1 in (0, 1] or 'none'")
        if v not in out:
            out.append(v)
    if not out:
        raise AblationError("no --levels given")
    return out


def level_name(level: float | None) -> str:
    return NONE if level is None else f"{level:g}"


def plan(scenarios: Sequence[str], seeds: Sequence[int], levels: Sequence[float | None],
         topologies: Sequence[str] = ("ring",), config: str = "dkf+lda+dtm",
         frames: int | None = None, tracker_file: str | None = None) -> list[Task]:
    """Every run, in the order scenario, seed, level, topology (a worker's scenario cache keeps
    hitting: one scenario load serves every topology)."""
    if isinstance(topologies, str):
        topologies = (topologies,)
    grid = [(sc, int(s), lv, tp) for sc in scenarios for s in seeds for lv in levels
            for tp in topologies]
    return [Task(i, sc, s, lv, tp, config, frames, tracker_file)
            for i, (sc, s, lv, tp) in enumerate(grid)]


def group_of(scenario: str, topology: str) -> str:
    """The aggregates' group of a run: ``"terrace-sim/ring"``."""
    return f"{scenario}/{topology}"


@functools.lru_cache(maxsize=2)
def _load(scenario: str, seed: int, frames: int | None, level: float | None):
    """The scenario at this re-id level (``None``: the scenario's own, descriptors then
    dropped by :func:`run_task`), once per worker process."""
    return load_scenario(scenario, seed=seed, frames=frames, rank1=level)


def appearance_at(scenario: str, level: float) -> AppearanceParams:
    """The appearance parameters ``scenario`` runs with at rank-1 ``level`` (its
    ``[appearance]`` table with ``rank1`` set, read as the loader reads it; the calibration is
    cached, so the loader's costs nothing more)."""
    path = resolve_scenario_path(scenario)
    raw = read_scenario_toml(path)
    app = {k: v for k, v in raw.get("appearance", {}).items()
           if k not in ("rank1", "mean_ap", "decay")}
    top = scenario_table({"appearance": {**app, "rank1": level}}, path.name)
    return appearance_params_from_table(top.table("appearance"))


def run_task(task: Task) -> dict:
    """One run: ``{"task", "summary", "reid", "config", "decay", "effective_dim"}`` (no tracks:
    small to pickle)."""
    data = _load(task.scenario, task.seed, task.frames, task.level)
    reid = decay = eff = None
    if task.level is None:
        data = data.without_descriptors()
    else:
        reid = scenario_reid(data).to_dict()
        params = appearance_at(task.scenario, task.level)
        decay, eff = params.decay, effective_dimension(params.dim, params.decay)
    cfg, _ = geometry_only(data, tracker_config(task.config, task.tracker_config))
    _, summary = run_once(data, task.topology, cfg, show_progress=False)
    return {"task": asdict(task), "summary": summary, "reid": reid, "config": cfg.ablation,
            "decay": decay, "effective_dim": eff}


def _label(t: Task) -> str:
    return f"{t.scenario} {t.topology} s{t.seed} rank-1 {level_name(t.level)}"


def row_of(result: Mapping) -> dict:
    """One reid_sweep.csv row."""
    task, s, reid = result["task"], result["summary"], result["reid"]
    level = task["level"]
    med = {v: s.get("metrics", {}).get(v, {}).get("median", {}) for v in ("ground", "image")}
    row = {"scenario": task["scenario"], "seed": task["seed"], "level": level_name(level),
           "rank1": level, "decay": result.get("decay"),
           "effective_dim": result.get("effective_dim"),
           "scene_rank1": None if reid is None else reid["rank1"],
           "scene_mean_ap": None if reid is None else reid["mean_ap"],
           "scene_people": None if reid is None else reid["people"],
           "config": result["config"], "topology": task["topology"], "frames": s["frames"],
           "nodes": s["nodes"]}
    for col, m in GROUND_COLS + IDENTITY_COLS:
        row[col] = med["ground"].get(m)
    for col, m in IMAGE_COLS:
        row[col] = med["image"].get(m)
    row["bytes_per_frame"] = s["bandwidth"]["bytes_per_frame"]
    return row


def aggregate(rows: Sequence[Mapping]) -> dict:
    """``{group: {level name: {column: {"mean", "std", "n"}}}}`` over seeds (sample std,
    0 with one seed; undefined values left out), groups (:func:`group_of`) and levels in the
    order of the rows."""
    acc: dict[str, dict[str, dict[str, list[float]]]] = {}
    for r in rows:
        cell = acc.setdefault(group_of(str(r["scenario"]), str(r["topology"])), {}) \
            .setdefault(str(r["level"]), {})
        for col in AGG_COLS:
            v = _num(r.get(col))
            if v is not None:
                cell.setdefault(col, []).append(v)
    return {sc: {lv: {col: {"mean": statistics.fmean(v),
                            "std": statistics.stdev(v) if len(v) > 1 else 0.0, "n": len(v)}
                      for col, v in cols.items()}
                 for lv, cols in levels.items()}
            for sc, levels in acc.items()}


def write_csv(path: Path, rows: Sequence[Mapping]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLS)
        for r in rows:
            w.writerow([_csv_value(r.get(c)) for c in CSV_COLS])


def vs_none(levels: Mapping[str, Mapping]) -> dict[str, float | None]:
    """Per level of one group: its mean ground IDF1 minus that of ``none`` (None where either
    is missing; ``none`` itself left out)."""
    base = levels.get(NONE, {}).get("ground_idf1")
    return {lv: (None if base is None or "ground_idf1" not in cells
                 else cells["ground_idf1"]["mean"] - base["mean"])
            for lv, cells in levels.items() if lv != NONE}


def worse_than_none(agg: Mapping, tolerance: float = 0.0) -> dict[str, list[str]]:
    """Per group, the levels whose ground IDF1 is below that of ``none`` by more than
    ``tolerance`` (the re-id sweep's "never worse" goal)."""
    return {g: [lv for lv, d in vs_none(levels).items() if d is not None and d < -tolerance]
            for g, levels in agg.items()}


def _delta(d: float | None) -> str:
    return "–" if d is None else f"{d:+.3f}"


def _cell(cell: Mapping | None, fmt: str, pm: bool) -> str:
    if not cell:
        return "–"
    text = fmt.format(cell["mean"])
    return f"{text} ± {fmt.format(cell['std'])}" if pm and cell["n"] > 1 else text


def markdown(agg: Mapping, meta: Mapping) -> str:
    """``reid_sweep.md``: one table per scenario, a row per level."""
    lines = ["# Tracking quality against re-id quality", ""]
    lines.append(
        f"Stated level: cross-camera rank-1 of the simulated descriptors with "
        f"{meta['quality_people']} people (`[appearance] rank1`); `none`: no descriptors, the "
        f"geometry-only path (dkf+dtm). Scene rank-1 / mAP: the same measurement on each run's "
        f"own detections (two per person and camera). Topologies "
        f"{', '.join(meta['topologies'])}, configuration {meta['config']}"
        + (f" with the parameters of `{Path(meta['tracker_config']).name}`"
           if meta.get("tracker_config") else " with the default parameters")
        + f", seeds {', '.join(map(str, meta['seeds']))}, frames: "
        f"{meta['frames'] or 'each scenario’s default'}. Cells: mean over seeds of the median "
        "over nodes (± the sample std when there are several seeds); vs none: ground IDF1 minus "
        "that of no descriptors in the same scenario and topology.")
    lines.append("")
    worse = {g: lv for g, lv in worse_than_none(agg).items() if lv}
    lines += ["Levels below no descriptors in ground IDF1: "
              + ("; ".join(f"{g} at {', '.join(lv)}" for g, lv in worse.items()) if worse
                 else "none") + ".", ""]
    if meta.get("failed"):
        lines += [f"- **{len(meta['failed'])} run(s) failed** and are left out: "
                  + "; ".join(meta["failed"][:10]), ""]
    pm = len(meta["seeds"]) > 1
    for g, levels in agg.items():
        info = meta.get("scenarios", {}).get(g.split("/")[0], {})
        delta = vs_none(levels)
        lines += [f"## {g}", "",
                  f"{info.get('cameras', '?')} cameras, {info.get('frames', '?')} frames.", ""]
        lines += _md_table(["rank-1"] + [h for _, h, _ in TABLE] + ["vs none"],
                           [[lv] + [_cell(cells.get(col), fmt, pm) for col, _, fmt in TABLE]
                            + [_delta(delta.get(lv))] for lv, cells in levels.items()])
        lines.append("")
    return "\n".join(lines)


def table_text(agg: Mapping) -> str:
    """The tables as plain text (what the command prints)."""
    header = ["group", "rank-1"] + [h for _, h, _ in TABLE] + ["vs none"]
    rows = [header]
    for g, levels in agg.items():
        delta = vs_none(levels)
        rows += [[g, lv] + [_cell(cells.get(col), fmt, False) for col, _, fmt in TABLE]
                 + [_delta(delta.get(lv))] for lv, cells in levels.items()]
    width = [max(len(r[i]) for r in rows) for i in range(len(header))]
    return "\n".join("  ".join(v.ljust(w) if i < 2 else v.rjust(w)
                               for i, (v, w) in enumerate(zip(r, width))) for r in rows)


_COLORS = ("#08306b", "#e6550d", "#31a354", "#756bb1", "#636363", "#d6616b", "#17becf",
           "#8c6d31")


def plot(path: Path, agg: Mapping, meta: Mapping) -> None:
    """``reid_sweep.png``: ground / image (rows) MOTA and IDF1 (columns) against the stated
    rank-1, one line per group (error bars: std over seeds); ``none`` a dashed line."""
    import matplotlib  # plotting only here: keeps matplotlib out of every other command

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after use("Agg"): no display needed

    panels = ((("ground_mota", "ground MOTA"), ("ground_idf1", "ground IDF1")),
              (("image_mota", "image MOTA"), ("image_idf1", "image IDF1")))
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), squeeze=False)
    for r, row in enumerate(panels):
        for c, (col, title) in enumerate(row):
            ax = axes[r][c]
            for i, (sc, levels) in enumerate(agg.items()):
                color = _COLORS[i % len(_COLORS)]
                pts = sorted((float(lv), cells[col]["mean"], cells[col]["std"])
                             for lv, cells in levels.items() if lv != NONE and col in cells)
                if pts:
                    xs, ys, es = zip(*pts)
                    ax.errorbar(xs, ys, yerr=es if len(meta["seeds"]) > 1 else None,
                                marker="o", ms=4, capsize=2, color=color, label=sc)
                none = levels.get(NONE, {}).get(col)
                if none:
                    ax.axhline(none["mean"], color=color, linestyle="--", linewidth=1,
                               label=f"{sc}: no descriptors (dkf+dtm)")
            ax.set_xlabel(f"re-id cross-camera rank-1 ({meta['quality_people']} people)")
            ax.set_title(title, fontsize=10)
            ax.grid(alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    ncol = 2 if len(agg) < 3 else 3
    if handles:
        fig.legend(handles, labels, loc="upper center", ncol=ncol, frameon=False, fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.96 - 0.03 * -(-len(labels) // ncol)))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(out: Path, rows: Sequence[Mapping], agg: Mapping, meta: Mapping) -> list[Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "reid_sweep.csv", out / "reid_sweep.md", out / "reid_sweep.png",
             out / "summary.json"]
    write_csv(paths[0], rows)
    paths[1].write_text(markdown(agg, meta))
    plot(paths[2], agg, meta)
    paths[3].write_text(json.dumps({"meta": meta, "cells": agg}, indent=2))
    return paths


def main(args) -> int:
    """``sim_cluster reid-sweep``; raises ``AblationError`` on a bad argument."""
    t0 = time.monotonic()
    scenarios = parse_list(args.scenarios, None, "scenario")
    seeds = parse_seeds(args.seeds)
    levels = parse_levels(args.levels)
    config = parse_list(args.config, CONFIG_NAMES, "config")[0]
    topologies = parse_list(args.topologies, topology_names(), "topology")
    if args.frames is not None and args.frames < 1:
        raise AblationError(f"--frames must be >= 1, got {args.frames}")
    jobs = (os.cpu_count() or 1) if args.jobs is None else args.jobs
    if jobs < 1:
        raise AblationError(f"--jobs must be >= 1, got {args.jobs}")
    info, skipped = probe(scenarios, seeds[0], None)
    runnable = [s for s in scenarios if s in info]
    if not runnable:
        raise AblationError("nothing to run: every scenario was skipped")
    tracker_file = getattr(args, "tracker_config", None)
    if tracker_file:
        tracker_config(config, tracker_file)  # a bad file is one error now, not one per run
        tracker_file = str(Path(tracker_file).expanduser().resolve())
    tasks = plan(runnable, seeds, levels, topologies, config, args.frames, tracker_file)
    quiet = getattr(args, "quiet", False)
    if not quiet:
        print(f"reid-sweep: {len(tasks)} runs ({len(runnable)} scenario(s) x {len(seeds)} "
              f"seed(s) x {len(levels)} levels x {len(topologies)} topologies) on {min(jobs, len(tasks))} process(es)",
              file=sys.stderr, flush=True)
    results = execute(tasks, jobs, progress=not quiet, run=run_task, label=_label,
                      name="reid-sweep")
    ok = [r for r in results if r is not None]
    failed = [_label(t) for t, r in zip(tasks, results) if r is None]
    for r in ok:
        info[r["task"]["scenario"]].setdefault("frames", r["summary"]["frames"])
    rows = [row_of(r) for r in ok]
    meta = {"scenarios": info, "skipped": skipped, "failed": failed, "seeds": seeds,
            "levels": [level_name(lv) for lv in levels], "topologies": topologies,
            "config": config, "tracker_config": tracker_file, "frames": args.frames,
            "quality_people": QUALITY_PEOPLE,
            "std": "sample standard deviation over seeds (ddof=1; 0 with one seed)",
            "provenance": provenance()}  # the docs' tables name commit and machine
    agg = aggregate(rows)
    paths = write_outputs(Path(args.out), rows, agg, meta)
    if rows:
        print(table_text(agg))
    print(f"reid-sweep: {len(rows)}/{len(tasks)} runs in {_hms(time.monotonic() - t0)}; wrote "
          + ", ".join(str(p) for p in paths))
    if failed:
        print(f"reid-sweep: {len(failed)} run(s) failed (see above); they are left out",
              file=sys.stderr)
        return 1
    return 0

