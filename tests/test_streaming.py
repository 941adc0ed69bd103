"""Frames on demand: a scenario's frame ``k`` does not depend on the run's length, on the frames
asked for before it, or on whether the scenario was streamed or materialised; and a stream's
memory is one chunk, not the run. For every kind: the synthetic world, EPFL gt-replay (a
hand-made sequence, and the real one when the data is there) and det-files (the simulator's
stream and a camera process's det-file source)."""
from __future__ import annotations

import gc
import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from edge_node.core.types import Detection
from edge_node.runtime.sources import load_det_file_camera
from sim_cluster.scenarios.data import CHUNK_FRAMES, Frame, ScenarioData, ScenarioStream
from sim_cluster.scenarios.detfiles import export_detections, load_det_files, open_det_files
from sim_cluster.scenarios.epfl import (build_ground_truth, load_epfl_gt, load_sequence,
                                        open_epfl_gt)
from sim_cluster.scenarios.files import read_scenario_toml, resolve_scenario_path
from sim_cluster.scenarios.loader import load_scenario, open_scenario
from sim_cluster.scenarios.synthetic.appearance import _KEEP_PER_CAMERA, AppearanceModel
from sim_cluster.scenarios.synthetic.schema import parse_synthetic
from sim_cluster.scenarios.synthetic.world import PeopleWalk, simulate_people
from tests.test_epfl import _real_root


def _same_frame(a: Frame, b: Frame) -> None:
    np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.wh, b.wh)
    for c in range(len(a.detections)):
        np.testing.assert_array_equal(a.detection_truth[c], b.detection_truth[c])
        assert len(a.detections[c]) == len(b.detections[c])
        for x, y in zip(a.detections[c], b.detections[c]):
            np.testing.assert_array_equal(x.box, y.box)
            np.testing.assert_array_equal(x.descriptor, y.descriptor)
            assert x.score == y.score
        np.testing.assert_array_equal(a.boxes[c][0], b.boxes[c][0])
        np.testing.assert_array_equal(a.boxes[c][1], b.boxes[c][1])


def _frame_of(data: ScenarioData, k: int) -> Frame:
    """Frame ``k`` of a materialised scenario."""
    return Frame(data.detections[k], data.detection_truth[k], data.truth.ids[k], data.truth.xy[k],
                 data.truth.wh[k], [data.truth.boxes[c][k] for c in range(data.num_cameras)])


def _same_as_short_run(short: ScenarioData, open_long) -> None:
    """Frames of ``open_long()`` (a stream of a longer run of the same scenario) read backwards
    and forwards across chunks equal ``short``'s (a materialised 150-frame run); a second stream
    that skips straight ahead (a node joining late) sees the same frames as the first."""
    long = open_long()
    assert short.frames == 150 and long.frames > 250
    for k in (149, 3, 120, 0, 250, 149):
        f = long.frame(k)
        if k < short.frames:
            _same_frame(f, _frame_of(short, k))
    _same_frame(open_long().frame(250), long.frame(250))
    _same_frame(open_long().frame(210), long.frame(210))


@pytest.mark.parametrize("name", ["terrace-sim", "terrace-calib"])
def test_frame_independent_of_run_length_and_access_order(name):
    short = load_scenario(name, frames=150)  # materialised, 2 chunks (the second cut at 150)
    long = open_scenario(name, frames=100_000)  # streamed
    probe = [149, 3, 120, 0, 250, 149]  # backwards and forwards, across chunks
    for k in probe:
        f = long.frame(k)
        if k < 150:
            want = Frame(short.detections[k], short.detection_truth[k], short.truth.ids[k],
                         short.truth.xy[k], short.truth.wh[k],
                         [short.truth.boxes[c][k] for c in range(short.num_cameras)])
            _same_frame(f, want)
    # A second stream that skips straight to frame 250 (a node joining late) sees the same frame.
    _same_frame(open_scenario(name, frames=100_000).frame(250), long.frame(250))
    _same_frame(open_scenario(name, frames=100_000).frame(310), long.frame(310))
    assert short.frames == 150 and len(short.detections) == 150


def test_people_walk_is_a_prefix_of_longer_walks():
    path = resolve_scenario_path("terrace-sim")
    cfg = parse_synthetic(read_scenario_toml(path), path, 3, None)
    rng = lambda: np.random.default_rng([3, 1])  # noqa: E731
    whole = simulate_people(cfg.area, cfg.fps, 400, cfg.people, rng())
    walk = PeopleWalk(cfg.area, cfg.fps, cfg.people, rng())
    for k in range(400):
        ids, xy, wh = walk.next()
        present = np.isfinite(whole.xy[k, :, 0])
        np.testing.assert_array_equal(ids, whole.ids[present])
        np.testing.assert_array_equal(xy, whole.xy[k, present])
        np.testing.assert_array_equal(wh, whole.wh[present])
    # Nobody who left is kept: the walk holds only the people in the world now.
    assert len(walk.active) == len(ids) and walk.born == len(whole.ids) > len(walk.active)


def test_stream_holds_one_chunk():
    s = open_scenario("terrace-sim", frames=10 * CHUNK_FRAMES)
    calls = []
    inner = s.chunk
    s.chunk = lambda j: calls.append(j) or inner(j)
    for k in range(0, 10 * CHUNK_FRAMES, 7):
        s.frame(k)
    assert calls == list(range(10))  # one chunk made per chunk of frames read in order
    assert s._held[0] == 9  # and only the last one held


def test_camera_subset_and_materialise_round_trip():
    full = open_scenario("terrace-sim", frames=120)
    two = full.first_cameras(2)
    assert two.num_cameras == 2 and full.num_cameras == 4
    data = two.materialise()
    assert len(data.truth.boxes) == 2 and all(len(d) == 2 for d in data.detections)
    again = ScenarioStream.of(data, chunk_frames=50)
    for k in (0, 49, 50, 119):
        _same_frame(again.frame(k), full.first_cameras(2).frame(k))
    with pytest.raises(IndexError, match="frame 120 outside 0..119"):
        again.frame(120)


def test_appearance_cache_is_bounded_and_forgetting_changes_nothing():
    m = AppearanceModel(seed=5)
    first = m.base(1, 0).copy()
    kept = m.base(2, 0).copy()
    for pid in range(3, 10 * _KEEP_PER_CAMERA):  # a one-camera process: people keep coming
        m.base(pid, 0)
        m.base(2, 0)  # someone who stays: used every time, never forgotten
    assert len(m._base) == len(m._identity) == _KEEP_PER_CAMERA
    assert (1, 0) not in m._base and (2, 0) in m._base
    np.testing.assert_array_equal(m.base(1, 0), first)  # derived again identically
    np.testing.assert_array_equal(m.base(2, 0), kept)
    for cam in range(1, 4):  # a model that serves four cameras keeps four times as many
        for pid in range(10 * _KEEP_PER_CAMERA):
            m.base(pid, cam)
    assert len(m._base) == len(m._identity) == 4 * _KEEP_PER_CAMERA


def test_a_camera_process_makes_only_its_camera_and_sees_the_same():
    full = open_scenario("terrace-sim", frames=300)
    mine = full.camera(2)
    for k in (0, 150, 299):
        a, b = mine(k), full.frame(k).detections[2]
        assert len(a) == len(b) > 0
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x.box, y.box)
            np.testing.assert_array_equal(x.descriptor, y.descriptor)
    focused = full.focus([2])(1)
    assert all(not f.detections[c] for f in focused for c in (0, 1, 3))
    assert any(f.detections[2] for f in focused)


def _camera_process_sees_the_same(full: ScenarioStream, c: int, probe) -> None:
    """``full.camera(c)`` (a camera process's own stream, made through ``focus``) reads frame
    ``k`` as the whole stream does; the focused chunks leave the other cameras empty."""
    mine = full.camera(c)
    for k in probe:
        a, b = mine(k), full.frame(k).detections[c]
        assert len(a) == len(b)
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x.box, y.box)
            np.testing.assert_array_equal(x.descriptor, y.descriptor)
            assert x.score == y.score
    focused = full.focus([c])(1)
    others = [o for o in range(full.num_cameras) if o != c]
    assert all(not f.detections[o] and not len(f.boxes[o][0]) for f in focused for o in others)
    assert any(f.detections[c] for f in focused)


# -- EPFL gt-replay ---------------------------------------------------------------------------------
def write_long_mini(root: Path, frames: int = 320) -> None:
    """A hand-made two-camera sequence (the layout of ``epfl_pom``) of ``frames`` frames: three
    people walking across both 360x288 images, one leaving after frame 200."""
    d = root / "epfl_pom" / "mini"
    d.mkdir(parents=True)
    (root / "epfl_pom" / "homographies.json").write_text(json.dumps({"mini": {
        "sequence": "mini1", "image_scale": 1.0, "image_size_annotations": [360, 288],
        "H": [np.eye(3).tolist(), [[1, 0, 10], [0, 1, 0], [0, 0, 1]]]}}))
    for c in range(2):
        rows = [f"{k},{p},{20 + p * 90 + (k % 100) + 5 * c},{60 + 20 * p},30,{70 + 10 * p},0,0,0,0"
                for k in range(frames) for p in range(3) if p != 2 or k <= 200]
        (d / f"mini1-c{c}.gt.csv").write_text("\r\n".join(rows) + "\r\n")


def test_epfl_gt_frame_independent_of_run_length_and_access_order(tmp_path):
    write_long_mini(tmp_path)
    short = load_epfl_gt("mini", frames=150, data_root=tmp_path, seed=4)
    _same_as_short_run(short, lambda: open_epfl_gt("mini", data_root=tmp_path, seed=4))
    assert sum(len(d) for frame in short.detections for d in frame) > 300  # not vacuous
    # Camera c's chunk j has its own random stream: another seed changes the detections.
    other = open_epfl_gt("mini", data_root=tmp_path, seed=5).frame(3).detections[0]
    assert [d.box.tolist() for d in other] != [d.box.tolist() for d in short.detections[3][0]]


def test_epfl_gt_camera_process_makes_only_its_camera(tmp_path):
    write_long_mini(tmp_path)
    _camera_process_sees_the_same(open_epfl_gt("mini", data_root=tmp_path), 1, (0, 150, 319))


def test_epfl_gt_stream_truth_is_the_sequences_ground_truth(tmp_path):
    """Chunked ground truth equals the whole run's (build_ground_truth over every frame)."""
    write_long_mini(tmp_path)
    whole = build_ground_truth(load_sequence("mini", data_root=tmp_path), 0, 320, 30.0)
    s = open_epfl_gt("mini", data_root=tmp_path)
    for k in (319, 0, 150, 201, 99, 100):
        f = s.frame(k)
        np.testing.assert_array_equal(f.ids, whole.ids[k])
        np.testing.assert_array_equal(f.xy, whole.xy[k])
        np.testing.assert_array_equal(f.wh, whole.wh[k])
        for c in range(2):
            np.testing.assert_array_equal(f.boxes[c][1], whole.boxes[c][k][1])
    assert len(s.frame(201).ids) == 2 and len(s.frame(200).ids) == 3


@pytest.mark.epfl
def test_epfl_gt_real_sequence_frame_independent_of_run_length():
    _real_root()
    short = load_scenario("terrace-gt", frames=150)
    _same_as_short_run(short, lambda: open_scenario("terrace-gt", frames=400))


# -- det-files --------------------------------------------------------------------------------------
def test_det_files_frame_independent_of_run_length_and_access_order(tmp_path):
    export_detections(load_scenario("terrace-sim", frames=300), tmp_path)
    short = load_det_files(tmp_path, frames=150)
    _same_as_short_run(short, lambda: open_det_files(tmp_path))
    _camera_process_sees_the_same(open_det_files(tmp_path), 2, (0, 150, 299))


def _long_det_dir(d: Path, frames: int, dim: int) -> np.ndarray:
    """A one-camera det-files directory, one detection a frame with a descriptor (float32)."""
    (d / "c0").mkdir(parents=True)
    k = np.arange(frames)
    rows = np.column_stack([k + 1, np.full(frames, -1), 10 + k % 200, 20 + k % 50,
                            np.full(frames, 30), np.full(frames, 60), np.full(frames, 0.9)])
    np.savetxt(d / "c0" / "det.txt", rows, fmt="%.4f", delimiter=",")
    desc = np.random.default_rng(0).standard_normal((frames, dim)).astype(np.float32)
    desc[7] = np.nan  # frame 7: no descriptor
    np.save(d / "c0" / "det.npy", desc)
    (d / "calibration.json").write_text(json.dumps({"frames": frames, "cameras": [
        {"image_size": [360, 288], "G": np.eye(3).tolist(), "descriptors": "c0/det.npy"}]}))
    return desc


def _detections_alive() -> int:
    return sum(type(o) is Detection for o in gc.get_objects())  # isinstance wakes lazy modules


def test_det_file_source_reads_frames_on_demand(tmp_path):
    """A camera process's det-file source over 20,000 frames holds det.txt's table and a memory
    map of the descriptors: opening makes no Detection (a frame's are built when it is read),
    and what it keeps is a fraction of the descriptors alone (a list of detections per frame
    would be more than them)."""
    frames, dim = 20_000, 256
    desc = _long_det_dir(tmp_path, frames, dim)
    gc.collect()
    alive = _detections_alive()  # other tests' (module fixtures) may be
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        src = load_det_file_camera(tmp_path / "calibration.json", 0, node=3)
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert src.frames == frames
    assert _detections_alive() == alive  # opening made none
    assert held < desc.nbytes / 4, (held, desc.nbytes)
    assert isinstance(src.read.__self__.descriptors, np.memmap)
    for k in (19_999, 5, 7, 12_345):  # any order: each frame is read from the files
        (d,) = src(k)
        np.testing.assert_array_equal(d.box, [10 + k % 200, 20 + k % 50, 30, 60])
        assert d.score == 0.9
        if k == 7:
            assert d.descriptor is None
        else:
            assert d.descriptor.dtype == np.float32 and not isinstance(d.descriptor, np.memmap)
            np.testing.assert_array_equal(d.descriptor, desc[k])
    assert src(frames) == []
