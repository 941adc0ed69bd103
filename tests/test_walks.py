"""The scale benchmark's metrics: ids kept along long walks on a hand-made case, and the
frame-by-frame ground evaluation against the whole-run one."""
from __future__ import annotations

import json

import numpy as np
import pytest

from edge_node.core.config import TrackerConfig
from sim_cluster.cli import main
from sim_cluster.evaluation.metrics import evaluate_ground
from sim_cluster.evaluation.online import OnlineGround
from sim_cluster.evaluation.walks import WalkLog, walk_ids
from sim_cluster.experiments.bench_scale import size_ratios
from sim_cluster.network import topology
from sim_cluster.network.inprocess import run_network
from sim_cluster.scenarios.data import Frame
from sim_cluster.scenarios.loader import load_scenario


def _frame(ids, per_camera):
    return Frame(detections=[], detection_truth=[], ids=np.array(ids), xy=np.zeros((len(ids), 2)),
                 wh=np.zeros((len(ids), 2)),
                 boxes=[(np.array(c), np.zeros((len(c), 4))) for c in per_camera])


def test_walk_ids_on_a_hand_made_case():
    """Person 1 walks 10 frames across cameras 0-3: matched to track a in 6, to b in 2,
    missed in 2 -> id kept 6/10, 2 ids. Person 2 walks 5 frames across cameras 0-4, track c
    all along -> 5/5, 1 id. Person 3 crosses 2 cameras only: not a long walker, however it
    is matched. Together: (6 + 5) / (10 + 5) kept, 1.5 ids per walk."""
    log = WalkLog()
    for _ in range(5):  # cameras 0-4: person 1 in 0-3, person 2 in 0-4, person 3 in 0-1
        log.observe(_frame([1, 2, 3], [[1, 2, 3], [1, 2, 3], [1, 2], [1, 2], [2]]))
    for _ in range(5):  # person 1 alone
        log.observe(_frame([1], [[1], [1], [1], [1], []]))
    assert log.frames == {1: 10, 2: 5, 3: 5}
    assert log.long_walkers(4) == {1, 2}
    matches = [(1, "a")] * 6 + [(1, "b")] * 2 + [(2, "c")] * 5 + [(3, "x"), (3, "y")]
    got = walk_ids(matches, log.frames, log.long_walkers(4))
    assert got == {"walkers": 2, "id_kept": pytest.approx(11 / 15), "ids_per_walk": 1.5}
    alone = walk_ids(matches, log.frames, {1})
    assert alone["id_kept"] == pytest.approx(0.6) and alone["ids_per_walk"] == 2
    assert walk_ids(matches, log.frames, set())["id_kept"] is None


def test_online_ground_equals_the_whole_run_evaluation():
    data = load_scenario("terrace-sim", frames=60)
    run = run_network(data, topology.build("ring", 4), TrackerConfig())
    online = OnlineGround(data.units_per_metre, 1.0)
    for node, frames in run.tracks.items():
        for k, ts in enumerate(frames):
            online.add(node, k, ts, data.frame(k))
    assert online.summary() == evaluate_ground(run.tracks, data, 1.0)
    assert sum(1 for _ in online.matches(0)) == \
        online.summary()["per_node"]["0"]["num_matches"] + \
        online.summary()["per_node"]["0"]["num_switches"]


def test_scale_sweep_writes_its_table(tmp_path, capsys):
    assert main(["bench", "--cameras", "4", "--frames", "20", "--out", str(tmp_path),
                 "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "cameras" in out and "wrote" in out
    row = json.loads((tmp_path / "scale.json").read_text())["rows"][0]
    assert row["cameras"] == 4 and row["frames"] == 20 and row["trackers_max"] >= 1
    assert row["bytes_per_node_frame"] > 0 and 0 < row["cpu_ms_median"]
    assert set(row["per_node"]["ground"]) == {"0", "1", "2", "3"}
    assert (tmp_path / "scale.csv").read_text().startswith("cameras,scope,frames,")
    assert (tmp_path / "scale.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_size_ratio_is_each_scopes_cpu_at_the_largest_size_over_the_smallest():
    rows = [{"cameras": c, "scope": h, "cpu_ms_median": ms}
            for c, h, ms in ((4, 0, 1.6), (16, 0, 4.0), (64, 0, 6.4), (4, 1, 1.5), (64, 1, 1.8),
                             (16, 2, 2.0))]
    got = size_ratios(rows)
    assert set(got) == {0, 1}  # scope 2 ran at one size: no ratio
    assert got[0] == pytest.approx(4.0) and got[1] == pytest.approx(1.2)
