"""``sim_cluster soak``: the chaos schedule, the verdict's arithmetic, and a short soak of real
processes whose fault-free minute scores exactly what the in-process network scores."""
from __future__ import annotations

import json

import pytest

from edge_node.faults import FAULTY_KINDS, FaultPlan, Network
from sim_cluster.experiments.soak import (Fault, chaos_schedule, fault_plan, soak, summary_lines,
                                          verdict)
from sim_cluster.network.topology import build


def test_chaos_schedule_is_seeded_spaced_and_a_valid_fault_plan():
    a = chaos_schedule(7, 30, 4)
    assert a == chaos_schedule(7, 30, 4) and a != chaos_schedule(8, 30, 4)
    assert [int(f.at_s // 60) for f in a] == list(range(2, 30, 3))  # one every 3 min from min 2
    assert {f.kind for f in a} == {"kill", "freeze", "loss", "partition", "long_freeze",
                                   "disk_full", "flood", "faulty"}
    for f in a:
        assert 5 <= f.at_s % 60 <= 20
        assert f.kind in ("partition", "disk_full") or 0 <= f.node < 4
    assert {f.duration_s for f in a if f.kind == "long_freeze"} <= {30.0, 120.0}
    adjacency = build("ring", 4)
    plan = fault_plan(a, adjacency, 25.0, 7)
    FaultPlan.from_dict(plan, Network(adjacency, 30 * 60 * 25 + 1))  # the nodes' own check
    faulty = next(f for f in a if f.kind == "faulty")
    (rule,) = plan["faulty"]
    assert rule == {"node": faulty.node, "kind": faulty.faulty, "start": round(faulty.at_s * 25),
                    "stop": round((faulty.at_s + faulty.duration_s) * 25)}
    assert rule["kind"] in FAULTY_KINDS and 20 <= faulty.duration_s <= 40
    loss = next(f for f in a if f.kind == "loss")
    rules = [r for r in plan["link"] if r["start"] == round(loss.at_s * 25)]
    assert {(r["src"], r["dst"]) for r in rules} == (
        {(loss.node, j) for j in adjacency[loss.node]} | {(j, loss.node) for j in adjacency[loss.node]})


def _sample(t, rss, pids=(1, 2), age=100.0):
    return {"t_s": t, "nodes": {str(i): {"pid": pids[i], "rss_mb": r, "age_s": age}
                                for i, r in enumerate(rss)}}


def test_verdict_exempts_fault_minutes_and_checks_rss_per_process_life():
    scores = {m: {0: {"mota": 0.95, "idf1": 0.9}, 1: {"mota": 0.95, "idf1": 0.9}} for m in range(5)}
    scores[2][1] = {"mota": 0.1, "idf1": 0.1}  # the killed node, minute 2: not a survivor
    scores[3][0] = {"mota": 0.5, "idf1": 0.5}  # the minute after: exempt
    ref = {m: {0: {"mota": 1.0, "idf1": 1.0}, 1: {"mota": 1.0, "idf1": 1.0}} for m in range(5)}
    kill = [Fault("kill", 130.0, 10.0, node=1)]
    samples = [_sample(0, [100, 100])] + [_sample(60 * (m + 1), [100, 104]) for m in range(5)]
    v = verdict(5, kill, scores, ref, samples, 0)
    assert [m["exempt"] for m in v["minutes"]] == [False, False, True, True, False]
    assert v["minutes"][2]["survivors"] == [0] and v["minutes"][2]["mota"] == 0.95
    assert v["minutes"][0]["ratio"] == pytest.approx(0.95)
    assert v["rss_drift_after_warmup"] == {"0": 0.0, "1": 0.0} and v["pass"]
    # a clean minute below 0.9 x the reference fails; so does RSS growing 11 % in one life
    low = {**scores, 4: {0: {"mota": 0.85, "idf1": 0.9}, 1: {"mota": 0.85, "idf1": 0.9}}}
    assert not verdict(5, kill, low, ref, samples, 0)["pass"]
    grow = samples[:-1] + [_sample(300, [111, 104])]
    g = verdict(5, kill, scores, ref, grow, 0)
    assert g["rss_drift_after_warmup"]["0"] == pytest.approx(0.11) and not g["pass"]
    # a restarted process (new pid) starts its own baseline once it is a minute old
    restarted = samples[:3] + [_sample(240, [100, 60], pids=(1, 3), age=30.0),
                               _sample(300, [100, 62], pids=(1, 3), age=90.0)]
    r = verdict(5, kill, scores, ref, restarted, 0)
    assert r["rss_drift_after_warmup"]["1"] == pytest.approx(0.0) and r["pass"]
    assert not verdict(5, kill, scores, ref, samples, 1)["pass"]  # an unplanned exit
    assert not verdict(5, kill, scores, None, samples, 0)["pass"]  # no reference, no verdict


@pytest.mark.integration
@pytest.mark.slow  # three 8 s minutes of a 3-node cluster, a kill and a restart
def test_a_short_soak_kills_restarts_and_its_clean_minute_equals_the_in_process_run(tmp_path):
    seed = next(s for s in range(50) if chaos_schedule(s, 3, 2, minute_s=8.0)[0].kind == "kill")
    report = soak(3, 2, tmp_path / "soak", chaos=seed, topology="chain", minute_s=8.0,
                  say=lambda _: None)
    kill = chaos_schedule(seed, 3, 2, minute_s=8.0)[0]
    kinds = [(e["kind"], e["node"]) for e in report["events"]]
    assert kinds == [("kill", kill.node), ("restart", kill.node)]
    assert report["unplanned"] == []
    pids = {s["nodes"][str(kill.node)]["pid"] for s in report["samples"]}
    assert len(pids) == 2  # the restarted node is a new process
    minutes = report["verdict"]["minutes"]
    assert [m["exempt"] for m in minutes] == [False, False, True]  # the kill is in minute 3
    for m in minutes[:2]:
        # no fault yet: the processes' tracks score what the same network scores in one
        # process (sync mode reproduces it exactly), so the ratio is 1 to the last digit
        assert m["mota"] is not None
        assert m["mota"] == pytest.approx(m["reference_mota"], abs=1e-12)
        assert m["idf1"] == pytest.approx(m["reference_idf1"], abs=1e-12)
    assert json.loads((tmp_path / "soak" / "soak.json").read_text())["chaos"] == seed
    assert (tmp_path / "soak" / "soak.png").stat().st_size > 10_000
    assert "kill" in "\n".join(summary_lines(report))
