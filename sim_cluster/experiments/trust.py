"""``sim_cluster trust-report``: one faulty node (F = 1) of each kind against the fault-free run,
honest nodes only (docs/faults.md, "A faulty neighbour").

Per scenario (a ring), seed and faulty kind (``edge_node/forgery.py``: hijack, phantom, bumped,
hallucinate, stale, forged_merge), node 0 is faulty from a third of the run to two thirds, in
process through the shared fault layer (the camera processes apply the same plans). Reported,
over the honest nodes (every node but 0):

* ground MOTA and IDF1 from the fault's start to the end, against the fault-free run's over the
  same frames (median over honest nodes), and their ratio;
* settled: ground MOTA of the faulty node and its neighbours from 2 s after each change of the
  fault (its start and its end), against the fault-free run's (a bumped camera's goal: back to
  0.95x within 2 s);
* far tracks: tracks an honest node reported farther than 2 m from every person for more than
  1 s in a row (episodes, summed over honest nodes);
* quarantine: per honest neighbour of the faulty node, the frames from the fault's start until
  it quarantined node 0 (``edge_node/core/trust.py``), and every quarantine of an honest node;
* ids kept: of the people tracked just before the fault, the share whose id on the honest nodes
  is the same just after it ends;
* in fault-free runs, sync and async with late and lost messages (10 % loss, 1-3 frames of
  delay), every quarantine at any node (must be 0); their MOTA and IDF1 over the same nodes.

With ``--baseline`` every faulty run is repeated with the trust role off (``trust_check =
false``): the harm each kind does without the defence; ``--baseline-from FILE`` takes those
runs from an earlier ``trust.json`` instead (they do not depend on the role's parameters).
``--tracker-config FILE`` sets tracker parameters for every run (recorded in the JSON's
``meta``). Cells run in a process pool (``--jobs``),
results in the plan's order whatever the pool. Writes ``trust.json`` (every cell, with its
provenance) and prints a table; ``sim_cluster report`` renders the docs' table from the JSON.
"""
from __future__ import annotations

import dataclasses
import json
import multiprocessing as mp
import time
from pathlib import Path

import numpy as np

from edge_node.faults import FAULTY_KINDS, FaultPlan
from sim_cluster.evaluation.metrics import evaluate
from sim_cluster.experiments.ablation import AblationError, parse_seeds
from sim_cluster.experiments.provenance import provenance
from sim_cluster.experiments.run import tracker_config
from sim_cluster.experiments.report import trust_rows as table
from sim_cluster.network.inprocess import RunResult, run_network
from sim_cluster.network.topology import build
from sim_cluster.progress import progress_bar
from sim_cluster.scenarios.loader import load_scenario

FAULTY = 0
FAR_M = 2.0
LONG_S = 1.0
SETTLE_S = 2.0  # s: how long after each change of a fault the settled figures start


def _ground(result: RunResult, data, nodes, start: int) -> dict:
    sub = {n: result.tracks[n] for n in nodes}
    per = evaluate(sub, data, views=("ground",), start=start)["ground"]["per_node"]
    return {m: float(np.median([per[str(n)][m] for n in nodes])) for m in ("mota", "idf1")}


def settled_mota(result: RunResult, data, nodes, start: int, stop: int) -> float:
    """Ground MOTA of ``nodes`` (median) over the frames at least ``SETTLE_S`` after each change
    of the fault (from ``start + 2 s`` to ``stop``, and from ``stop + 2 s`` to the end): what
    a node tracks once it has had time to recover (a bumped camera re-registered, a quarantine
    taken, a camera back in its place). Misses, false positives and switches of both spans
    summed before the ratio."""
    settle = int(round(SETTLE_S * data.fps))
    spans = [(start + settle, stop), (stop + settle, data.frames)]
    sub = {n: result.tracks[n] for n in nodes}
    errors = {n: 0.0 for n in nodes}
    objects = {n: 0.0 for n in nodes}
    for a, b in spans:
        if b <= a:
            continue
        per = evaluate(sub, data, views=("ground",), start=a, frames=b)["ground"]["per_node"]
        for n in nodes:
            m = per[str(n)]
            errors[n] += m["num_misses"] + m["num_false_positives"] + m["num_switches"]
            objects[n] += m["num_objects"]
    return float(np.median([1.0 - errors[n] / objects[n] for n in nodes if objects[n]]))


def far_episodes(result: RunResult, data, nodes, start: int) -> int:
    """Tracks farther than ``FAR_M`` from every person for more than ``LONG_S`` in a row."""
    upm, long = data.units_per_metre, int(round(LONG_S * data.fps))
    episodes = 0
    for n in nodes:
        run: dict = {}
        for k in range(start, len(result.tracks[n])):
            xy = data.truth.xy[k]
            far_now = set()
            for t in result.tracks[n][k]:
                d = np.min(np.hypot(*(np.asarray(xy) - t.x[:2]).T)) / upm if len(xy) else np.inf
                if d > FAR_M:
                    far_now.add(t.id)
            for tid in far_now:
                run[tid] = run.get(tid, 0) + 1
                if run[tid] == long + 1:
                    episodes += 1
            for tid in list(run):
                if tid not in far_now:
                    del run[tid]
    return episodes


def _ids(result: RunResult, data, nodes, k: int) -> dict:
    """Per honest node, person -> the id of its track within 1 m at frame ``k``."""
    out = {}
    upm = data.units_per_metre
    for n in nodes:
        m = {}
        for pid, p in zip(np.asarray(data.truth.ids[k]).tolist(), data.truth.xy[k]):
            best = min(((np.hypot(*(t.x[:2] - p)) / upm, t.id) for t in result.tracks[n][k]),
                       default=(np.inf, None))
            if best[0] < 1.0:
                m[pid] = best[1]
        out[n] = m
    return out


def kept_ids(result: RunResult, data, nodes, before: int, after: int) -> float | None:
    a, b = _ids(result, data, nodes, before), _ids(result, data, nodes, after)
    pairs = [(a[n][p], b[n].get(p)) for n in nodes for p in a[n] if p in b[n]]
    return None if not pairs else sum(x == y for x, y in pairs) / len(pairs)


def quarantines(result: RunResult) -> dict:
    """Per node, per neighbour: the frames it was quarantined (``trust`` in the run's stats)."""
    return {n: {j: t["quarantined_frames"] for j, t in s.trust.items()}
            for n, s in result.stats.items()}


LATE = {"loss": 0.1, "delay": 1, "jitter": 2}  # the fault-free async runs' links


def run_cell(scenario: str, seed: int, kind: str | None, config: str = "dkf+lda+dtm",
             mode: str = "sync", trust: bool = True, late: bool = False,
             tracker_file: str | None = None) -> dict:
    """One run: node 0 of a ring faulty of ``kind`` (None: fault-free) for the middle third;
    ``tracker_file``: tracker parameters over ``config`` (``--tracker-config``)."""
    data = load_scenario(scenario, seed=seed)
    adj = build("ring", data.num_cameras)
    start, stop = data.frames // 3, 2 * data.frames // 3
    plan: dict = {"seed": seed}
    if kind is not None:
        plan["faulty"] = [{"node": FAULTY, "kind": kind, "start": start, "stop": stop}]
    if late:
        plan["link"] = [dict(LATE)]
    cfg = dataclasses.replace(tracker_config(config, tracker_file), trust_check=trust)
    t0 = time.process_time()
    r = run_network(data, adj, cfg, mode=mode, faults=FaultPlan.from_dict(plan))
    # the nodes scored: all but node 0, in the fault-free runs too (the ratios compare the same
    # nodes); quarantines are counted at every node when nobody is faulty
    honest = [n for n in range(data.num_cameras) if n != FAULTY]
    judges = honest if kind else list(range(data.num_cameras))
    first = {n: r.stats[n].trust.get(FAULTY, {}).get("first_quarantine") for n in adj[FAULTY]}
    q = quarantines(r)
    return {"scenario": scenario, "seed": seed, "kind": kind or "none", "mode": mode,
            "late": late, "trust": trust, "frames": data.frames, "start": start, "stop": stop,
            "ground": _ground(r, data, honest, start),
            # the faulty node and its neighbours, once settled (a bumped camera's goal)
            "settled_mota": settled_mota(r, data, [FAULTY, *adj[FAULTY]], start, stop),
            "far": far_episodes(r, data, honest, start),
            "kept_ids": kept_ids(r, data, honest, start - 1, stop + 25),
            "quarantine_frames": {str(n): (None if f is None or kind is None else f - start)
                                  for n, f in first.items()},
            "honest_quarantined": sum(1 for n in judges for j, ks in q[n].items()
                                      if ks and (kind is None or j != FAULTY)),
            "cpu_s": round(time.process_time() - t0, 1)}


def plan_cells(scenarios: list[str], seeds: list[int], kinds: list[str], config: str,
               baseline: bool, tracker_file: str | None = None) -> list[dict]:
    cells = []
    for scenario in scenarios:
        for seed in seeds:
            common = dict(scenario=scenario, seed=seed, config=config, tracker_file=tracker_file)
            cells.append(dict(common, kind=None))
            cells.append(dict(common, kind=None, mode="async", late=True))
            for kind in kinds:
                cells.append(dict(common, kind=kind))
                if baseline:
                    cells.append(dict(common, kind=kind, trust=False))
    return cells


def _run(cell: dict) -> dict:
    return run_cell(**cell)


def summarise(rows: list[dict]) -> list[dict]:
    """Per scenario, kind and defence (trust on / off): the medians over seeds of the honest
    nodes' ratios to the fault-free sync run, and the worst of the other figures."""
    base = {(r["scenario"], r["seed"]): r["ground"] for r in rows
            if r["kind"] == "none" and r["mode"] == "sync"}
    base_settled = {(r["scenario"], r["seed"]): r.get("settled_mota") for r in rows
                    if r["kind"] == "none" and r["mode"] == "sync"}
    groups: dict = {}
    for r in rows:
        key = (r["scenario"], r["kind"], r["mode"], r["late"], r["trust"])
        groups.setdefault(key, []).append(r)
    out = []
    for (scenario, kind, mode, late, trust), rs in groups.items():
        ratio = {m: float(np.median([r["ground"][m] / base[(scenario, r["seed"])][m]
                                     for r in rs if base[(scenario, r["seed"])][m]]))
                 for m in ("mota", "idf1")}
        settled = [r["settled_mota"] / base_settled[(scenario, r["seed"])] for r in rs
                   if r.get("settled_mota") is not None
                   and base_settled.get((scenario, r["seed"]))]
        qf = [f for r in rs for f in r["quarantine_frames"].values()]
        kept = [r["kept_ids"] for r in rs if r["kept_ids"] is not None]
        out.append({"scenario": scenario, "kind": kind, "mode": mode, "late": late,
                    "trust": trust, "seeds": len(rs),
                    "mota": float(np.median([r["ground"]["mota"] for r in rs])),
                    "idf1": float(np.median([r["ground"]["idf1"] for r in rs])),
                    "mota_ratio": ratio["mota"], "idf1_ratio": ratio["idf1"],
                    "settled_ratio": float(np.median(settled)) if settled else None,
                    "far": max(r["far"] for r in rs),
                    "quarantine_frames": (None if not qf or kind == "none" or None in qf
                                          else max(qf)),
                    "unquarantined": sum(f is None for f in qf) if kind != "none" else 0,
                    "kept_ids": min(kept) if kept else None,
                    "honest_quarantined": sum(r["honest_quarantined"] for r in rs)})
    return out


def main(args) -> int:
    """``sim_cluster trust-report``."""
    kinds = [k for k in (args.kinds.split(",") if args.kinds else FAULTY_KINDS) if k]
    bad = [k for k in kinds if k not in FAULTY_KINDS]
    if bad:
        raise AblationError(f"--kinds: unknown faulty kind(s) {', '.join(bad)}; choose from "
                               f"{', '.join(FAULTY_KINDS)}")
    seeds = parse_seeds(args.seeds)
    tracker_file = getattr(args, "tracker_config", None)
    if tracker_file:
        tracker_config(args.config, tracker_file)  # a bad file is one error now, not one per run
    cells = plan_cells(args.scenarios.split(","), seeds, kinds, args.config, args.baseline,
                       tracker_file)
    reused, baseline_from = [], getattr(args, "baseline_from", None)
    if baseline_from:  # trust-off rows of an earlier report: they do not depend on the role
        old = json.loads(Path(baseline_from).read_text())
        was = old.get("meta", {})
        told = (was.get("tracker_config") or {}).get("text")
        now = Path(tracker_file).read_text() if tracker_file else None
        if was.get("config") != args.config or told != now:
            raise AblationError(
                f"--baseline-from {baseline_from}: its runs used --config {was.get('config')} "
                f"and {'no --tracker-config' if told is None else 'another --tracker-config'}; "
                "they are not this report's trust-off runs")
        have = {(r["scenario"], r["seed"], r["kind"]): r for r in old["rows"] if not r["trust"]}
        keep = []
        for c in cells:
            key = (c["scenario"], c["seed"], c["kind"] or "none")
            if c.get("trust") is False and key in have:
                reused.append(have[key])
            else:
                keep.append(c)
        cells = keep
    update, close = progress_bar("trust cells", len(cells), not args.quiet)
    rows = []
    try:
        if args.jobs > 1:
            with mp.get_context("spawn").Pool(args.jobs) as pool:
                for row in pool.imap(_run, cells):
                    rows.append(row)
                    update(len(rows), len(cells))
        else:
            for cell in cells:
                rows.append(_run(cell))
                update(len(rows), len(cells))
    finally:
        close()
    rows += reused
    summary = summarise(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "trust.json").write_text(json.dumps(
        {"meta": {"provenance": provenance(), "seeds": seeds, "config": args.config,
                  "tracker_config": None if not tracker_file else {
                      "file": str(tracker_file), "text": Path(tracker_file).read_text()},
                  "faulty_node": FAULTY, "topology": "ring",
                  "baseline_from": None if not reused else {
                      "file": str(baseline_from), "rows": len(reused),
                      "provenance": old.get("meta", {}).get("provenance")}},
         "summary": summary, "rows": rows}, indent=1))
    print(table(summary))
    return 0
