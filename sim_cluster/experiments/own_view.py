"""Each camera's own view before and after it draws what it sees, in one session: image and
ground MOTA of ``dkf+lda+dtm`` with the drawing of before (``view_place = false``,
``view_behind = 1``, ``view_locate = 1e9``) and with the defaults (docs/tuning.md, "Each camera
draws what it sees").

    python -m sim_cluster.experiments.own_view --out docs/results/views \\
        [--cells terrace-gt/complete,terrace-gt/ring,terrace-gt/chain,terrace-sim/complete]
        [--seeds 0,1,2]

Each run's figure is the median over its nodes (``evaluation.metrics.evaluate``), a cell's the
median over the seeds. The runs go one after the other in this process (both drawings of a seed
on the same loaded scenario). Writes ``own_view.json`` in ``--out``: per cell and drawing, each
seed's figures and the medians, and ``meta.provenance``.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from edge_node.core import TrackerConfig
from sim_cluster.evaluation.metrics import evaluate
from sim_cluster.experiments.provenance import provenance
from sim_cluster.network.inprocess import run_network
from sim_cluster.network.topology import build
from sim_cluster.scenarios.loader import load_scenario

CONFIG = "dkf+lda+dtm"
#: the drawing before: at the network's estimate, only targets measured within view_frames
BEFORE = {"view_place": False, "view_behind": 1.0, "view_locate": 1e9}
DRAWINGS = {"before": BEFORE, "after": {}}
DEFAULT_CELLS = "terrace-gt/complete,terrace-gt/ring,terrace-gt/chain,terrace-sim/complete"


def measure(cells: list[tuple[str, str]], seeds: list[int], log=print) -> dict:
    out: dict = {}
    for scenario, topology in cells:
        cell = out.setdefault(f"{scenario}/{topology}", {d: {"seeds": {}} for d in DRAWINGS})
        for seed in seeds:
            data = load_scenario(scenario, seed=seed)
            adjacency = build(topology, data.num_cameras)
            for name, overrides in DRAWINGS.items():
                cfg = TrackerConfig.for_ablation(CONFIG, **overrides)
                ev = evaluate(run_network(data, adjacency, cfg).tracks, data,
                              views=("image", "ground"))
                got = {v: ev[v]["median"]["mota"] for v in ("image", "ground")}
                cell[name]["seeds"][str(seed)] = got
                log(f"{scenario} {topology} seed {seed} {name}: image MOTA {got['image']:.3f}, "
                    f"ground MOTA {got['ground']:.3f}")
        for name in DRAWINGS:
            runs = cell[name]["seeds"].values()
            for v in ("image", "ground"):
                cell[name][f"{v}_mota"] = statistics.median(r[v] for r in runs)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim_cluster.experiments.own_view",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--cells", default=DEFAULT_CELLS, help="scenario/topology, comma-separated")
    p.add_argument("--seeds", default="0,1,2", help="comma-separated scenario seeds")
    p.add_argument("--out", default="runs/own-view", help="folder for own_view.json")
    a = p.parse_args(argv)
    cells = [tuple(c.split("/", 1)) for c in a.cells.split(",")]
    seeds = [int(s) for s in a.seeds.split(",")]
    res = {"meta": {"provenance": provenance(), "config": CONFIG, "before": BEFORE,
                    "seeds": seeds, "statistic": "median over nodes, then over seeds"},
           "cells": measure(cells, seeds, log=lambda s: print(s, flush=True))}
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "own_view.json").write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
