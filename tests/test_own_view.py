"""Each camera's own view (``Track.boxes``) holds only what that camera can see: a target that
walked out of its image is not drawn there, and, with ``view_hidden`` below 1, neither is a
target it has stopped measuring behind a nearer one. The expected boxes are computed by hand
from the people's true positions on the fakes' top-down cameras (100 px per metre)."""
from __future__ import annotations

import numpy as np
import pytest

from edge_node.core import Detection, TrackerConfig
from fakes import PX_PER_M, SELECTIVE, box_at, make_nodes, step

W = 1000  # the fakes' image is 1000 x 1000 px over 10 x 10 m


def inside_fraction(x: float, w: float = 0.5) -> float:
    """Fraction of the width of the box of a person at ground ``x`` (``w`` m wide) inside camera
    0's image."""
    x0, x1 = (x - w / 2) * PX_PER_M, (x + w / 2) * PX_PER_M
    return float(np.clip((min(x1, W) - max(x0, 0.0)) / (x1 - x0), 0.0, 1.0))


@pytest.mark.parametrize("view_inside", [0.9, 0.0])
def test_a_camera_stops_drawing_a_target_that_left_its_image(view_inside):
    """A person walks right, out of camera 0's image (ground x 0-10 m) into camera 1's, which
    looks at x 5-15 m. Camera 0 detects the person while the whole box is in its image; camera 1
    all along, so the network keeps the track. Camera 0 draws the track while at least
    ``view_inside`` of its box's width is in the image (0: any overlap), never once it has
    left."""
    cfg = TrackerConfig(registration=False, view_inside=view_inside)
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg, offsets={1: (5.0, 0.0)})
    drawn = {}
    for k in range(80):
        x = 8.0 + 0.05 * k
        d0 = [Detection(box_at(x, 5.0), None)] if inside_fraction(x) == 1.0 else []
        d1 = [Detection(box_at(x - 5.0, 5.0), None)]
        out = step(nodes, k, {0: d0, 1: d1})
        if k >= 2:  # born from two observations
            assert len(out[0]) == 1, k  # the network tracks the person throughout
            drawn[k] = 0 in out[0][0].boxes
    for k, shown in drawn.items():
        x = 8.0 + 0.05 * k  # the estimate is within 5 cm of it: look 5 cm either way
        if min(inside_fraction(x + 0.05), inside_fraction(x - 0.05)) >= max(view_inside, 0.01):
            assert shown, (k, x)
        elif max(inside_fraction(x + 0.05), inside_fraction(x - 0.05)) < max(view_inside, 0.01):
            assert not shown, (k, x)
    assert sum(drawn.values()) > 10 and not all(drawn.values())


def test_a_target_hidden_behind_a_nearer_one_is_not_drawn_once_the_camera_stops_measuring_it():
    """Two people stand one behind the other in camera 0's image: the nearer one's box (its
    bottom edge lower) covers 82 % of the farther one's. Camera 0 stops detecting the farther
    one (as a detector would); camera 1 still does. Past ``view_fresh`` frames camera 0 no
    longer draws it when ``view_hidden`` is 0.5; it does with the default 1 (never hidden). The
    nearer one is drawn throughout, and the network reports both."""
    far, near = (5.0, 5.0), (5.0, 5.3)
    cover = (far[1] * PX_PER_M - (near[1] * PX_PER_M - 170)) / 170  # overlap over the box height
    assert 0.8 < cover < 0.85
    for hidden, expect in ((0.5, False), (1.0, True)):
        cfg = TrackerConfig(view_fresh=5, view_hidden=hidden)
        nodes = make_nodes({0: (1,), 1: (0,)}, cfg)
        for k in range(40):
            both = [Detection(box_at(*far), None), Detection(box_at(*near), None)]
            out = step(nodes, k, {0: both if k < 20 else both[1:], 1: both})
            if k < 2:
                continue  # born from two observations
            assert len(out[0]) == 2
            by_y = sorted(out[0], key=lambda t: t.x[1])
            assert 0 in by_y[1].boxes  # the nearer one
            if k < 20 + cfg.view_fresh:
                assert 0 in by_y[0].boxes, k  # measured, or not long ago
        assert (0 in by_y[0].boxes) is expect


def test_a_target_the_camera_stopped_measuring_is_drawn_only_while_a_nearer_one_hides_it():
    """Hand-made boxes in a 1000 x 1000 image, ``view_frames`` 10. Box 0 is a target the camera
    measures now (its bottom edge at row 500). Targets it has not measured for 11 frames or
    more are drawn only behind box 0: at least ``view_behind`` (0.5) of their area covered by
    it, and their bottom edge at least ``view_depth`` (0.2) of their height above row 500."""
    from edge_node.core.views import OwnViews, ViewSettings
    from edge_node.geometry import Camera
    cam = Camera(0, (1000, 1000), np.eye(3))
    views = OwnViews(ViewSettings.of(TrackerConfig(), view_frames=10), [cam], {})
    h = 100.0
    boxes = np.array([[100.0, 400, 50, h],   # measured now; bottom edge row 500
                      [110.0, 370, 50, h],   # row 470: 30 % of h above; covered 40/50 x 70/100 = 56 %
                      [130.0, 370, 50, h],   # row 470, covered 20/50 x 70/100 = 28 %: not hidden
                      [100.0, 390, 50, h],   # row 490: 10 % of h above, beside it: not behind
                      [600.0, 370, 50, h],   # nobody in front
                      [800.0, 370, 50, h]])  # nobody in front, but measured 10 frames ago
    age = np.array([0, 11, 11, 11, 10**6, 10])
    assert views.visible(cam, boxes, age).tolist() == [True, True, False, False, False, True]
    # view_behind 1: such targets are never drawn; view_depth 0: beside counts as behind
    never = OwnViews(ViewSettings.of(TrackerConfig(), view_frames=10, view_behind=1.0), [cam], {})
    assert never.visible(cam, boxes, age).tolist() == [True, False, False, False, False, True]
    beside = OwnViews(ViewSettings.of(TrackerConfig(), view_frames=10, view_depth=0.0), [cam], {})
    assert beside.visible(cam, boxes, age).tolist() == [True, True, False, True, False, True]


def test_a_camera_draws_a_target_where_it_sees_it_not_where_the_network_puts_it():
    """Camera 0 believes everything 0.3 m further right than it is (a calibration error the
    registration is not there to learn); camera 1 is right. One person stands still at
    (5, 5) m: the fused estimate lies between the two cameras' measurements, right of where
    camera 0 sees the person. With ``view_place`` camera 0 draws the box where its own
    detection is (the offset learnt at ``view_rate`` 0.2, a factor 0.8 closer each frame);
    without it, where camera 0's image holds the estimate. When camera 0 stops detecting the
    person (frames 50-59, within ``view_frames``) the estimate moves to camera 1's
    measurement; camera 0 keeps its offset and the box moves with the estimate."""
    x_true = 5.0
    truth = box_at(x_true, 5.0)
    for place in (True, False):
        shift, x = {}, {}
        cfg = TrackerConfig(registration=False, view_place=place, **SELECTIVE)
        nodes = make_nodes({0: (1,), 1: (0,)}, cfg, offsets={0: (0.3, 0.0)})
        for k in range(60):
            d = [Detection(box_at(x_true, 5.0), None)]
            out = step(nodes, k, {0: d if k < 50 else [], 1: d})
            if k in (49, 59):
                (track,) = out[0]
                b = track.boxes[0]
                shift[k] = (b[0] + b[2] / 2) - (truth[0] + truth[2] / 2)  # px, bottom centres
                x[k] = track.x[0]
                assert b[1] + b[3] == pytest.approx(truth[1] + truth[3], abs=1.0)
        assert 5.02 < x[49] < 5.28  # between the two cameras' 5.0 and 5.3
        if place:
            assert abs(shift[49]) < 0.5
        else:  # camera 0 draws ground x at pixel (x - 0.3) * 100
            assert shift[49] == pytest.approx((x[49] - 0.3 - x_true) * PX_PER_M, abs=0.5)
            assert abs(shift[49]) > 2.0
        # camera 0 no longer measures: the estimate moves to camera 1's 5.0, and the box with it
        assert x[59] < x[49] - 0.02
        assert shift[59] - shift[49] == pytest.approx((x[59] - x[49]) * PX_PER_M, abs=0.5)


def test_a_target_is_not_drawn_as_the_twin_of_one_the_camera_measured_more_recently():
    """Hand-made boxes in a 1000 x 1000 image, all measured within ``view_frames``. Box 0 is a
    target the camera measures now (bottom edge at row 500). A target it measured 5 frames ago
    whose box overlaps box 0 with an IoU of at least ``view_twin`` (0.5) at the same depth
    (bottom edges closer than ``view_depth`` (0.2) of the box's height) is one person held by
    two trackers: not drawn, unless the node knows the two for two people. Boxes 6-8, far
    from the others, are not measured now: 7 (IoU 0.82 with 6) was measured longer ago than
    6 and is not drawn; 8 (IoU 0.82 with 6 as well) as long ago as 6, and both are drawn. IoUs by hand:
    box 1 45 x 100 / (2 x 5000 - 4500) = 0.82; box 2 20 x 100 / 8000 = 0.25; box 3 (bottom
    edge 30 px higher, one behind the other) 50 x 70 / 6500 = 0.54; box 5 as box 1 (and 0.75
    with box 4)."""
    from edge_node.core.views import OwnViews, ViewSettings
    from edge_node.geometry import Camera
    cam = Camera(0, (1000, 1000), np.eye(3))
    views = OwnViews(ViewSettings.of(TrackerConfig(), view_frames=10), [cam], {})
    assert views.s.view_twin == 0.5  # the default
    h = 100.0
    boxes = np.array([[100.0, 400, 50, h],   # measured now
                      [105.0, 400, 50, h],   # its twin
                      [130.0, 400, 50, h],   # beside it, IoU 0.25
                      [100.0, 370, 50, h],   # behind it, not at its depth
                      [102.0, 400, 50, h],   # measured now as well: two detections, two people
                      [95.0, 400, 50, h],    # a twin the node knows for another person
                      [600.0, 400, 50, h],   # measured 3 frames ago
                      [605.0, 400, 50, h],   # its twin, measured 7 frames ago
                      [595.0, 400, 50, h]])  # its twin, measured 3 frames ago too
    age = np.array([0, 5, 5, 5, 0, 5, 3, 7, 3])
    known_two = {(5, 0), (5, 4)}  # box 5 overlaps box 4 too (IoU 43 x 100 / 5700 = 0.75)
    asked = []

    def same(a, b):
        asked.extend(zip(a.tolist(), b.tolist()))
        return np.array([(i, j) not in known_two for i, j in zip(a.tolist(), b.tolist())], bool)

    drawn = [True, False, True, True, True, True, True, False, True]
    assert views.visible(cam, boxes, age, same).tolist() == drawn
    assert sorted(asked) == [(1, 0), (1, 4), (5, 0), (5, 4), (7, 6), (7, 8)]
    # without the node's knowledge (None) nothing is a twin; nor with view_twin 1
    assert views.visible(cam, boxes, age).all()
    never = OwnViews(ViewSettings.of(TrackerConfig(), view_frames=10, view_twin=1.0), [cam], {})
    assert never.visible(cam, boxes, age, same).all()
    # a looser IoU takes box 2 for a twin too
    loose = OwnViews(ViewSettings.of(TrackerConfig(), view_frames=10, view_twin=0.2), [cam], {})
    drawn[2] = False
    assert loose.visible(cam, boxes, age, same).tolist() == drawn


def test_of_three_boxes_in_a_row_the_first_is_drawn_when_its_only_twin_is_not():
    """Boxes 16 px apart (IoU 34 x 100 / 6600 = 0.52 between neighbours, 18 x 100 / 8200 =
    0.22 between the first and the last), measured 7, 3 and 0 frames ago: the middle one is
    the twin of the last and is not drawn; the first is the twin of the middle one only, which
    is not drawn, so the first is (of each pair of twins the camera draws one)."""
    from edge_node.core.views import OwnViews, ViewSettings
    from edge_node.geometry import Camera
    cam = Camera(0, (1000, 1000), np.eye(3))
    views = OwnViews(ViewSettings.of(TrackerConfig(), view_frames=10), [cam], {})
    boxes = np.array([[100.0, 400, 50, 100], [116.0, 400, 50, 100], [132.0, 400, 50, 100]])
    assert views.visible(cam, boxes, np.array([7, 3, 0]),
                         lambda a, b: np.ones(len(a), bool)).tolist() == [True, False, True]


def test_the_twin_rule_asks_the_manager_about_the_drawn_trackers_ids():
    """Through ``OwnViews.boxes`` on a node's table: of three trackers the reporter shows rows
    1 and 2, at nearly the same place on the fakes' top-down camera; row 1 was measured now,
    row 2 five frames ago. The manager is asked about the pair by the trackers' ids (not the
    rows' or the boxes' positions), and row 2 is drawn only when the manager knows the two for
    two people."""
    from edge_node.core.gallery import Gallery
    from edge_node.core.state import NodeState
    from edge_node.core.views import OwnViews, ViewSettings
    from fakes import topdown_camera
    ids = [(0, 0), (0, 1), (1, 5)]
    k = 20
    for known_two in (False, True):
        views = OwnViews(ViewSettings.of(TrackerConfig()), [topdown_camera(0)], {})
        st = NodeState(1)
        for t in ids:
            st.insert(t, Gallery())
        st.view_k[:, 0] = [k, k, k - 5]
        st.view_size[:, 0] = [0.5, 1.7]
        asked = []

        def two_people(pairs, known_two=known_two):
            asked.extend(pairs)
            return np.full(len(pairs), known_two)

        x_hat = np.array([[5.0, 5.0, 0.5, 1.7, 0, 0], [5.05, 5.0, 0.5, 1.7, 0, 0]])
        out = views.boxes(st, np.array([1, 2]), k, x_hat, two_people)
        assert asked == [((1, 5), (0, 1))]
        assert 0 in out[0]
        assert (0 in out[1]) is known_two


def test_the_managers_say_which_pairs_are_two_people():
    """The DTM knows a pair for two people when its co-motion evidence is below zero (a camera
    measured both at once far apart); a pair without evidence, or with evidence for one
    person, may be one. Without a DTM nothing is merged: every pair is two people."""
    from edge_node.core.manager import DistributedTrackerManager, IndependentTrackers, ManagerSettings
    cfg = TrackerConfig()
    dtm = DistributedTrackerManager(ManagerSettings.of(cfg))
    a, b, c, d = (0, 1), (1, 1), (2, 1), (3, 1)
    dtm.evidence[(a, b)] = -2.0
    dtm.evidence[(a, c)] = 3.0
    dtm.evidence[(b, c)] = 0.0
    pairs = [(a, b), (b, a), (a, c), (b, c), (c, d), (a, d)]
    assert dtm.two_people(pairs).tolist() == [True, True, False, False, False, False]
    assert IndependentTrackers(ManagerSettings.of(cfg)).two_people(pairs).tolist() == [True] * 6
    assert dtm.two_people([]).shape == (0,)
