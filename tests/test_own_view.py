"""Each camera's own view (``Track.boxes``) holds only what that camera can see: a target that
walked out of its image is not drawn there, and, with ``view_hidden`` below 1, neither is a
target it has stopped measuring behind a nearer one. The expected boxes are computed by hand
from the people's true positions on the fakes' top-down cameras (100 px per metre)."""
from __future__ import annotations

import numpy as np
import pytest

from edge_node.core import Detection, TrackerConfig
from fakes import PX_PER_M, box_at, make_nodes, step

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
