"""Re-identification by motion (edge_node/core/reappear.py): the bridge of a gap, computed by
hand, the decision's rules, and a network in which a person hidden for longer than the
birth-time rule reaches keeps their id on every node without ever showing a second one."""
from __future__ import annotations

import numpy as np
import pytest

from edge_node.core import Detection, TrackerConfig
from edge_node.core.gallery import Gallery
from edge_node.core.reappear import Gone, Young, awaiting, d_mid, reappearances
from fakes import SELECTIVE, box_at, make_nodes, step

CFG = TrackerConfig()  # 1 ground unit per metre, 25 fps: dt = 0.04 s


def empty() -> Gallery:
    return Gallery(CFG.gallery_size, CFG.gallery_every)


def looks(v) -> Gallery:
    g = Gallery(CFG.gallery_size, CFG.gallery_every, [np.asarray(v, float)])
    return g


def gone(tid=(1, 0), seen=100, frame=116, p=(0.64, 0.0), v=(1.0, 0.0), gallery=None) -> Gone:
    """Walking +x at 1 m/s, last seen at frame 100 at x = 0, dropped 16 frames later (coasted
    on at its velocity to x = 0.64)."""
    return Gone(tid, frame, seen, np.array([*p, 0.5, 1.7, *v]), gallery or empty())


def young(tid=(0, 5), born=150, origin=(2.0, 0.0), now=(2.4, 0.0), gallery=None) -> Young:
    return Young(tid, born, np.array([*now, 0.5, 1.7, 0.0, 0.0]), gallery or empty(),
                 np.array(origin, float))


def test_the_gap_is_bridged_to_its_middle_from_both_sides():
    # middle of frames 100 (seen) and 150 (born): 125. Forward: 0.64 + 1.0 x (125 - 116) x 0.04
    # = 1.0. The new tracker went 0.4 m in the 10 frames since its birth at x = 2.0: 0.04 m a
    # frame; back 25 frames from its birth: 2.0 - 1.0 = 1.0. They meet.
    assert d_mid(young(), gone(), 160, CFG) == pytest.approx(0.0, abs=1e-12)
    # 0.3 m to the side, and 0.2 m further along: 0.2 - 0 and 0.3
    y = young(origin=(2.2, 0.3), now=(2.6, 0.3))
    assert d_mid(y, gone(), 160, CFG) == pytest.approx(np.hypot(0.2, 0.3))
    # a walker going the other way does not continue this course: back from x = 2.0 at
    # -0.04 m a frame for 25 frames is x = 3.0, 2 m from the forward point
    assert d_mid(young(now=(1.6, 0.0)), gone(), 160, CFG) == pytest.approx(2.0)


def test_a_first_measurement_no_walker_could_have_come_from_is_not_the_course():
    """A new tracker that would have walked from its camera's first measurement faster than
    ``reid_speed`` (2 m/s, 0.08 m a frame at 25 fps) did not start there (a box the image cut
    misplaces its foot point): the dropped tracker's course is carried on to now and compared
    with where the new one is. The walker of ``gone`` (x = 0.64 at frame 116, 1 m/s) is at
    x = 0.64 + 44 x 0.04 = 2.4 at frame 160; the new tracker born at frame 150, its first
    measurement 1.5 m to the side, is there now: 0.155 m a frame since the origin."""
    y = young(origin=(2.0, 1.5), now=(2.4, 0.0))
    assert d_mid(y, gone(), 160, CFG) == pytest.approx(0.0, abs=1e-12)
    assert reappearances([y], [gone()], 160, CFG) == [((0, 5), (1, 0))]
    # elsewhere now: 1.6 m from the course carried on, beyond reappear_gate
    y = young(origin=(2.0, 0.0), now=(2.4, 1.6))
    assert d_mid(y, gone(), 160, CFG) == pytest.approx(1.6)
    assert reappearances([y], [gone()], 160, CFG) == []
    # 1.875 m/s is a walker's: its course carried back from the origin to the middle of the
    # gap (frame 125), as before: 2.0 - 0.075 x 25 = 0.125, 0.875 from the forward point 1.0
    y = young(origin=(2.0, 0.0), now=(2.75, 0.0))
    assert d_mid(y, gone(), 160, CFG) == pytest.approx(0.875)


def test_linked_at_the_decision_frame_only_and_within_the_gate():
    age = CFG.reappear_age
    assert reappearances([young()], [gone()], 150 + age, CFG) == [((0, 5), (1, 0))]
    assert reappearances([young()], [gone()], 150 + age + 1, CFG) == []  # decided once
    # meeting point 1.6 m off the course: beyond reappear_gate (1.5 m)
    far = young(origin=(2.0, 1.6), now=(2.4, 1.6))
    assert d_mid(far, gone(), 160, CFG) == pytest.approx(1.6)
    assert reappearances([far], [gone()], 160, CFG) == []
    # a tracker dropped after the new one was born is not it; nor one seen too long before
    assert reappearances([young(born=110, origin=(0.4, 0.0), now=(0.8, 0.0))], [gone()],
                         110 + age, CFG) == []
    late = 100 + CFG.reappear_frames + 1
    assert reappearances([young(born=late)], [gone()], late + age, CFG) == []


def test_nearest_pair_first_each_tracker_once():
    a = gone((1, 0))
    b = gone((1, 1), p=(0.64, 0.5))  # a second walker 0.5 m beside the first
    y0 = young((0, 5), origin=(2.0, 0.45), now=(2.4, 0.45))  # 0.05 from b, 0.45 from a
    y1 = young((0, 6), origin=(2.0, 0.1), now=(2.4, 0.1))  # 0.1 from a, 0.4 from b
    assert reappearances([y0, y1], [a, b], 160, CFG) == [((0, 5), (1, 1)), ((0, 6), (1, 0))]
    # one dropped tracker, two new ones: only the nearer takes its id
    assert reappearances([y0, y1], [a], 160, CFG) == [((0, 6), (1, 0))]


def test_galleries_that_differ_veto_the_link():
    e0, e1 = np.eye(8)[0], np.eye(8)[1]  # cosine distance 1
    assert reappearances([young(gallery=looks(e0))], [gone(gallery=looks(e1))], 160, CFG) == []
    assert reappearances([young(gallery=looks(e0))], [gone(gallery=looks(e0))], 160,
                         CFG) == [((0, 5), (1, 0))]
    # one side without descriptors: motion alone decides
    assert reappearances([young()], [gone(gallery=looks(e1))], 160, CFG) == [((0, 5), (1, 0))]


def test_a_new_tracker_waits_while_a_link_may_come():
    age, hide = CFG.reappear_age, CFG.reappear_hide
    assert awaiting(young(), [gone()], 150, CFG)
    assert awaiting(young(), [gone()], 150 + age + hide - 1, CFG)
    assert not awaiting(young(), [gone()], 150 + age + hide, CFG)
    assert not awaiting(young(), [], 150, CFG)
    # born 40 m away: no dropped walker got there in 2 s at reid_speed
    assert not awaiting(young(origin=(40.0, 0.0), now=(40.4, 0.0)), [gone()], 152, CFG)


def walker(k: int) -> Detection:
    """1 m/s along x at y = 3 m, with no descriptor."""
    return Detection(box_at(1.0 + 0.04 * k, 3.0), None)


HIDDEN = range(30, 100)  # 70 frames: dropped after kappa, back 2.8 m on, 54 frames after the drop


@pytest.mark.parametrize("reappear", [True, False])
def test_a_walker_hidden_longer_than_the_birth_rule_reaches_keeps_the_id(reappear):
    """Only camera 0 sees the walker; node 1 hears of it. Back after 70 frames, 2.8 m on, more
    than ``reid_frames`` after the drop and farther than ``reid_gate`` from where it was
    dropped: the birth-time rule gives a new id; the course gives the old one back, on both
    nodes, and neither ever reports the new id."""
    cfg = TrackerConfig(reappear=reappear, **SELECTIVE)
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg)
    shown: dict[int, set] = {0: set(), 1: set()}
    for k in range(150):
        out = step(nodes, k, {0: [] if k in HIDDEN else [walker(k)]})
        for i in out:
            shown[i] |= {t.id for t in out[i]}
    ids = {i: [t.id for t in out[i]] for i in out}
    assert nodes[0].stats.dropped == 1
    assert nodes[0].stats.reidentified == 0  # the birth-time rule did not reach
    if reappear:
        assert ids == {0: [(0, 0)], 1: [(0, 0)]}
        assert shown == {0: {(0, 0)}, 1: {(0, 0)}}
        assert nodes[0].stats.reappeared == 1 and nodes[1].stats.reappeared == 0
    else:
        assert ids == {0: [(0, 1)], 1: [(0, 1)]}
        assert shown == {0: {(0, 0), (0, 1)}, 1: {(0, 0), (0, 1)}}


def test_someone_else_walking_elsewhere_is_somebody_new():
    """Another person appears 3 m to the side of the hidden walker's course, walking back:
    a new id, shown once the wait is over."""
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig(**SELECTIVE))
    for k in range(150):
        if k < 30:
            dets = [walker(k)]
        elif k in HIDDEN:
            dets = []
        else:
            dets = [Detection(box_at(6.0 - 0.04 * (k - 100), 6.0), None)]
        out = step(nodes, k, {0: dets})
    assert [t.id for t in out[0]] == [t.id for t in out[1]] == [(0, 1)]
    assert nodes[0].stats.reappeared == 0
