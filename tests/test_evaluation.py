"""Metrics on hand-built cases whose values are counted by hand here."""
from __future__ import annotations

import json

import numpy as np
import pytest

from edge_node.core.types import Track
from edge_node.geometry import Camera
from sim_cluster.evaluation.metrics import (EvaluationError, evaluate, evaluate_ground,
                                            evaluate_image, iou_matrix, project_boxes, visible_box,
                                            visible_boxes)
from sim_cluster.scenarios.data import GroundTruth, ScenarioData

UPM = 30.0  # ground units per metre in these cases, to exercise the conversion
A, B = 1, 2
FRAMES = 4


def identity_camera(i: int) -> Camera:
    """G = I: a ground point (x, y) is the pixel (x, y) and a cylinder (cx, fy, w, h) frames the
    box (cx - w/2, fy - h, w, h): boxes are written down directly."""
    return Camera(id=i, image_size=(1000, 1000), G=np.eye(3))


def box_state(box: tuple[float, float, float, float]) -> np.ndarray:
    """The state whose cylinder projects to ``box`` in an identity camera."""
    x, y, w, h = box
    return np.array([x + w / 2, y + h, w, h, 0.0, 0.0])


BOX_A = (100.0, 100.0, 50.0, 100.0)
BOX_B = (400.0, 100.0, 50.0, 100.0)
XY_A = np.array([0.0, 0.0])  # metres
XY_B = np.array([5.0, 0.0])


def shifted(box, dx):
    return (box[0] + dx, box[1], box[2], box[3])


def scenario() -> ScenarioData:
    ids = [np.array([A, B])] * FRAMES
    xy = [np.stack([XY_A, XY_B]) * UPM] * FRAMES
    wh = [np.array([[15.0, 52.0], [15.0, 52.0]])] * FRAMES
    cam_boxes = [(np.array([A, B]), np.array([BOX_A, BOX_B]))] * FRAMES
    truth = GroundTruth(ids=ids, xy=xy, wh=wh, boxes=[list(cam_boxes) for _ in range(3)])
    return ScenarioData(name="hand", cameras=[identity_camera(i) for i in range(3)], frames=FRAMES,
                        fps=25.0, units_per_metre=UPM, detections=[[[] for _ in range(3)]] * FRAMES,
                        truth=truth)


def test_iou_matrix_by_hand():
    a = np.array([[0, 0, 10, 10]])
    b = np.array([[5, 0, 10, 10], [0, 0, 10, 10], [20, 20, 5, 5]])
    np.testing.assert_allclose(iou_matrix(a, b), [[50 / 150, 1.0, 0.0]])
    assert iou_matrix(np.zeros((0, 4)), b).shape == (0, 3)


def test_visible_box_filters_and_clips():
    cam = identity_camera(0)
    np.testing.assert_allclose(visible_box(cam, box_state((-20, 100, 50, 100))), [0, 100, 30, 100])
    assert visible_box(cam, box_state((-200, 100, 50, 100))) is None  # entirely left of the image
    assert visible_box(cam, box_state((100, 1000, 50, 100))) is None  # below the image


# EPFL Terrace c0's published homography: its third coordinate is negative for visible points.
TERRACE_C0 = np.array([[-1.6688907435, -6.950230571, 940.69592392565],
                       [1.1984806153, -10.749577832, 868.29873467315],
                       [0.000406921, -0.0209324057, 0.42949125235]])


def test_project_boxes_matches_cylinder_to_box():
    rng = np.random.default_rng(0)
    for scale in (1.0, 0.5):
        cam = Camera(id=0, image_size=(360, 288), G=TERRACE_C0, pixel_scale=scale)
        feet = rng.uniform([20, 120], [340, 280], (20, 2))
        cyl = np.hstack([cam.to_ground(feet), rng.uniform([10, 40], [40, 110], (20, 2))])
        np.testing.assert_allclose(project_boxes(cam, cyl),
                                   [cam.cylinder_to_box(c) for c in cyl], rtol=1e-9, atol=1e-9)


def test_visible_boxes_do_not_depend_on_the_homography_sign():
    """A homography's sign is arbitrary; Camera.in_front alone rejects every point of a camera
    published with the negative sign (EPFL Terrace c0, Campus c0/c1)."""
    a = Camera(id=0, image_size=(360, 288), G=TERRACE_C0)
    b = Camera(id=0, image_size=(360, 288), G=-TERRACE_C0)
    cyl = np.hstack([a.to_ground(np.array([[100.0, 200.0], [300.0, 150.0]])), [[30, 90], [30, 90]]])
    ba, oka = visible_boxes(a, cyl)
    bb, okb = visible_boxes(b, cyl)
    assert oka.all() and okb.all()
    np.testing.assert_allclose(ba, bb)


# --- image view ------------------------------------------------------------------------------------
def image_tracks_node1():
    """t1 follows A; B is tracked by t2, missed, then t3 (one switch); t9 is a false positive;
    t8 lies outside the image (ignored); at frame 3 t3 drifts below IoU 0.5 (FN + FP)."""
    fp_box = (700.0, 500.0, 50.0, 100.0)
    out_box = (-500.0, 100.0, 50.0, 100.0)
    return [
        [((1, 1), box_state(shifted(BOX_A, 0))), ((1, 2), box_state(shifted(BOX_B, 5)))],
        [((1, 1), box_state(shifted(BOX_A, 10))), ((1, 9), box_state(fp_box)),
         ((1, 8), box_state(out_box))],
        [((1, 1), box_state(shifted(BOX_A, 0))), ((1, 3), box_state(shifted(BOX_B, 0)))],
        [((1, 1), box_state(shifted(BOX_A, 5))), ((1, 3), box_state(shifted(BOX_B, 20)))],
    ]


def perfect_tracks(node: int):
    """Track objects (core.types.Track) following A and B exactly."""
    return [[Track(id=(node, 1), frame=k, x=box_state(BOX_A), P=np.eye(6), observed=True, ell=0),
             Track(id=(node, 2), frame=k, x=box_state(BOX_B), P=np.eye(6), observed=True, ell=0)]
            for k in range(FRAMES)]


def test_image_view_by_hand():
    tracks = {0: perfect_tracks(0), 1: image_tracks_node1(), 2: [[] for _ in range(FRAMES)]}
    res = evaluate_image(tracks, scenario())
    n1 = res["per_node"]["1"]
    gt, fn, fp, idsw = 8, 2, 2, 1
    assert (n1["num_objects"], n1["num_misses"], n1["num_false_positives"], n1["num_switches"]) == (
        gt, fn, fp, idsw)
    assert n1["num_predictions"] == 8  # t1 x4, t2, t9, t3 x2; t8 is outside the image
    assert n1["mota"] == pytest.approx(1 - (fn + fp + idsw) / gt)
    ious = [1.0, 45 / 55, 40 / 60, 1.0, 1.0, 45 / 55]  # IoU of a 50-px box shifted by dx: (50-dx)/(50+dx)
    assert n1["num_matches"] + n1["num_switches"] == len(ious)
    assert n1["motp"] == pytest.approx(np.mean(ious))
    idtp = 4 + 1  # A<->t1 four frames; B<->t2 or B<->t3 one frame each within IoU 0.5
    assert n1["idp"] == pytest.approx(idtp / 8)
    assert n1["idr"] == pytest.approx(idtp / gt)
    assert n1["idf1"] == pytest.approx(2 * idtp / (gt + 8))

    n0, n2 = res["per_node"]["0"], res["per_node"]["2"]
    assert n0["mota"] == 1.0 and n0["idf1"] == 1.0 and n0["motp"] == pytest.approx(1.0)
    assert n2["mota"] == 0.0 and n2["num_misses"] == 8 and n2["motp"] is None and n2["idp"] is None

    med = res["median"]
    assert med["mota"] == pytest.approx(np.median([1.0, 1 - 5 / 8, 0.0]))
    assert med["motp"] == pytest.approx((1.0 + np.mean(ious)) / 2)  # node 2 has no matches
    assert med["num_misses"] == 2


# --- ground view -----------------------------------------------------------------------------------
def ground_tracks():
    """Distances in metres to the matched person; t9 a far false positive at frames 1 and 3."""
    def at(p, off):
        return np.array([*(p + np.asarray(off)) * UPM, 15.0, 52.0, 0.0, 0.0])
    far = np.array([20.0, 20.0])
    return [
        [((0, 1), at(XY_A, (0.3, 0))), ((0, 2), at(XY_B, (0, 0.4)))],
        [((0, 1), at(XY_A, (0.3, 0.4))), ((0, 9), at(far, (0, 0)))],
        [((0, 1), at(XY_A, (0, 0.2))), ((0, 3), at(XY_B, (0.1, 0)))],
        [((0, 1), at(XY_A, (0, 0))), ((0, 3), at(XY_B, (0, -0.6))), ((0, 9), at(far, (0, 0)))],
    ]


def test_ground_view_by_hand():
    res = evaluate_ground({0: ground_tracks()}, scenario(), threshold_m=1.0)
    g = res["per_node"]["0"]
    gt, fn, fp, idsw, npred = 8, 1, 2, 1, 9
    assert (g["num_objects"], g["num_misses"], g["num_false_positives"], g["num_switches"],
            g["num_predictions"]) == (gt, fn, fp, idsw, npred)
    assert g["mota"] == pytest.approx(1 - (fn + fp + idsw) / gt)
    assert g["motp_m"] == pytest.approx(np.mean([0.3, 0.4, 0.5, 0.2, 0.1, 0.0, 0.6]))
    idtp = 4 + 2  # A<->t1, B<->t3
    assert g["idp"] == pytest.approx(idtp / npred)
    assert g["idr"] == pytest.approx(idtp / gt)
    assert g["idf1"] == pytest.approx(2 * idtp / (gt + npred))
    assert "motp" not in g
    # A tighter threshold (0.45 m) turns the 0.5 m and 0.6 m matches into FN + FP.
    t = evaluate_ground({0: ground_tracks()}, scenario(), threshold_m=0.45)["per_node"]["0"]
    assert (t["num_misses"], t["num_false_positives"]) == (3, 4)


def test_evaluate_is_json_and_median_over_three_nodes():
    tracks = {0: perfect_tracks(0), 1: image_tracks_node1(), 2: [[] for _ in range(FRAMES)]}
    res = evaluate(tracks, scenario())
    json.dumps(res, allow_nan=False)
    assert set(res) >= {"image", "ground", "ground_threshold_m"}
    assert res["ground_threshold_m"] == 1.0 and res["frames"] == FRAMES
    assert set(res["image"]["per_node"]) == {"0", "1", "2"}
    assert set(res["ground"]["per_node"]) == {"0", "1", "2"}


def test_bad_node_is_an_error():
    with pytest.raises(EvaluationError, match="node 5"):
        evaluate_image({5: [[]]}, scenario())
    with pytest.raises(EvaluationError, match="track entry"):
        evaluate_ground({0: [[42]]}, scenario())


def test_start_frame_evaluates_only_the_later_frames():
    """Frames before ``start`` are neither misses nor false positives."""
    import numpy as np
    from types import SimpleNamespace
    from sim_cluster.evaluation.metrics import evaluate_ground

    xy = [np.array([[0.0, 0.0]])] * 4
    truth = SimpleNamespace(ids=[np.array([1])] * 4, xy=xy, wh=[np.array([[0.5, 1.7]])] * 4,
                            boxes=[])
    scen = SimpleNamespace(truth=truth, units_per_metre=1.0, num_cameras=1, frames=4)
    tracks = {0: [[], [], [((0, 0), np.array([0.1, 0, 0.5, 1.7, 0, 0]))],
                  [((0, 0), np.array([0.1, 0, 0.5, 1.7, 0, 0]))]]}
    full = evaluate_ground(tracks, scen, frames=4)["per_node"]["0"]
    late = evaluate_ground(tracks, scen, frames=4, start=2)["per_node"]["0"]
    assert full["mota"] == 0.5 and full["num_misses"] == 2  # 2 of 4 frames missed by hand
    assert late["mota"] == 1.0 and late["num_objects"] == 2 and late["num_misses"] == 0


def test_latency_line_names_nodes_without_samples():
    """A node with no neighbour has ``latency.median_ms`` None (``latency_summary([])``)."""
    from edge_node.runtime.output import latency_summary
    from sim_cluster.evaluation.report import latency_line

    def summary(*samples):
        return {"processes": {str(i): {"latency": latency_summary(s)}
                              for i, s in enumerate(samples)}}

    assert latency_line(summary([0.001], [0.002, 0.004])) == \
        "one-hop latency: median of node medians 2.00 ms"
    assert latency_line(summary([0.001], [], [0.003])) == \
        "one-hop latency: median of node medians 2.00 ms (no samples: node 1)"
    assert latency_line(summary([], [])) == "one-hop latency: - (no samples: nodes 0, 1)"
    assert latency_line({"processes": {"0": {"latency": None}}}) == \
        "one-hop latency: - (no samples: node 0)"


# --- identity counts -------------------------------------------------------------------------------
def test_identity_counts_by_hand():
    """Three people over 10 frames, one node, counted by hand (standard MOT definitions):

    A (frames 0-9): t1 at 0-3, missed at 4-5, t2 at 6-9: tracked 8/10 = 0.8 -> mostly tracked;
      one fragmentation (4); ids {t1, t2}.
    B (frames 0-9): t3 at 2-3 and 7: tracked 3/10 -> partially tracked; one fragmentation (4; the
      miss at 8 is after its last tracked frame, not an interruption); ids {t3}.
    C (frames 5-9): never tracked -> mostly lost.
    t9: a false positive far from everyone at frames 0-1.
    Track ids reported: t1, t2, t3, t9 = 4; ids per person matched: (2 + 1) / 2 = 1.5.
    """
    from types import SimpleNamespace

    P, Q, R = 1, 2, 3
    where = {P: np.array([0.0, 0.0]), Q: np.array([10.0, 0.0]), R: np.array([20.0, 0.0])}
    ids = [np.array([P, Q] + ([R] if k >= 5 else [])) for k in range(10)]
    truth = SimpleNamespace(ids=ids, xy=[np.stack([where[i] for i in f]) for f in ids],
                            wh=[np.full((len(f), 2), 1.0) for f in ids], boxes=[])
    scen = SimpleNamespace(truth=truth, units_per_metre=1.0, num_cameras=1, frames=10)

    def at(p):
        return np.array([*(where[p] + [0.1, 0.0]), 0.5, 1.7, 0.0, 0.0])

    owner = {"t1": (P, range(0, 4)), "t2": (P, range(6, 10)), "t3": (Q, (2, 3, 7))}
    frames = [[(t, at(p)) for t, (p, ks) in owner.items() if k in ks] for k in range(10)]
    for k in (0, 1):
        frames[k].append(("t9", np.array([50.0, 50.0, 0.5, 1.7, 0.0, 0.0])))
    g = evaluate_ground({0: frames}, scen, frames=10)["per_node"]["0"]
    assert g["num_unique_objects"] == 3
    assert (g["mostly_tracked"], g["partially_tracked"], g["mostly_lost"]) == (1, 1, 1)
    assert g["num_fragmentations"] == 2
    assert g["num_track_ids"] == 4
    assert g["ids_per_person"] == pytest.approx(1.5)
    assert g["num_switches"] == 1  # A: t1 -> t2


def test_fragmentations_agree_with_motmetrics():
    """``fragmentations`` is motmetrics' ``num_fragmentations`` without its per-person loop."""
    import motmetrics as mm
    from motmetrics.metrics import events_to_df_map, num_fragmentations

    from sim_cluster.evaluation.metrics import fragmentations

    rng = np.random.default_rng(1)
    for _ in range(20):
        people, hyps = int(rng.integers(1, 10)), int(rng.integers(0, 10))
        acc = mm.MOTAccumulator(auto_id=False)
        for k in range(int(rng.integers(1, 50))):
            o = [i for i in range(people) if rng.random() < 0.7]
            h = list(range(int(rng.integers(0, hyps + 1))))
            d = np.where(rng.random((len(o), len(h))) < 0.5, rng.random((len(o), len(h))), np.nan)
            acc.update(o, h, d, frameid=k)
        df = events_to_df_map(acc.mot_events)
        assert fragmentations(acc) == num_fragmentations(df, df.noraw.OId.value_counts())
