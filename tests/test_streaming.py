"""Frames on demand: a scenario's frame ``k`` does not depend on the run's length, on the frames
asked for before it, or on whether the scenario was streamed or materialised; and a stream's
memory is one chunk, not the run."""
from __future__ import annotations

import numpy as np
import pytest

from sim_cluster.scenarios.data import Frame, ScenarioStream
from sim_cluster.scenarios.files import read_scenario_toml, resolve_scenario_path
from sim_cluster.scenarios.loader import load_scenario, open_scenario
from sim_cluster.scenarios.synthetic.appearance import _KEEP, AppearanceModel
from sim_cluster.scenarios.synthetic.schema import parse_synthetic
from sim_cluster.scenarios.synthetic.world import CHUNK_FRAMES, PeopleWalk, simulate_people


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
    for pid in range(2, _KEEP + 50):
        m.base(pid, 0)
    assert len(m._base) <= _KEEP and len(m._identity) <= _KEEP
    assert (1, 0) not in m._base  # forgotten, and derived again identically
    np.testing.assert_array_equal(m.base(1, 0), first)


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
