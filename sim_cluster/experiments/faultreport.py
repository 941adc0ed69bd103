"""``sim_cluster fault-report``: the standard faults on one scenario, against the fault-free run.

Cases (4-node ring unless said): kill 1 of 4 at mid-run; kill and restart; 10% and 30% loss on
every link (async); every message 3 frames late (async); a partition into two halves for a
quarter of the run; node 0 faulty from mid-run on, one case per faulty kind (hijack, phantom,
bumped, hallucinate, stale, forged_merge: ``edge_node/forgery.py``; scored on the honest nodes,
``sim_cluster trust-report`` has the detail). Each case is run in process through the shared fault layer
(``edge_node/faults.py``), deterministically from its seed; the multi-process cluster applies
the same plans (``sim_cluster up --faults``).

Reported per case: the survivors' ground MOTA and IDF1 over the frames from the fault on, beside
the fault-free run's over the same frames (targets that only a dead camera could see are left out
of both), their ratio, the frames until the nodes agree on ids again after the fault ends
(restart, partition), what the receivers refused (messages too old, from the future or a second
time; tracker entries and merges the screen rejected, ``edge_node/core/screen.py``), and crashes
(exceptions out of a node: must be 0).
"""
from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.faults import FAULTY_KINDS, FaultPlan
from sim_cluster.evaluation.metrics import evaluate
from sim_cluster.network.inprocess import run_network
from sim_cluster.network.topology import build
from sim_cluster.progress import progress_bar
from sim_cluster.scenarios.data import ScenarioData
from sim_cluster.scenarios.loader import scenario_from_args


@dataclass
class Case:
    name: str
    plan: dict
    mode: str = "sync"
    baseline_mode: str = "sync"
    dead: tuple[int, ...] = ()  # nodes dead at the end (not survivors)
    faulty: tuple[int, ...] = ()  # nodes that lie (not scored; their people still count)
    heal: int | None = None  # frame the fault ends (restart, partition healed)
    extra: dict = field(default_factory=dict)


def standard_cases(frames: int) -> list[Case]:
    mid, q = frames // 2, frames // 4
    return [
        Case("kill 1 of 4 at mid-run", {"node": [{"node": 2, "kill": mid}]}, dead=(2,)),
        Case("kill and restart", {"node": [{"node": 2, "kill": mid, "restart": mid + q // 2}]},
             heal=mid + q // 2),
        Case("10% loss, every link (async)", {"seed": 1, "link": [{"loss": 0.1, "start": mid}]},
             mode="async", baseline_mode="async"),
        Case("30% loss, every link (async)", {"seed": 1, "link": [{"loss": 0.3, "start": mid}]},
             mode="async", baseline_mode="async"),
        Case("3-frame delay, every link (async)", {"link": [{"delay": 3, "start": mid}]},
             mode="async", baseline_mode="async"),
        Case("partition {0,1} / {2,3}", {"partition": [{"groups": [[0, 1], [2, 3]],
                                                        "start": mid, "stop": mid + q}]},
             heal=mid + q),
    ] + [Case(f"faulty node 0: {kind}", {"seed": 1, "faulty": [{"node": 0, "kind": kind,
                                                                 "start": mid}]}, faulty=(0,))
         for kind in FAULTY_KINDS]


def _without_dead_only(data: ScenarioData, dead: tuple[int, ...], start: int) -> ScenarioData:
    """Ground truth without the people that, from ``start`` on, only dead cameras could see."""
    if not dead:
        return data
    out = copy.copy(data)
    truth = copy.copy(data.truth)
    ids, xy, wh = list(truth.ids), list(truth.xy), list(truth.wh)
    alive_cams = [c for c in range(data.num_cameras) if c not in dead]
    for k in range(start, data.frames):
        seen = set()
        for c in alive_cams:
            seen.update(int(i) for i in truth.boxes[c][k][0])
        keep = np.array([int(i) in seen for i in ids[k]], dtype=bool)
        ids[k], xy[k], wh[k] = ids[k][keep], xy[k][keep], wh[k][keep]
    truth.ids, truth.xy, truth.wh = ids, xy, wh
    out.truth = truth
    return out


def _ground(result, data, nodes, start) -> dict:
    sub = {n: result.tracks[n] for n in nodes}
    per = evaluate(sub, data, views=("ground",), start=start)["ground"]["per_node"]
    return {m: float(np.median([per[str(n)][m] for n in nodes])) for m in ("mota", "idf1")}


def _recovery(result, adjacency, nodes, heal: int | None, frames: int, agree: float = 0.95):
    """Frames after ``heal`` until every live node holds >= ``agree`` of its neighbours' ids."""
    if heal is None:
        return None
    for k in range(heal, frames):
        ok = True
        for n in nodes:
            theirs = {t.id for j in adjacency[n] if j in nodes for t in result.tracks[j][k]}
            mine = {t.id for t in result.tracks[n][k]}
            if theirs and len(mine & theirs) / len(theirs) < agree:
                ok = False
                break
        if ok:
            return k - heal
    return frames - heal


def run_report(data: ScenarioData, cfg: TrackerConfig | None = None, progress=None) -> dict:
    cfg = cfg or TrackerConfig()
    adj = build("ring", data.num_cameras)
    frames = data.frames
    start = frames // 2
    baselines = {}
    rows = []
    cases = standard_cases(frames)
    for i, case in enumerate(cases):
        if case.baseline_mode not in baselines:
            baselines[case.baseline_mode] = run_network(data, adj, cfg, mode=case.baseline_mode)
        crashes = 0
        try:
            r = run_network(data, adj, cfg, mode=case.mode, faults=FaultPlan.from_dict(case.plan))
        except Exception as e:  # noqa: BLE001 - a crash is what this report counts
            crashes, r = 1, None
            error = f"{type(e).__name__}: {e}"
        survivors = tuple(n for n in range(data.num_cameras)
                          if n not in case.dead and n not in case.faulty)
        truth = _without_dead_only(data, case.dead, start)
        ref = _ground(baselines[case.baseline_mode], truth, survivors, start)
        row = {"case": case.name, "mode": case.mode, "survivors": list(survivors),
               "fault_free": ref, "crashes": crashes}
        if r is not None:
            got = _ground(r, truth, survivors, start)
            row.update(got=got,
                       ratio={m: (got[m] / ref[m]) if ref[m] else None for m in got},
                       frames_to_recover=_recovery(r, adj, survivors, case.heal, frames),
                       rejected=sum(s.ignored_messages + s.duplicate_messages
                                    + sum(s.rejected.values()) for s in r.stats.values()),
                       bytes_per_frame=r.bandwidth()["bytes_per_frame"])
        else:
            row["error"] = error
        rows.append(row)
        if progress:
            progress(i + 1, len(cases))
    return {"scenario": data.name, "seed": data.seed, "frames": frames, "topology": "ring",
            "fault_from_frame": start, "cases": rows}


def table(report: dict) -> str:
    lines = [f"Faults on {report['scenario']} (seed {report['seed']}, {report['frames']} frames, "
             f"4-node ring; metrics over frames {report['fault_from_frame']}+, survivors only)",
             "",
             "| case | mode | ground MOTA (fault-free) | ratio | ground IDF1 (fault-free) | ratio "
             "| frames to recover | rejected | crashes |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in report["cases"]:
        if "got" not in r:
            lines.append(f"| {r['case']} | {r['mode']} | error: {r.get('error')} | | | | | | "
                         f"{r['crashes']} |")
            continue
        rec = "-" if r["frames_to_recover"] is None else str(r["frames_to_recover"])
        lines.append(
            f"| {r['case']} | {r['mode']} | {r['got']['mota']:.3f} ({r['fault_free']['mota']:.3f}) "
            f"| {r['ratio']['mota']:.3f} | {r['got']['idf1']:.3f} ({r['fault_free']['idf1']:.3f}) "
            f"| {r['ratio']['idf1']:.3f} | {rec} | {r['rejected']} | {r['crashes']} |")
    return "\n".join(lines)


def main(args) -> int:
    """``sim_cluster fault-report``."""
    data = scenario_from_args(args)
    update, close = progress_bar("fault cases", len(standard_cases(data.frames)), not args.quiet)
    try:
        report = run_report(data, progress=update)
    finally:
        close()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fault_report.json").write_text(json.dumps(report, indent=2))
    text = table(report)
    (out / "fault_report.md").write_text(text + "\n")
    print(text)
    return 0 if all(r["crashes"] == 0 for r in report["cases"]) else 1
