"""The synthetic world and its scenario files: determinism, validation, geometry, detector."""
from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest

from fakes import homography_scene
from sim_cluster.scenarios.data import ScenarioData
from sim_cluster.scenarios.files import (ScenarioError, list_presets, read_scenario_toml,
                                         resolve_scenario_path)
from sim_cluster.scenarios.loader import SCENARIO_KINDS, load_scenario
from sim_cluster.scenarios.synthetic.appearance import AppearanceModel
from sim_cluster.scenarios.synthetic.detector_model import DetectorParams, detect, in_image_fraction
from sim_cluster.scenarios.synthetic.schema import camera_from_pose, parse_synthetic
from sim_cluster.scenarios.synthetic.world import (WorldConfig, generate, project_people,
                                                   simulate_people, visible_fractions)

SIMS = ("terrace-sim", "lab-sim", "campus-sim")


def _config(name: str, seed: int = 0, frames: int | None = None) -> WorldConfig:
    path = resolve_scenario_path(name)
    return parse_synthetic(read_scenario_toml(path), path, seed, frames)


@functools.lru_cache(maxsize=None)
def _preset(name: str) -> ScenarioData:
    return load_scenario(name)


def _flat(s: ScenarioData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    boxes = np.array([d.box for k in range(s.frames) for c in range(s.num_cameras)
                      for d in s.detections[k][c]])
    desc = np.array([d.descriptor[:8] for k in range(s.frames) for c in range(s.num_cameras)
                     for d in s.detections[k][c]])
    truth = np.concatenate([s.detection_truth[k][c] for k in range(s.frames)
                            for c in range(s.num_cameras)])
    return boxes, desc, truth


def _rates(s: ScenarioData) -> tuple[np.ndarray, np.ndarray]:
    """Per camera: share of ground-truth boxes detected, false positives per frame."""
    rate, fp = [], []
    for c in range(s.num_cameras):
        gt = hit = n_fp = 0
        for k in range(s.frames):
            ids = s.truth.boxes[c][k][0]
            t = s.detection_truth[k][c]
            gt += len(ids)
            hit += int(np.isin(ids, t).sum())
            n_fp += int((t < 0).sum())
        rate.append(hit / gt)
        fp.append(n_fp / s.frames)
    return np.array(rate), np.array(fp)


# -- determinism --------------------------------------------------------------------------------


def test_same_seed_same_scenario_and_other_seed_other_scenario():
    a = load_scenario("terrace-sim", seed=3, frames=120)
    b = load_scenario("terrace-sim", seed=3, frames=120)
    c = load_scenario("terrace-sim", seed=4, frames=120)
    assert a.frames == b.frames == 120 and a.seed == 3
    for x, y in zip(_flat(a), _flat(b)):
        np.testing.assert_array_equal(x, y)
    for k in range(a.frames):
        np.testing.assert_array_equal(a.truth.xy[k], b.truth.xy[k])
        for cam in range(a.num_cameras):
            np.testing.assert_array_equal(a.truth.boxes[cam][k][1], b.truth.boxes[cam][k][1])
    assert not np.allclose(a.truth.xy[0][:3], c.truth.xy[0][:3])
    assert len(_flat(a)[0]) != len(_flat(c)[0]) or not np.allclose(_flat(a)[0], _flat(c)[0])


def test_detector_parameters_do_not_move_other_random_streams():
    cfg = _config("lab-sim", frames=100)
    base = generate(cfg)
    no_fp = generate(dataclasses.replace(
        cfg, detector=dataclasses.replace(cfg.detector, false_positives_per_frame=0.0)))
    more_miss = generate(dataclasses.replace(
        cfg, detector=dataclasses.replace(cfg.detector, miss_rate=0.3)))
    bb, bd, bt = _flat(base)
    nb, nd, nt = _flat(no_fp)
    tp = bt >= 0
    assert np.all(nt >= 0) and tp.sum() == len(nt) and (~tp).sum() > 0
    np.testing.assert_array_equal(bb[tp], nb)  # same true detections, same noise
    np.testing.assert_array_equal(bd[tp], nd)
    # A higher miss rate only removes detections; survivors keep their boxes and descriptors.
    for k in range(base.frames):
        for c in range(base.num_cameras):
            kept = {int(t): d for t, d in zip(more_miss.detection_truth[k][c],
                                              more_miss.detections[k][c]) if t >= 0}
            ref = {int(t): d for t, d in zip(base.detection_truth[k][c], base.detections[k][c])
                   if t >= 0}
            assert set(kept) <= set(ref)
            for t, d in kept.items():
                np.testing.assert_array_equal(d.box, ref[t].box)
                np.testing.assert_array_equal(d.descriptor, ref[t].descriptor)
    # The people do not move when the detector changes.
    for k in range(base.frames):
        np.testing.assert_array_equal(base.truth.xy[k], more_miss.truth.xy[k])


# -- scenario files -----------------------------------------------------------------------------


def test_presets_are_listed_and_resolvable():
    assert set(SIMS) <= set(list_presets())
    assert "synthetic" in SCENARIO_KINDS
    with pytest.raises(ScenarioError, match=r"^no-such-preset: unknown scenario preset"):
        load_scenario("no-such-preset")
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load_scenario("/nonexistent/dir/scene.toml")


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("fov_deg = 64.0", "fov_deg = 200",
         "my-scene.toml: cameras[2].fov_deg must be in (0, 180), got 200"),
        ("miss_rate = 0.1", "miss_rate = 1.5",
         "my-scene.toml: detector.miss_rate must be in [0, 1], got 1.5"),
        ("fov_deg = 60.0\n", "focal_px = 300.0\nfov_deg = 60.0\n",
         "my-scene.toml: cameras[1]: needs exactly one of fov_deg and focal_px"),
        ("speed_mps = [0.7, 1.5]", "speed_mps = [1.5, 0.7]",
         "my-scene.toml: people.speed_mps must have lo <= hi"),
        ("turn_rate_dps = 180.0", "turn_rat_dps = 180.0",
         "my-scene.toml: people.turn_rat_dps is not a known field"),
        ("position = [11.0, 11.0, 2.8]", "position = [11.0, 11.0]",
         "my-scene.toml: cameras[2].position must be a list of 3 numbers"),
        ("position = [11.0, 11.0, 2.8]", "position = [11.0, 11.0, -2.0]",
         "my-scene.toml: cameras[2].position height (z) must be > 0"),
        ("xmax = 10.0", "xmax = -1.0", "my-scene.toml: area.xmax must be > xmin"),
        ('kind = "synthetic"', 'kind = "bogus"', "my-scene.toml: source.kind must be one of"),
        ("frames = 600 ", "frames = 0 ", "my-scene.toml: frames must be >= 1, got 0"),
        ("[area]", "[area", "my-scene.toml: invalid TOML"),
        ("fov_deg = 62.0", 'fov_deg = "wide"', "my-scene.toml: cameras[0].fov_deg must be a number"),
        ("box_noise_px = 2.0", "box_noise_px = -1", "my-scene.toml: detector.box_noise_px must be >= 0"),
    ],
)
def test_validation_errors_name_file_and_field(tmp_path: Path, old: str, new: str, message: str):
    text = resolve_scenario_path("terrace-sim").read_text()
    assert old in text
    bad = tmp_path / "my-scene.toml"
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(ScenarioError) as err:
        load_scenario(str(bad), frames=5)
    assert str(err.value).startswith(message)
    assert isinstance(err.value, ValueError) and err.value.file == "my-scene.toml"


def test_seed_and_frames_arguments_are_validated():
    with pytest.raises(ScenarioError, match="terrace-sim.toml: seed must be an integer >= 0"):
        load_scenario("terrace-sim", seed=-1)
    with pytest.raises(ScenarioError, match="terrace-sim.toml: frames must be an integer >= 1"):
        load_scenario("terrace-sim", frames=0)


def test_a_homography_only_camera_works(tmp_path: Path):
    cam = _config("terrace-sim").cameras[0]
    text = homography_scene(cam.G, frames=40, people=5)
    path = tmp_path / "flat.toml"
    path.write_text(text)
    s = load_scenario(str(path))
    assert s.num_cameras == 1 and s.cameras[0].P is None and s.name == "flat"
    n_gt = 0
    for k in range(s.frames):
        ids, boxes = s.truth.boxes[0][k]
        for pid, box in zip(ids, boxes):
            j = int(np.flatnonzero(s.truth.ids[k] == pid)[0])
            np.testing.assert_allclose(s.cameras[0].box_to_cylinder(box)[:2], s.truth.xy[k][j], atol=1e-6)
            n_gt += 1
    assert n_gt > 40


# -- geometry -----------------------------------------------------------------------------------


def test_camera_from_pose_is_consistent():
    cam = camera_from_pose(0, (360, 288), np.array([-1.0, -2.0, 3.0]), 30.0, 20.0, fov_deg=60.0)
    np.testing.assert_allclose(cam.center(), [-1.0, -2.0, 3.0], atol=1e-9)
    pts = np.array([[3.0, 1.0], [6.0, 4.0], [2.0, 5.0]])
    q = np.hstack([pts, np.zeros((3, 1)), np.ones((3, 1))]) @ cam.P.T
    np.testing.assert_allclose(cam.to_image(pts), q[:, :2] / q[:, 2:], atol=1e-9)
    np.testing.assert_allclose(cam.to_ground(cam.to_image(pts)), pts, atol=1e-9)
    # The optical axis hits the principal point; 60 deg horizontal fov -> f = 180 / tan 30.
    axis = np.array([-1.0, -2.0, 3.0]) + 5.0 * np.array(
        [np.cos(np.radians(20)) * np.cos(np.radians(30)), np.cos(np.radians(20)) * np.sin(np.radians(30)),
         -np.sin(np.radians(20))])
    q = cam.P @ np.append(axis, 1.0)
    np.testing.assert_allclose(q[:2] / q[2], [180.0, 144.0], atol=1e-9)
    assert cam.P[0, :3] @ cam.P[0, :3] > 0 and abs(cam.P[2, :3] @ cam.P[2, :3] - 1.0) < 1e-12


def test_ground_truth_boxes_stand_on_the_ground_positions():
    s = load_scenario("lab-sim", frames=60)
    worst, n, dh = 0.0, 0, []
    for c, cam in enumerate(s.cameras):
        for k in range(s.frames):
            ids, boxes = s.truth.boxes[c][k]
            assert np.all(np.isin(ids, s.truth.ids[k]))
            for pid, box in zip(ids, boxes):
                j = int(np.flatnonzero(s.truth.ids[k] == pid)[0])
                cyl = cam.box_to_cylinder(box)
                worst = max(worst, float(np.abs(cyl[:2] - s.truth.xy[k][j]).max()))
                dh.append(cyl[3] - s.truth.wh[k][j, 1])
                n += 1
    assert n > 500 and worst < 1e-6
    # Heights from the box top: the silhouette's top is the far rim of the head circle, so the
    # recovered height is a little too tall, more so for steep close views.
    assert 0.0 < np.median(dh) < 0.1 and np.max(np.abs(dh)) < 0.4


def test_projected_boxes_have_the_silhouette_width_and_top():
    cam = _config("terrace-sim").cameras[1]
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 10, (50, 2))
    wh = np.column_stack([rng.uniform(0.4, 0.6, 50), rng.uniform(1.5, 1.9, 50)])
    boxes, front = project_people(cam, xy, wh)
    assert front.all()
    ref = np.array([cam.cylinder_to_box(np.r_[p, s]) for p, s in zip(xy, wh)])
    np.testing.assert_allclose(boxes[:, [1, 2]], ref[:, [1, 2]], atol=1e-9)
    # Re-anchoring lifts the bottom edge from the base rim's nearest point to the base centre:
    # the projected radius, a few pixels, at most a sixth of the box for people > 3 m away.
    far = np.hypot(*(xy - cam.center()[:2]).T) > 3.0
    lift = (ref[:, 1] + ref[:, 3]) - (boxes[:, 1] + boxes[:, 3])
    assert np.all(lift > 0) and np.median(lift) < 5.0
    assert np.all(lift[far] < boxes[far, 3] / 6.0)
    np.testing.assert_allclose(boxes[:, 0] + boxes[:, 2] / 2, cam.to_image(xy)[:, 0], atol=1e-9)


# -- occlusion and the detector -----------------------------------------------------------------


def test_visible_fraction_of_half_covered_box_is_one_half():
    boxes = np.array([[0.0, 0.0, 10.0, 20.0], [5.0, 0.0, 10.0, 20.0], [50.0, 50.0, 10.0, 20.0]])
    vis = visible_fractions(boxes, np.array([1.0, 2.0, 0.5]), (100, 100))
    np.testing.assert_allclose(vis, [1.0, 0.5, 1.0])
    # Half outside the image: in-image fraction 0.5, the in-image part is unoccluded.
    out = np.array([[-5.0, 0.0, 10.0, 20.0]])
    assert in_image_fraction(out, (100, 100))[0] == pytest.approx(0.5)
    assert visible_fractions(out, np.array([1.0]), (100, 100))[0] == 1.0
    assert visible_fractions(np.array([[200.0, 0.0, 10.0, 20.0]]), np.array([1.0]), (100, 100))[0] == 0.0


def test_a_person_behind_another_is_occluded_and_missed():
    cam = camera_from_pose(0, (360, 288), np.array([0.0, 0.0, 2.0]), 0.0, 10.0, fov_deg=60.0)
    xy = np.array([[4.0, 0.0], [7.0, 0.0], [5.0, 2.5]])  # #2 right behind #1; #3 aside
    wh = np.array([[0.5, 1.75], [0.5, 1.75], [0.5, 1.75]])
    boxes, front = project_people(cam, xy, wh)
    assert front.all()
    depth = np.hypot(xy[:, 0], xy[:, 1])
    vis = visible_fractions(boxes, depth, cam.image_size)
    assert vis[0] == 1.0 and vis[2] == 1.0
    assert 0.0 < vis[1] < 0.5  # only the head shows over the nearer person's
    params = DetectorParams(miss_rate=0.0, false_positives_per_frame=0.0, box_noise_px=0.0)
    dets, ids = detect(cam, np.array([1, 2, 3]), boxes, vis, params, AppearanceModel(seed=0),
                       np.random.default_rng(0))
    assert ids.tolist() == [1, 3]
    np.testing.assert_allclose(dets[0].box, boxes[0], atol=1e-9)
    # Seen from the side, nobody hides anybody and all three are detected.
    side = camera_from_pose(1, (360, 288), np.array([5.5, -6.0, 2.0]), 90.0, 10.0, fov_deg=70.0)
    b2, _ = project_people(side, xy, wh)
    v2 = visible_fractions(b2, np.hypot(xy[:, 0] - 5.5, xy[:, 1] + 6.0), side.image_size)
    _, ids2 = detect(side, np.array([1, 2, 3]), b2, v2, params, AppearanceModel(seed=0),
                     np.random.default_rng(0))
    assert sorted(ids2.tolist()) == [1, 2, 3]


def test_detection_rate_is_one_minus_miss_rate_without_occlusion_misses():
    cfg = _config("terrace-sim", frames=300)
    det = dataclasses.replace(cfg.detector, occlusion_miss_threshold=0.0, min_box_height_px=0.0,
                              false_positives_per_frame=0.0)
    s = generate(dataclasses.replace(cfg, detector=det))
    rate, fp = _rates(s)
    assert np.all(np.abs(rate - 0.9) < 0.025)
    assert np.all(fp == 0.0)


def test_false_positives_are_person_sized_and_inside_the_image():
    s = _preset("terrace-sim")
    n = 0
    for k in range(s.frames):
        for c, cam in enumerate(s.cameras):
            for d, t in zip(s.detections[k][c], s.detection_truth[k][c]):
                if t < 0:
                    x, y, w, h = d.box
                    W, H = cam.image_size
                    assert 0 <= x and 0 <= y and x + w <= W + 1e-9 and y + h <= H + 1e-9
                    assert 1.0 <= h <= H and w < h
                    n += 1
    assert n > 300


# -- people -------------------------------------------------------------------------------------


def test_people_walk_at_their_speed_and_do_not_overlap():
    cfg = _config("terrace-sim")
    traj = simulate_people(cfg.area, cfg.fps, 400, cfg.people, np.random.default_rng(1))
    step = np.hypot(*np.moveaxis(np.diff(traj.xy, axis=0), -1, 0)) * cfg.fps
    assert np.nanmax(step) <= cfg.people.speed_mps[1] + 1e-9
    assert np.nanmean(step) > 0.5 * cfg.people.speed_mps[0]
    for k in range(0, 400, 4):
        here = traj.present[k]
        q, r = traj.xy[k, here], traj.wh[here, 0] / 2
        d = np.hypot(*(q[:, None] - q[None]).transpose(2, 0, 1)) - (r[:, None] + r[None])
        np.fill_diagonal(d, np.inf)
        assert d.min() > -0.05  # cylinders may touch, not interpenetrate


# -- presets ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "cams", "mean_people", "max_people", "min_rate"),
    [("terrace-sim", 4, (7.5, 9.0), 9, 0.65), ("lab-sim", 4, (5.0, 6.0), 6, 0.55),
     ("campus-sim", 3, (4.0, 5.0), 5, 0.8)],
)
def test_presets_have_the_advertised_shape(name, cams, mean_people, max_people, min_rate):
    s = _preset(name)
    assert s.name == name and s.num_cameras == cams and s.frames == 600 and s.fps == 25.0
    assert s.units_per_metre == 1.0
    assert all(c.image_size == (360, 288) and c.P is not None for c in s.cameras)
    counts = np.array([len(ids) for ids in s.truth.ids])
    assert mean_people[0] <= counts.mean() <= mean_people[1]
    assert counts.max() == max_people
    rate, fp = _rates(s)
    # 10% random misses plus occlusion misses: between min_rate and 1 - miss_rate (+ noise).
    assert np.all(rate >= min_rate) and np.all(rate <= 0.93)
    assert abs(fp.mean() - 0.2) < 0.04
    # Every camera sees people (overlapping views) and every detection has a descriptor.
    for c in range(cams):
        assert np.mean([len(s.truth.boxes[c][k][0]) for k in range(s.frames)]) > 0.5 * counts.mean()
    d = s.detections[300][0][0]
    assert d.descriptor.shape == (512,) and abs(np.linalg.norm(d.descriptor) - 1.0) < 1e-12


def test_terrace_has_entries_exits_and_crossings():
    s = _preset("terrace-sim")
    everybody = np.unique(np.concatenate(s.truth.ids))
    assert len(everybody) > 9  # people left and others came in
    # Crossings: pairs of people closer than 1 m at some frame.
    close = 0
    for k in range(0, s.frames, 5):
        q = s.truth.xy[k]
        d = np.hypot(*(q[:, None] - q[None]).transpose(2, 0, 1))
        close += int((d[np.triu_indices(len(q), 1)] < 1.0).sum())
    assert close > 10
