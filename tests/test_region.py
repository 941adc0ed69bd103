"""The regional ground evaluation (a node scored inside its neighbourhood's views only) on a
hand-made case whose numbers are derived by hand, and the scale sweep's --scope rows."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from edge_node.geometry import Camera
from sim_cluster.cli import main
from sim_cluster.evaluation.metrics import EvaluationError
from sim_cluster.evaluation.online import OnlineGround
from sim_cluster.evaluation.region import RegionalGround, Regions, sees
from sim_cluster.network.topology import lattice
from sim_cluster.scenarios.data import Frame
from sim_cluster.scenarios.synthetic.layout import LayoutParams, layout_cameras


def _strip_camera(i: int) -> Camera:
    """A 100 x 100 px image that sees exactly the ground [10 i, 10 i + 10] x [0, 10] m."""
    return Camera(i, (100, 100), np.array([[0.1, 0.0, 10.0 * i], [0.0, 0.1, 0.0], [0, 0, 1]]))


def _truth(people: dict[int, tuple[float, float]]) -> Frame:
    return Frame(detections=[], detection_truth=[], ids=np.array(list(people)),
                 xy=np.array(list(people.values()), float).reshape(-1, 2),
                 wh=np.zeros((len(people), 2)), boxes=[])


def _tracks(places: dict[str, tuple[float, float]]) -> list:
    return [SimpleNamespace(id=t, x=np.array([*xy, 0.0, 0.0])) for t, xy in places.items()]


def test_sees_the_image_in_front_of_the_camera():
    cam = _strip_camera(1)
    assert sees(cam, np.array([[10.0, 0.0], [15, 5], [20, 10], [9.9, 5], [15, 10.1]])).tolist() \
        == [True, True, True, False, False]
    real = layout_cameras(LayoutParams(kind="corridor", cameras=1))[0]  # at (4, -1), facing +y
    assert sees(real, np.array([[4.0, 4.0], [4.0, -20.0], [4.0, 40.0]])).tolist() \
        == [True, False, False]  # its cell's centre; behind it; beyond the image's top


def test_regional_score_on_a_hand_made_case():
    """Cameras 0, 1, 2 see the strips x in [0, 10], [10, 20], [20, 30] m (y in [0, 10]), on
    the chain 0 - 1 - 2: node 0's region is x in [0, 20], node 1's is all three strips.

    Two frames. People: p1 at (5, 5) and p2 at (15, 5) inside node 0's region, p3 at (25, 5)
    outside it. Tracks: a at (5.2, 5) on p1 in both frames; c at (12, 9), near nobody, inside,
    in frame 0 only; d at (28, 2), near nobody, outside, in both frames.

    Regional, node 0 (p3 and d ignored): 4 truths (p1, p2 x 2), 2 matches (p1 - a), 2 misses
    (p2, inside, never tracked), 1 false positive (c); MOTA = 1 - (2 + 1) / 4 = 0.25, IDF1 =
    2 IDTP / (2 IDTP + 2 IDFN + 1 IDFP) = 4 / 7.
    Global, node 0: 6 truths, 2 matches, 4 misses (p2, p3 x 2), 3 false positives (c, d x 2);
    MOTA = 1 - 7 / 6 = -1/6, IDF1 = 4 / (4 + 4 + 3) = 4 / 11.
    Node 1's region holds everything: its regional score is its global one."""
    regions = Regions([_strip_camera(i) for i in range(3)], lattice(1, 3))
    regional, whole = RegionalGround(regions, 1.0, 1.0), OnlineGround(1.0, 1.0)
    people = _truth({1: (5, 5), 2: (15, 5), 3: (25, 5)})
    frames = [_tracks({"a": (5.2, 5), "c": (12, 9), "d": (28, 2)}),
              _tracks({"a": (5.2, 5), "d": (28, 2)})]
    for k, tracks in enumerate(frames):
        for node in (0, 1):
            regional.add(node, k, tracks, people)
            whole.add(node, k, tracks, people)
    reg, glob = regional.summary()["per_node"], whole.summary()["per_node"]
    assert (reg["0"]["num_objects"], reg["0"]["num_matches"], reg["0"]["num_misses"],
            reg["0"]["num_false_positives"]) == (4, 2, 2, 1)
    assert reg["0"]["mota"] == pytest.approx(0.25) and reg["0"]["idf1"] == pytest.approx(4 / 7)
    assert (glob["0"]["num_objects"], glob["0"]["num_misses"],
            glob["0"]["num_false_positives"]) == (6, 4, 3)
    assert glob["0"]["mota"] == pytest.approx(-1 / 6) and glob["0"]["idf1"] == pytest.approx(4 / 11)
    assert reg["1"] == glob["1"]
    assert regional.walk_frames[0] == {1: 2, 2: 2}  # p3 never in node 0's region
    assert regional.walk_frames[1] == {1: 2, 2: 2, 3: 2}


def test_a_region_names_cameras_the_scenario_has():
    with pytest.raises(EvaluationError, match="cameras"):
        Regions([_strip_camera(0)], lattice(1, 2))
    with pytest.raises(EvaluationError, match="no region"):
        Regions([_strip_camera(0)], lattice(1, 1)).contains(5, np.zeros((1, 2)))


def test_scale_sweep_one_row_per_cameras_and_scope(tmp_path, capsys):
    assert main(["bench", "--cameras", "4", "--scope", "0,1", "--frames", "20",
                 "--out", str(tmp_path), "--quiet"]) == 0
    rows = json.loads((tmp_path / "scale.json").read_text())["rows"]
    assert [(r["cameras"], r["scope"]) for r in rows] == [(4, 0), (4, 1)]
    for r in rows:
        assert -1 <= r["mota_region"] <= 1 and 0 <= r["idf1_region"] <= 1
        assert set(r["per_node"]["ground_region"]) == {"0", "1", "2", "3"}
    assert rows[1]["trackers_median"] <= rows[0]["trackers_median"]
    assert (tmp_path / "scale.csv").read_text().startswith("cameras,scope,frames,")
