"""Negative evidence (``report_unseen``, ``views.OwnViews.expect``): a node does not report a
target its own camera should see and has not measured for ``report_unseen`` frames in a row.
Two nodes whose cameras see the same 10 m x 10 m (``fakes.topdown_camera``); node 1's
detector adds a false person that node 0's camera would see."""
from __future__ import annotations

import numpy as np

from edge_node.core import Detection, TrackerConfig
from fakes import box_at, graph, make_nodes, step

FRAMES = 60


def person(k: int) -> tuple[float, float]:
    """A real person walking 1 m/s along x."""
    return 2.0 + 0.04 * k, 6.0


def run(false_at, cfg: TrackerConfig, frames: int = FRAMES):
    """Node 0 detects the person; node 1 detects the person and a false one at
    ``false_at(k)``. Returns, per frame, the set of positions node 0 and node 1 report
    (rounded to the metre) and the frame node 0 last reported the false person."""
    nodes = make_nodes(graph("complete", 2), cfg)
    last_false = {0: None, 1: None}
    for k in range(frames):
        p, q = person(k), false_at(k)
        dets = {0: [Detection(box_at(*p), None)],
                1: [Detection(box_at(*p), None), Detection(box_at(*q), None)]}
        out = step(nodes, k, dets)
        for i, tracks in out.items():
            near_q = [t for t in tracks if np.hypot(t.x[0] - q[0], t.x[1] - q[1]) < 0.5]
            near_p = [t for t in tracks if np.hypot(t.x[0] - p[0], t.x[1] - p[1]) < 0.5]
            if k > 5:
                assert near_p, (i, k)  # the real person is always reported
            if near_q:
                last_false[i] = k
    return last_false


def test_a_false_person_in_view_is_no_longer_reported_by_the_camera_that_cannot_see_it():
    """In node 0's view, never measured by it: node 0 stops reporting it ``report_unseen``
    frames after it adopted it; node 1, whose camera measures it, reports it throughout. With
    the option off, node 0 reports it to the end."""
    walker = lambda k: (8.0 - 0.04 * k, 3.0)  # noqa: E731, 3 m from the person
    on = run(walker, TrackerConfig(report_unseen=10))
    assert on[1] == FRAMES - 1
    # adopted at frame 2 (two observations at node 1, one frame on the wire): reported for
    # at most report_unseen frames, then never again
    assert on[0] is not None and on[0] <= 2 + 10, on
    off = run(walker, TrackerConfig(report_unseen=0))
    assert off[0] == FRAMES - 1


def test_a_false_person_behind_a_nearer_one_or_outside_the_view_is_still_reported():
    """Node 0 could not have measured it: a nearer person covers it (the bottom of the real
    person's box is lower in the image, and covers more than a third of it), or its box lies
    outside node 0's image; no negative evidence, node 0 reports it as node 1 does."""
    behind = lambda k: (person(k)[0], person(k)[1] - 0.6)  # noqa: E731
    assert run(behind, TrackerConfig(report_unseen=10))[0] == FRAMES - 1
    # feet below the image's bottom edge (y > 10 m): node 1's camera is shifted to see it
    outside = lambda k: (5.0, 10.5)  # noqa: E731
    nodes_cfg = TrackerConfig(report_unseen=10)
    from fakes import topdown_camera  # node 1 sees 1 m further on
    from edge_node.core import CameraNode
    nodes = {0: CameraNode(topdown_camera(0), (1,), nodes_cfg, "t"),
             1: CameraNode(topdown_camera(1, (0.0, 1.0)), (0,), nodes_cfg, "t")}
    seen = 0
    for k in range(FRAMES):
        p, q = person(k), outside(k)
        dets = {0: [Detection(box_at(*p), None)],
                1: [Detection(box_at(p[0], p[1] - 1.0), None), Detection(box_at(q[0], q[1] - 1.0), None)]}
        out = step(nodes, k, dets)
        seen += any(np.hypot(t.x[0] - q[0], t.x[1] - q[1]) < 0.5 for t in out[0])
    assert seen >= FRAMES - 5, seen


def _runs(cfg: TrackerConfig, frames: int = 90):
    """Node 0's detector misses the real person 15 frames in every 30 (frames 10-24, 40-54,
    70-84: a person it cannot find in some pose), node 1's never does; node 1's detector also
    adds the false walker of the first test. Returns the frames node 0 did not report the
    real person (after frame 5) and the last frame it reported the false one."""
    nodes = make_nodes(graph("complete", 2), cfg)
    walker = lambda k: (8.0 - 0.04 * k, 3.0)  # noqa: E731
    missing, last_false = [], None
    for k in range(frames):
        p, q = person(k), walker(k)
        dets = {0: [] if 10 <= k % 30 < 25 else [Detection(box_at(*p), None)],
                1: [Detection(box_at(*p), None), Detection(box_at(*q), None)]}
        tracks = step(nodes, k, dets)[0]
        if k > 5 and not any(np.hypot(t.x[0] - p[0], t.x[1] - p[1]) < 0.5 for t in tracks):
            missing.append(k)
        if any(np.hypot(t.x[0] - q[0], t.x[1] - q[1]) < 0.5 for t in tracks):
            last_false = k
    return missing, last_false


def test_a_node_learns_how_long_its_camera_misses_real_people():
    """With a fixed limit of 10 frames node 0 hides the real person from the 10th frame of
    every 15-frame run of misses to its end. Learning from the runs that end (``unseen_runs``), it hides
    them in the first run only: that run ends after 15 frames, and the limit becomes 16. The
    false person, whom node 0's camera never measures, ends no run: still hidden from the
    floor's 10 frames after it came on."""
    fixed, false_fixed = _runs(TrackerConfig(report_unseen=10, unseen_runs=0))
    assert fixed == [*range(19, 25), *range(49, 55), *range(79, 85)], fixed
    learnt, false_learnt = _runs(TrackerConfig())  # the defaults: 10, learnt from 200 runs
    assert learnt == [*range(19, 25)], learnt
    assert false_fixed is not None and false_fixed <= 2 + 10
    assert false_learnt == false_fixed


def test_the_learnt_limit_falls_below_only_the_longest_runs():
    """``OwnViews.unseen_limit``: the floor until runs end; then one more than the longest
    kept run but a fraction ``unseen_tail`` of them; only the latest ``unseen_runs`` kept."""
    from edge_node.core.views import OwnViews, ViewSettings
    cfg = TrackerConfig(report_unseen=10, unseen_runs=100, unseen_tail=0.02)
    views = OwnViews(ViewSettings.of(cfg), [], {})
    assert views.unseen_limit() == 10
    views.learn([1] * 90 + [2] * 7 + [30, 40, 50])  # the two longest (2 %) may be passed
    assert views.unseen_limit() == 31
    views.learn([1] * 97)  # 97 newer runs: only the 30, 40 and 50 are left of the old
    assert views.unseen_limit() == 31  # still 2 of 100 may be passed: the 50 and the 40
    views.learn([1] * 3)  # and now they fall out of the 100 kept
    assert views.unseen_limit() == 10
    assert OwnViews(ViewSettings.of(TrackerConfig(report_unseen=0, unseen_runs=100)), [],
                    {}).unseen_limit() == 0
