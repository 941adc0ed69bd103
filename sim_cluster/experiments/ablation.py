"""``sim_cluster ablation``: the paper's ablation study (Sec. IV-B, Fig. 3) over scenarios, seeds,
configurations and topologies, plus the centralized baseline and the bandwidth of Sec. III-D / IV.

    sim_cluster ablation --scenarios terrace-sim,lab-sim,campus-sim,terrace-gt,campus-gt \\
        --seeds 0-4 --out runs/ablation [--frames N] [--orderings 3] [--jobs N]

The grid is every (scenario, seed, config, topology, ordering): configs ``dkf``, ``dkf+lda``,
``dkf+lda+dtm``; topologies complete, ring, chain, disconnected and ``centralized`` (one tracker fed
every camera's detections, run with each config too). Ring and chain are run over ``--orderings``
distinct camera orderings (``topology.orderings``; the paper's Fig. 4) and averaged within a seed
before the statistics over seeds.

Runs execute in a ``ProcessPoolExecutor`` (``--jobs``, default: every core). Each task loads its
scenario itself (cached per worker process) and returns its summary without tracks; results are
ordered by the plan, never by completion, so the outputs do not depend on ``--jobs``. A scenario
whose data is missing (``epfl.DataNotFoundError``) is skipped with one line saying why.

It prints, per scenario, topology and configuration, ground MOTA / IDF1 and the identity counts
(people, track ids, ids per person, fragmentations, mostly tracked / partially / mostly lost).
Outputs in ``--out``: ``results.csv`` (one row per run), ``results.md`` (tables), ``ablation.png``
(Fig. 3-style bars), ``summary.json`` (the aggregated numbers) and ``runs.jsonl`` (every run's
summary: per-node metrics, manager counters, per-link bytes).

Statistics: a run's metric is the median over nodes (``evaluation``); a seed's value is the mean
over orderings; a cell is ``mean ± std`` over seeds with the sample standard deviation (``ddof=1``,
0 when there is one seed). Undefined values (``None``, e.g. MOTA without objects) are left out.
"""
from __future__ import annotations

import csv
import functools
import json
import math
import os
import statistics
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from edge_node.core.config import ABLATIONS, CONFIG_NAMES, TrackerConfig
from protocol.errors import DmttError
from sim_cluster.experiments.provenance import provenance
from sim_cluster.experiments.run import run_once
from sim_cluster.network import topology as topo
from sim_cluster.network.inprocess import CENTRALIZED
from sim_cluster.scenarios.files import ScenarioError, read_scenario_toml, resolve_scenario_path
from sim_cluster.scenarios.loader import load_scenario
DEFAULT_SCENARIOS = ("terrace-sim", "lab-sim", "campus-sim", "terrace-gt", "campus-gt")
DEFAULT_TOPOLOGIES = ("complete", "ring", "chain", "disconnected", CENTRALIZED)


def topology_names() -> tuple[str, ...]:
    """Every ``--topologies`` name: the registered graphs (``topology.TOPOLOGIES``) and the
    centralized baseline."""
    return (*topo.TOPOLOGIES.names(), CENTRALIZED)


def ordered(topology: str) -> bool:
    """Whether ``topology`` is run over several camera orderings (ring, chain: paper Fig. 4)."""
    return topology in topo.TOPOLOGIES and topo.TOPOLOGIES.get(topology).ordered
FULL = "dkf+lda+dtm"

# (csv column, evaluation metric) per view
GROUND_COLS = (("ground_mota", "mota"), ("ground_motp_m", "motp_m"), ("ground_idf1", "idf1"),
               ("ground_idp", "idp"), ("ground_idr", "idr"),
               ("ground_num_switches", "num_switches"), ("ground_fp", "num_false_positives"),
               ("ground_fn", "num_misses"))
IMAGE_COLS = (("image_mota", "mota"), ("image_motp", "motp"), ("image_idf1", "idf1"),
              ("image_idp", "idp"), ("image_idr", "idr"),
              ("image_num_switches", "num_switches"), ("image_fp", "num_false_positives"),
              ("image_fn", "num_misses"))
BANDWIDTH_COLS = ("bytes_per_frame", "bytes_per_tracker_frame", "appearance_bytes_per_new_tracker")
# identity counts on the ground (evaluation.metrics.IDENTITY_METRICS), after the older columns
IDENTITY_COLS = (("ground_people", "num_unique_objects"), ("ground_track_ids", "num_track_ids"),
                 ("ground_ids_per_person", "ids_per_person"),
                 ("ground_fragmentations", "num_fragmentations"), ("ground_mt", "mostly_tracked"),
                 ("ground_pt", "partially_tracked"), ("ground_ml", "mostly_lost"))
KEY_COLS = ("scenario", "seed", "config", "topology", "ordering", "order", "frames", "nodes")
METRIC_COLS = (tuple(c for c, _ in GROUND_COLS) + tuple(c for c, _ in IMAGE_COLS) + BANDWIDTH_COLS
               + tuple(c for c, _ in IDENTITY_COLS))
CSV_COLS = KEY_COLS + METRIC_COLS

# The paper's analytic bandwidth (Sec. III-D and IV, Table II; Terrace, 4 cameras).
PAPER = {
    "kB_per_tracker_frame": 0.78,
    "kB_per_appearance_exchange": 16.38,  # two 512-element descriptors, once per new tracker
    "distributed_kB_per_frame_terrace": 28.23,  # upper bound: 9 trackers x 4 cameras + appearance
    "centralized_images_kB_per_frame_terrace": 1215,  # 4 x 360x288 RGB images (1,244,160 B)
}


class AblationError(DmttError, ValueError):
    """A bad argument of the ablation command (the CLI turns it into exit status 2)."""


# -- planning -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Task:
    """One run of the grid. ``ordering`` indexes ``order`` among the topology's orderings (0 for
    topologies without orderings, ``order`` then ``None``)."""

    index: int
    scenario: str
    seed: int
    config: str
    topology: str
    ordering: int
    order: tuple[int, ...] | None
    frames: int | None
    data_root: str | None = None


def parse_seeds(text: str) -> list[int]:
    """``"0-4"`` -> [0..4]; ``"0,2,5"``; mixtures like ``"0-2,7"``. Sorted, without duplicates."""
    seeds: set[int] = set()
    bad = AblationError(f"bad --seeds {text!r}: expected a range like 0-4 or a list like 0,2,5 "
                        "(non-negative integers)")
    for part in str(text).split(","):
        part = part.strip()
        if not part:
            raise bad
        lo_hi = part.split("-")
        try:
            nums = [int(p) for p in lo_hi]
        except ValueError:
            raise bad from None
        if len(nums) == 1:
            seeds.add(nums[0])
        elif len(nums) == 2 and nums[0] <= nums[1]:
            seeds.update(range(nums[0], nums[1] + 1))
        else:
            raise bad
    if not seeds or min(seeds) < 0:
        raise bad
    return sorted(seeds)


def parse_list(text: str | Sequence[str], allowed: Sequence[str] | None, what: str) -> list[str]:
    """A comma-separated list (order kept, duplicates dropped), each item checked against
    ``allowed`` when given."""
    items = text.split(",") if isinstance(text, str) else list(text)
    out: list[str] = []
    for item in (i.strip() for i in items):
        if not item:
            continue
        if allowed is not None and item not in allowed:
            raise AblationError(f"unknown {what} {item!r}: choose from {', '.join(allowed)}")
        if item not in out:
            out.append(item)
    if not out:
        raise AblationError(f"no {what} given")
    return out


def plan(scenarios: Sequence[str], seeds: Sequence[int], configs: Sequence[str] = ABLATIONS,
         topologies: Sequence[str] = DEFAULT_TOPOLOGIES, *, cameras: Mapping[str, int],
         orderings: int = 3, frames: int | None = None,
         data_root: str | Mapping[str, str | None] | None = None) -> list[Task]:
    """Every run of the grid, in a fixed order: scenario, seed, config, topology, ordering.

    ``cameras[scenario]`` is the scenario's number of cameras (ring/chain orderings depend on it).
    ``data_root`` is one folder for every scenario or a mapping scenario -> folder (or None).
    Runs of one (scenario, seed) are adjacent so a worker's scenario cache keeps hitting.
    """
    if orderings < 1:
        raise AblationError(f"--orderings must be >= 1, got {orderings}")
    tasks: list[Task] = []
    for scenario in scenarios:
        n = cameras[scenario]
        orders = {t: topo.orderings(t, n, orderings) for t in topologies if ordered(t)}
        root = data_root.get(scenario) if isinstance(data_root, Mapping) else data_root
        for seed in seeds:
            for config in configs:
                for topology in topologies:
                    variants: list[tuple[int, tuple[int, ...] | None]] = (
                        [(i, tuple(o)) for i, o in enumerate(orders[topology])]
                        if ordered(topology) else [(0, None)])
                    for i, order in variants:
                        tasks.append(Task(len(tasks), scenario, int(seed), config, topology, i,
                                          order, frames, root))
    return tasks


# -- running ------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=2)
def _load(scenario: str, seed: int, frames: int | None, data_root: str | None):
    """The scenario, once per worker process (runs of one scenario and seed are adjacent)."""
    return load_scenario(scenario, seed=seed, frames=frames, data_root=data_root)


def run_task(task: Task) -> dict:
    """Run one task; returns ``{"task": {...}, "summary": {...}}`` (no tracks: small to pickle)."""
    data = _load(task.scenario, task.seed, task.frames, task.data_root)
    cfg = TrackerConfig.for_ablation(task.config)
    _, summary = run_once(data, task.topology, cfg, order=task.order, show_progress=False)
    return {"task": _task_dict(task), "summary": summary}


def _task_dict(task: Task) -> dict:
    d = asdict(task)
    d["order"] = None if task.order is None else list(task.order)
    return d


class _Progress:
    """Runs done: a tqdm bar on a terminal, a line about every 10% otherwise (logs, CI)."""

    def __init__(self, total: int, enabled: bool = True, stream=None, name: str = "ablation"):
        self.total, self.done, self.enabled = total, 0, enabled and total > 0
        self.name = name
        self.stream = stream or sys.stderr
        self.t0 = time.monotonic()
        self.bar = None
        self.next_pct = 10
        if self.enabled and self.stream.isatty():
            self.bar = tqdm(total=total, desc=name, unit="run", file=self.stream)

    def step(self, label: str = "") -> None:
        self.done += 1
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.set_postfix_str(label, refresh=False)
            self.bar.update(1)
            return
        pct = 100 * self.done // self.total
        if pct >= self.next_pct or self.done == self.total:
            el = time.monotonic() - self.t0
            left = el / self.done * (self.total - self.done)
            print(f"{self.name}: {self.done}/{self.total} runs ({pct}%), {_hms(el)} elapsed, "
                  f"~{_hms(left)} left", file=self.stream, flush=True)
            self.next_pct = pct - pct % 10 + 10

    def write(self, message: str) -> None:
        """A line that does not break the bar."""
        if self.bar is not None:
            self.bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _hms(s: float) -> str:
    s = int(round(s))
    if s >= 3600:
        return f"{s // 3600}h{s % 3600 // 60:02d}m{s % 60:02d}s"
    return f"{s // 60}m{s % 60:02d}s"


def _label(t: Task) -> str:
    o = f"#{t.ordering}" if ordered(t.topology) else ""
    return f"{t.scenario} s{t.seed} {t.config} {t.topology}{o}"


def execute(tasks: Sequence, jobs: int = 1, progress: bool = True, *, run=None, label=None,
            name: str = "ablation") -> list[dict | None]:
    """Run ``tasks`` (in parallel when ``jobs > 1``); results in task order, ``None`` for a run
    that raised (reported with one line on stderr). ``run(task)`` (a module-level function: it
    crosses to worker processes) and ``label(task)`` default to the ablation's; ``name`` starts
    the progress lines (other sweeps share this loop)."""
    run_task_ = run or run_task
    _label_ = label or _label
    results: list[dict | None] = [None] * len(tasks)
    bar = _Progress(len(tasks), progress, name=name)

    def failed(t, e: BaseException) -> None:
        bar.write(f"{name}: run failed ({_label_(t)}): {type(e).__name__}: {e}")

    try:
        if jobs <= 1 or len(tasks) <= 1:
            for i, t in enumerate(tasks):
                try:
                    results[i] = run_task_(t)
                except Exception as e:  # one bad run must not lose the others
                    failed(t, e)
                bar.step(_label_(t))
            return results
        ex = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)))
        try:
            pending = {ex.submit(run_task_, t): i for i, t in enumerate(tasks)}
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    i = pending.pop(fut)
                    try:
                        results[i] = fut.result()
                    except Exception as e:
                        failed(tasks[i], e)
                    bar.step(_label_(tasks[i]))
        except BaseException:
            ex.shutdown(wait=False, cancel_futures=True)
            raise
        ex.shutdown(wait=True)
        return results
    finally:
        bar.close()


# -- rows and aggregation -----------------------------------------------------------------------------
def row_of(result: dict) -> dict:
    """One results.csv row from a run's ``{"task", "summary"}``."""
    task, s = result["task"], result["summary"]
    med = {v: s.get("metrics", {}).get(v, {}).get("median", {}) for v in ("ground", "image")}
    row: dict[str, Any] = {
        "scenario": task["scenario"], "seed": task["seed"], "config": task["config"],
        "topology": task["topology"], "ordering": task["ordering"],
        "order": "" if task["order"] is None else " ".join(str(i) for i in task["order"]),
        "frames": s["frames"], "nodes": s["nodes"],
    }
    for col, m in GROUND_COLS:
        row[col] = med["ground"].get(m)
    for col, m in IMAGE_COLS:
        row[col] = med["image"].get(m)
    for col in BANDWIDTH_COLS:
        row[col] = s["bandwidth"][col]
    for col, m in IDENTITY_COLS:
        row[col] = med["ground"].get(m)
    # RunResult.bandwidth() gives 0 where a ratio has no denominator (no tracker entry sent, as
    # disconnected or centralized; no appearance sent): undefined, not zero bytes
    for col in ("bytes_per_tracker_frame", "appearance_bytes_per_new_tracker"):
        if not row[col]:
            row[col] = None
    return row


def _num(v) -> float | None:
    if v is None or v == "":
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def stats(values: Iterable[float | None]) -> dict:
    """``{"mean", "std", "n"}`` of the defined values; sample std (0 for one value)."""
    vals = [v for v in (_num(x) for x in values) if v is not None]
    if not vals:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": statistics.fmean(vals), "std": statistics.stdev(vals) if len(vals) > 1 else 0.0,
            "n": len(vals)}


def per_seed(rows: Iterable[Mapping],
             col: str) -> dict[tuple[str, str, str], dict[int, float | None]]:
    """``(scenario, topology, config) -> seed -> value`` with orderings averaged within a seed."""
    acc: dict[tuple[str, str, str], dict[int, list[float]]] = {}
    for r in rows:
        key = (str(r["scenario"]), str(r["topology"]), str(r["config"]))
        seeds = acc.setdefault(key, {})
        vals = seeds.setdefault(int(r["seed"]), [])
        v = _num(r.get(col))
        if v is not None:
            vals.append(v)
    return {k: {s: (statistics.fmean(v) if v else None) for s, v in sorted(d.items())}
            for k, d in acc.items()}


def aggregate(rows: Sequence[Mapping]) -> dict:
    """Mean and std over seeds (orderings averaged first) of every metric column.

    ``{"cells": {scenario: {topology: {config: {column: {"mean", "std", "n"}}}}},
    "ratios": {scenario: {topology: {"ground_mota" | "ground_idf1": {...}}}}}``; ratios are the
    full configuration's distributed / centralized value, per seed then over seeds (only where
    both were run and the centralized value is > 0). ``ratios_by_config`` has the same for every
    configuration (``{scenario: {config: {topology: {...}}}}``).
    """
    cells: dict[str, dict[str, dict[str, dict]]] = {}
    for col in METRIC_COLS:
        for (sc, topo, cfg), seeds in per_seed(rows, col).items():
            cells.setdefault(sc, {}).setdefault(topo, {}).setdefault(cfg, {})[col] = \
                stats(seeds.values())
    by_config: dict[str, dict[str, dict[str, dict]]] = {}
    for col in ("ground_mota", "ground_idf1"):
        ps = per_seed(rows, col)
        for (sc, t, cfg), seeds in ps.items():
            if t == CENTRALIZED or (sc, CENTRALIZED, cfg) not in ps:
                continue
            cent = ps[(sc, CENTRALIZED, cfg)]
            r = [v / cent[s] for s, v in seeds.items()
                 if v is not None and cent.get(s) is not None and cent[s] > 0]
            by_config.setdefault(sc, {}).setdefault(cfg, {}).setdefault(t, {})[col] = stats(r)
    ratios = {sc: d[FULL] for sc, d in by_config.items() if FULL in d}
    return {"cells": cells, "ratios": ratios, "ratios_by_config": by_config}


# -- outputs ------------------------------------------------------------------------------------------
def _csv_value(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_csv(path: Path, rows: Sequence[Mapping], columns: Sequence[str] = CSV_COLS) -> None:
    """``rows`` as CSV with ``columns`` (floats in full precision, ``None`` as empty)."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow([_csv_value(r.get(c)) for c in columns])


def _pm(cell: Mapping | None, scale: float = 1.0, fmt: str = "{:.3f}") -> str:
    if not cell or cell.get("mean") is None:
        return "–"
    return f"{fmt.format(cell['mean'] * scale)} ± {fmt.format(cell['std'] * scale)}"


def _order_in(items: Iterable[str], preferred: Sequence[str]) -> list[str]:
    items = list(dict.fromkeys(items))
    return [p for p in preferred if p in items] + [i for i in items if i not in preferred]


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def _mean(cell: Mapping | None, fmt: str = "{:.1f}") -> str:
    """A cell's mean alone (``–`` when undefined, or absent in a summary from before the
    column)."""
    if not cell or cell.get("mean") is None:
        return "–"
    return fmt.format(cell["mean"])


#: The identity table: (column, header, format of the mean over seeds)
IDENTITY_TABLE = (("ground_mota", "gMOTA", "{:.3f}"), ("ground_idf1", "gIDF1", "{:.3f}"),
                  ("ground_people", "people", "{:.1f}"), ("ground_track_ids", "track ids", "{:.1f}"),
                  ("ground_ids_per_person", "ids/person", "{:.2f}"),
                  ("ground_fragmentations", "FM", "{:.1f}"), ("ground_mt", "MT", "{:.1f}"),
                  ("ground_pt", "PT", "{:.1f}"), ("ground_ml", "ML", "{:.1f}"))
IDENTITY_NOTE = ("Identity on the ground, mean over seeds of the median over nodes: people in the "
                 "area, track ids a node reported, track ids matched per person (1.00: one id "
                 "each), FM fragmentations (a person's tracking interrupted), MT / PT / ML people "
                 "tracked in >= 80 %, 20-80 %, < 20 % of their frames.")


def identity_rows(agg: Mapping, meta: Mapping) -> list[list[str]]:
    """``[scenario, topology, config, *IDENTITY_TABLE means]`` for every cell, in the order of
    the other tables (``--topologies``, ``--configs``)."""
    rows = []
    for sc, cells in agg["cells"].items():
        for t in _order_in(cells, meta["topologies"]):
            for c in _order_in(cells[t], meta["configs"]):
                rows.append([sc, t, c] + [_mean(cells[t][c].get(col), fmt)
                                          for col, _, fmt in IDENTITY_TABLE])
    return rows


def identity_text(agg: Mapping, meta: Mapping) -> str:
    """The identity table as plain text (what ``sim_cluster ablation`` prints)."""
    header = ["scenario", "topology", "config"] + [h for _, h, _ in IDENTITY_TABLE]
    rows = [header] + identity_rows(agg, meta)
    width = [max(len(r[i]) for r in rows) for i in range(len(header))]
    lines = ["  ".join(v.ljust(w) if i < 3 else v.rjust(w) for i, (v, w) in enumerate(zip(r, width)))
             for r in rows]
    return "\n".join(lines + [IDENTITY_NOTE])


def markdown(agg: Mapping, meta: Mapping) -> str:
    """``results.md``: per scenario, metric tables (rows topology, columns config), the ratio to
    centralized and the bandwidth beside the paper's analytic figures."""
    configs, topologies = meta["configs"], meta["topologies"]
    lines = ["# Ablation: configurations x topologies (paper Sec. IV-B, Fig. 3)", ""]
    lines.append(f"Seeds {', '.join(map(str, meta['seeds']))}; frames: "
                 f"{meta['frames'] if meta['frames'] else 'each scenario’s default'}; ring and "
                 f"chain averaged over up to {meta['orderings']} distinct camera orderings per seed. "
                 "Cells are mean ± std over seeds (sample std, 0 with one seed) of the median over "
                 "nodes (cameras). Ground: each node's tracks against everyone in the area, matched "
                 "within 1 m. Image: the node's tracks projected into its own camera, IoU ≥ 0.5 "
                 "(the paper's protocol). Centralized: one tracker fed every camera's detections.")
    lines.append("")
    for sc, reason in meta.get("skipped", {}).items():
        lines.append(f"- **{sc} skipped**: {reason}")
    if meta.get("skipped"):
        lines.append("")
    if meta.get("failed"):
        lines.append(f"- **{len(meta['failed'])} run(s) failed** and are left out: "
                     + "; ".join(meta["failed"][:10]))
        lines.append("")
    for sc, cells in agg["cells"].items():
        info = meta.get("scenarios", {}).get(sc, {})
        topos = _order_in(cells, topologies)
        cfgs = _order_in((c for t in cells.values() for c in t), configs)
        nseeds = max((cells[t][c]["ground_mota"]["n"] for t in topos for c in cells[t]), default=0)
        lines.append(f"## {sc}")
        lines.append("")
        desc = [f"{info.get('cameras', '?')} cameras", f"{info.get('frames', '?')} frames",
                f"{nseeds} seed(s)"]
        for t in (t for t in topo.TOPOLOGIES.names() if ordered(t)):
            if t in info.get("orderings", {}):
                desc.append(f"{t} orderings: "
                            + ", ".join("-".join(map(str, o)) for o in info["orderings"][t]))
        lines.append("; ".join(desc) + ".")
        if info.get("ring_is_complete") and "ring" in topos:
            lines.append("With 3 cameras the ring is the complete graph (as the paper's Campus).")
        lines.append("")

        def label(t: str) -> str:
            n = len(info.get("orderings", {}).get(t, []))
            return f"{t} ({n} orderings)" if n > 1 else t

        for col, title in (("ground_mota", "Ground MOTA"), ("ground_idf1", "Ground IDF1"),
                           ("image_mota", "Image MOTA"), ("image_idf1", "Image IDF1")):
            lines.append(f"**{title}**")
            lines.append("")
            lines += _md_table(["topology"] + cfgs,
                               [[label(t)] + [_pm(cells[t].get(c, {}).get(col)) for c in cfgs]
                                for t in topos])
            lines.append("")
        lines.append("**Identity (ground)**")
        lines.append("")
        lines += _md_table(["topology", "config"] + [h for _, h, _ in IDENTITY_TABLE[2:]],
                           [[label(t), c] + [_mean(cells[t][c].get(col), fmt)
                                             for col, _, fmt in IDENTITY_TABLE[2:]]
                            for t in topos for c in cfgs if c in cells[t]])
        lines.append("")
        ratios = agg.get("ratios", {}).get(sc)
        if ratios:
            lines.append(f"**Distributed / centralized ({FULL}, ground)**")
            lines.append("")
            lines += _md_table(["topology", "MOTA ratio", "IDF1 ratio"],
                               [[label(t), _pm(r.get("ground_mota")), _pm(r.get("ground_idf1"))]
                                for t, r in ((t, ratios[t]) for t in topos if t in ratios)])
            lines.append("")
        bw_cfg = FULL if FULL in cfgs else cfgs[-1]
        lines.append(f"**Bandwidth ({bw_cfg}; measured bytes the codec produced; kB = 1000 B)**")
        lines.append("")
        rows = []
        for t in topos:
            c = cells[t].get(bw_cfg, {})
            if t == CENTRALIZED:
                rows.append([f"{t} (raw detections to one server)",
                             _pm(c.get("bytes_per_frame"), 1e-3, "{:.2f}"), "–", "–"])
            else:
                rows.append([label(t), _pm(c.get("bytes_per_frame"), 1e-3, "{:.2f}"),
                             _pm(c.get("bytes_per_tracker_frame"), 1e-3),
                             _pm(c.get("appearance_bytes_per_new_tracker"), 1e-3, "{:.2f}")])
        if info.get("image_streaming_bytes_per_frame"):
            rows.append(["centralized image streaming, this scenario's cameras (analytic)",
                         f"{info['image_streaming_bytes_per_frame'] / 1000:.2f}", "–", "–"])
        rows.append(["paper, distributed upper bound (analytic, Terrace)",
                     f"{PAPER['distributed_kB_per_frame_terrace']}",
                     f"{PAPER['kB_per_tracker_frame']}", f"{PAPER['kB_per_appearance_exchange']}"])
        rows.append(["paper, centralized image streaming (analytic, Terrace)",
                     f"{PAPER['centralized_images_kB_per_frame_terrace']}", "–", "–"])
        lines += _md_table(["", "kB per frame (whole network)", "kB per tracker per frame",
                            "kB per new tracker's appearance"], rows)
        lines.append("")
    lines.append(IDENTITY_NOTE)
    lines.append("")
    lines.append("Paper figures (Sec. III-D, IV): 51 numbers per tracker per frame, 0.78 kB; two "
                 "512-element descriptors per new tracker, 16.38 kB, sent once; centralized "
                 "streaming of 4 RGB 360x288 images, 1215 kB per frame (1,244,160 B: the paper's "
                 "kB here is 1024 B). Measured figures count every directed link (a message to "
                 "each neighbour), per frame; per-tracker and per-appearance figures are per "
                 "tracker entry on one link.")
    lines.append("")
    return "\n".join(lines)


_CONFIG_COLORS = {"dkf": "#9ecae1", "dkf+lda": "#4292c6", "dkf+lda+dtm": "#08306b",
                  "dkf+dtm": "#fdae6b", "dkf+lda+dtm:noreg": "#a1d99b", "dkf+dtm:noreg": "#e6550d"}


def plot(path: Path, agg: Mapping, meta: Mapping) -> None:
    """``ablation.png``: rows scenarios, columns ground MOTA / IDF1; groups topologies, one bar
    per config, error bars the std over seeds (the paper's Fig. 3)."""
    import matplotlib  # plotting only here: keeps matplotlib out of every other command

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after use("Agg"): no display needed

    scenarios = list(agg["cells"])
    cols = (("ground_mota", "ground MOTA"), ("ground_idf1", "ground IDF1"))
    fig, axes = plt.subplots(max(len(scenarios), 1), 2, squeeze=False,
                             figsize=(12, 2.9 * max(len(scenarios), 1)))
    for r, sc in enumerate(scenarios):
        cells = agg["cells"][sc]
        topos = _order_in(cells, meta["topologies"])
        cfgs = _order_in((c for t in cells.values() for c in t), meta["configs"])
        width = 0.8 / max(len(cfgs), 1)
        for j, (col, title) in enumerate(cols):
            ax = axes[r][j]
            for k, c in enumerate(cfgs):
                xs, ys, es = [], [], []
                for i, t in enumerate(topos):
                    cell = cells[t].get(c, {}).get(col)
                    if cell and cell["mean"] is not None:
                        xs.append(i - 0.4 + width * (k + 0.5))
                        ys.append(cell["mean"])
                        es.append(cell["std"])
                ax.bar(xs, ys, width, yerr=es, capsize=2, label=c,
                       color=_CONFIG_COLORS.get(c), edgecolor="black", linewidth=0.4)
            ax.axhline(0, color="black", linewidth=0.6)
            ax.set_xticks(range(len(topos)))
            ax.set_xticklabels(topos)
            ax.set_title(f"{sc}: {title}", fontsize=10)
            ax.grid(axis="y", alpha=0.3)
            lo = min(0.0, ax.get_ylim()[0])
            ax.set_ylim(lo, max(1.0, ax.get_ylim()[1]))
    handles, labels = axes[0][0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper center", ncol=len(labels), frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.97 if len(scenarios) > 1 else 0.92))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(out: Path, rows: Sequence[Mapping], agg: Mapping, meta: Mapping,
                  results: Sequence[dict] = ()) -> list[Path]:
    """Write results.csv, results.md, summary.json, ablation.png (and runs.jsonl)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "results.csv", out / "results.md", out / "summary.json", out / "ablation.png"]
    write_csv(paths[0], rows)
    paths[1].write_text(markdown(agg, meta))
    paths[2].write_text(json.dumps({"meta": meta, "paper": PAPER, **agg}, indent=2))
    plot(paths[3], agg, meta)
    if results:
        p = out / "runs.jsonl"
        with open(p, "w") as fh:
            for r in results:
                fh.write(json.dumps(r, sort_keys=True) + "\n")
        paths.append(p)
    return paths


# -- command ------------------------------------------------------------------------------------------
def _uses_data_root(scenario: str) -> bool:
    """Whether ``--data-root`` applies: only dataset kinds take it (``load_scenario`` puts it in
    ``[source]``, which a synthetic scenario rejects as an unknown field)."""
    candidate = Path(scenario)
    if candidate.is_dir() or candidate.suffix == ".json":  # an exported detections folder
        return False
    try:
        raw = read_scenario_toml(resolve_scenario_path(scenario))
    except ScenarioError as e:
        raise AblationError(str(e)) from None
    source = raw.get("source")
    return isinstance(source, dict) and source.get("kind", "synthetic") == "epfl-gt"


def probe(scenarios: Sequence[str], seed: int, data_root: str | None,
          log=None, name: str = "ablation") -> tuple[dict[str, dict], dict[str, str]]:
    """Load each scenario's first frame: its cameras, or why it is skipped (missing data).

    An unknown or invalid scenario raises ``AblationError``.
    """
    log = log or sys.stderr
    info: dict[str, dict] = {}
    skipped: dict[str, str] = {}
    for sc in scenarios:
        root = data_root if _uses_data_root(sc) else None
        try:
            d = load_scenario(sc, seed=seed, frames=1, data_root=root)
        except ScenarioError as e:
            raise AblationError(str(e)) from None
        except OSError as e:  # epfl.DataNotFoundError: the data is not there
            skipped[sc] = str(e)
            print(f"{name}: skipping {sc}: {e}", file=log, flush=True)
            continue
        n = d.num_cameras
        info[sc] = {"cameras": n, "data_root": root,
                    "image_streaming_bytes_per_frame":
                        sum(3 * int(c.image_size[0]) * int(c.image_size[1]) for c in d.cameras),
                    "ring_is_complete": n > 1 and topo.build("ring", n) == topo.build("complete", n)}
    return info, skipped


def main(args) -> int:
    """``sim_cluster ablation``; raises ``AblationError`` on a bad argument."""
    t0 = time.monotonic()
    scenarios = parse_list(args.scenarios, None, "scenario")
    seeds = parse_seeds(args.seeds)
    configs = parse_list(args.configs, CONFIG_NAMES, "config")
    topologies = parse_list(args.topologies, topology_names(), "topology")
    if args.orderings < 1:
        raise AblationError(f"--orderings must be >= 1, got {args.orderings}")
    if args.frames is not None and args.frames < 1:
        raise AblationError(f"--frames must be >= 1, got {args.frames}")
    jobs = (os.cpu_count() or 1) if args.jobs is None else args.jobs
    if jobs < 1:
        raise AblationError(f"--jobs must be >= 1, got {args.jobs}")
    data_root = None if args.data_root is None else str(Path(args.data_root).expanduser().resolve())

    info, skipped = probe(scenarios, seeds[0], data_root)
    runnable = [s for s in scenarios if s in info]
    if not runnable:
        raise AblationError("nothing to run: every scenario was skipped")
    tasks = plan(runnable, seeds, configs, topologies,
                 cameras={s: info[s]["cameras"] for s in runnable},
                 orderings=args.orderings, frames=args.frames,
                 data_root={s: info[s]["data_root"] for s in runnable})
    quiet = getattr(args, "quiet", False)
    if not quiet:
        print(f"ablation: {len(tasks)} runs ({len(runnable)} scenario(s) x {len(seeds)} seed(s) x "
              f"{len(configs)} config(s) x {len(topologies)} topologies, ring/chain x up to "
              f"{args.orderings} orderings) on {min(jobs, len(tasks))} process(es)",
              file=sys.stderr, flush=True)
    results = execute(tasks, jobs, progress=not quiet)
    ok = [r for r in results if r is not None]
    failed = [_label(t) for t, r in zip(tasks, results) if r is None]
    rows = [row_of(r) for r in ok]
    for r in ok:  # the frames actually run, per scenario
        info[r["task"]["scenario"]].setdefault("frames", r["summary"]["frames"])
    for sc in runnable:
        info[sc]["orderings"] = {t: [list(tk.order) for tk in tasks
                                     if tk.scenario == sc and tk.topology == t
                                     and tk.seed == seeds[0] and tk.config == configs[0]]
                                 for t in topologies if ordered(t)}
    meta = {"scenarios": info, "skipped": skipped, "failed": failed, "seeds": seeds,
            "configs": configs, "topologies": topologies, "orderings": args.orderings,
            "frames": args.frames, "runs": len(tasks),
            "std": "sample standard deviation over seeds (ddof=1; 0 with one seed)",
            "ordering_average": "ring/chain: mean over orderings within a seed, then over seeds",
            "provenance": provenance()}  # the docs' tables name commit and machine
    agg = aggregate(rows)
    out = Path(args.out)
    paths = write_outputs(out, rows, agg, meta, results=ok)
    wall = time.monotonic() - t0
    if rows:
        print(identity_text(agg, meta))
    print(f"ablation: {len(rows)}/{len(tasks)} runs in {_hms(wall)}; wrote "
          + ", ".join(str(p) for p in paths))
    if failed:
        print(f"ablation: {len(failed)} run(s) failed (see above); they are left out",
              file=sys.stderr)
        return 1
    return 0
