"""Online registration (edge_node/core/registration.py), each camera's own view (Track.boxes),
and the manager without appearance (co-motion merging, re-identification by place)."""
import math

import numpy as np
import pytest

from edge_node.core import Detection, TrackerConfig
from edge_node.core.measurement import BoxMeasurements, box_measurement
from edge_node.core.registration import Registration
from fakes import SELECTIVE, box_at, det, graph, make_nodes, step, topdown_camera


def walk(k, lane):
    """A person walking a slow loop in lane ``lane`` (metres)."""
    t = k / 25.0
    return 2.0 + 0.3 * lane + 1.5 * np.sin(0.4 * t + lane), 2.0 + 1.2 * lane + 1.0 * np.cos(0.3 * t)


def undetected(x, y):
    return Detection(box_at(x, y), None)


def test_two_cameras_learn_their_relative_offset_and_keep_the_mean_at_zero():
    """Camera 1 believes everything is 0.8 m further along x than camera 0 does. Shared targets
    teach the pair their difference; the common frame is the cameras' mean, so each camera ends
    up corrected by half the offset, in opposite directions, and their corrected measurements
    agree."""
    offset = 0.8
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig(), offsets={1: (offset, 0.0)})
    rng = np.random.default_rng(0)
    for k in range(400):
        dets = [det(*walk(k, lane), pid=lane, rng=rng) for lane in range(3)]
        step(nodes, k, {0: dets, 1: dets})
    p = np.array([3.0, 3.5])
    c0 = nodes[0].registrations[0].correction_at(p)
    c1 = nodes[1].registrations[1].correction_at(p)
    np.testing.assert_allclose(c0 - c1, [offset, 0.0], atol=0.05)  # they agree after correction
    np.testing.assert_allclose(c0 + c1, [0.0, 0.0], atol=0.05)  # the mean correction is zero
    # the network holds one tracker per person, at the cameras' mean
    assert len(nodes[0].trackers) == 3
    xs = sorted(t.x_hat[0] for t in nodes[0].trackers.values())
    truth = sorted(walk(399, lane)[0] + offset / 2 for lane in range(3))
    np.testing.assert_allclose(xs, truth, atol=0.15)


@pytest.mark.parametrize("shared", [True, False])
def test_the_first_residuals_do_not_make_two_cameras_cross(shared):
    """``reg_shared``: camera 1's map is 1 m off along x and one person is seen by both. Each
    camera fits its first residual against the other's measurement, and the other fits it back.
    Weighed by ``V`` alone each takes ``Sigma / (Sigma + V)`` of the disagreement (prior 1 m^2
    against ``V`` of a few tenths): together they move about 1.7 times the offset and cross.
    With the other side's uncertainty counted as this side's, each takes ``Sigma / (2 Sigma +
    V)``, together ``2 Sigma / (2 Sigma + V)``: at most the offset, at least 0.8 of it for ``V``
    up to 0.5 m^2. Later frames bring both to the offset either way."""
    offset = 1.0
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig(reg_shared=shared),
                       offsets={1: (offset, 0.0)})
    rng = np.random.default_rng(0)
    p = np.array([3.0, 3.5])
    gaps = []  # camera 0's correction minus camera 1's along x, per frame
    for k in range(60):
        step(nodes, k, {c: [det(*walk(k, 0), pid=0, rng=rng)] for c in (0, 1)})
        gaps.append(float(nodes[0].registrations[0].correction_at(p)[0]
                          - nodes[1].registrations[1].correction_at(p)[0]))
    first = next(g for g in gaps if abs(g) > 0.01)  # the first frame with residuals
    if shared:
        assert 0.8 * offset <= first <= 1.0 * offset, gaps[:10]
        assert max(gaps) <= 1.05 * offset
    else:
        assert first > 1.4 * offset, gaps[:10]  # crossed
    assert abs(gaps[-1] - offset) < 0.05


def test_the_two_cameras_of_one_node_learn_their_relative_offset():
    """One node owning two cameras, no neighbours: each camera's residuals are against the
    node's other camera (its ``u, U`` of the same targets, this frame). Camera 0 believes
    everything is 0.5 m further along x than camera 1 does; as between two nodes, each ends up
    corrected by half of it, in opposite directions, and the node holds one tracker per person
    at the cameras' mean."""
    from edge_node.core import CameraNode

    offset = 0.5
    node = CameraNode([topdown_camera(0, (offset, 0.0)), topdown_camera(1)], (), TrackerConfig(), "t")
    rng = np.random.default_rng(0)
    for k in range(300):
        truth = [walk(k, lane) for lane in range(3)]
        node.prepare(k, {c: [det(x, y, pid=lane, rng=rng) for lane, (x, y) in enumerate(truth)]
                         for c in (0, 1)})
        tracks = node.update([])
    p = np.array([3.0, 3.5])
    c0, c1 = (node.registrations[c].correction_at(p) for c in (0, 1))
    np.testing.assert_allclose(c0 - c1, [-offset, 0.0], atol=0.05)
    np.testing.assert_allclose(c0 + c1, [0.0, 0.0], atol=0.05)
    assert len(tracks) == 3
    for t, (x, y) in zip(sorted(tracks, key=lambda t: t.x[1]), sorted(truth, key=lambda p: p[1])):
        np.testing.assert_allclose(t.x[:2], [x + offset / 2, y], atol=0.1)


def test_without_registration_the_offset_stays_between_the_cameras():
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig(registration=False), offsets={1: (0.8, 0.0)})
    rng = np.random.default_rng(0)
    for k in range(100):
        dets = [det(*walk(k, 0), pid=0, rng=rng)]
        step(nodes, k, {0: dets, 1: dets})
    assert nodes[0].registrations == {}


def test_a_camera_nobody_else_sees_keeps_its_own_map():
    nodes = make_nodes({0: (), 1: ()}, TrackerConfig(), offsets={1: (0.8, 0.0)})
    for k in range(100):
        step(nodes, k, {0: [det(*walk(k, 0), pid=0)], 1: [det(*walk(k, 0), pid=0)]})
    for i in (0, 1):
        assert nodes[i].registrations[i].residuals == 0
        np.testing.assert_allclose(nodes[i].registrations[i].theta, 0.0)


def test_the_common_frame_does_not_drift():
    """Four cameras with offsets that average to zero: over a long run the corrections settle at
    minus each camera's own offset and their mean stays at zero (no common drift)."""
    offsets = {0: (0.5, 0.0), 1: (-0.5, 0.3), 2: (0.2, -0.6), 3: (-0.2, 0.3)}
    adj = graph("complete", 4)
    nodes = make_nodes(adj, TrackerConfig(), offsets=offsets)
    rng = np.random.default_rng(1)
    p = np.array([3.0, 3.5])
    means = []
    for k in range(1500):
        dets = [det(*walk(k, lane), pid=lane, rng=rng) for lane in range(3)]
        step(nodes, k, {i: dets for i in adj})
        if k % 100 == 99:
            means.append(np.mean([nodes[i].registrations[i].correction_at(p) for i in adj], axis=0))
    for i in adj:
        np.testing.assert_allclose(nodes[i].registrations[i].correction_at(p),
                                   -np.array(offsets[i]), atol=0.06)
    assert max(np.linalg.norm(m) for m in means[3:]) < 0.03


def test_registration_ignores_boxes_cut_by_the_image_border():
    cam = topdown_camera(0)
    reg = Registration(cam, TrackerConfig())
    inside = box_measurement(cam, box_at(5.0, 5.0), TrackerConfig())
    cut = box_measurement(cam, np.array([-10.0, 300.0, 50.0, 170.0]), TrackerConfig())
    assert not inside.cut and cut.cut
    assert cut.R[0, 0] > 10 * inside.R[0, 0]  # the hidden side: the foot point is uncertain
    assert not reg.observe(cut, cut.z[:2] + 0.1, np.eye(2) * 0.01)
    assert reg.observe(inside, inside.z[:2] + 0.1, np.eye(2) * 0.01)


def test_own_view_box_sits_on_the_cameras_detection():
    """Camera 1 is 0.5 m off. Its own view of the person (the network's estimate mapped back
    through its own registration, at its own box size) lands on its own detections, not where
    the network's mean frame would put them."""
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig(), offsets={1: (0.5, 0.0)})
    rng = np.random.default_rng(3)
    for k in range(300):
        dets = [det(*walk(k, 0), pid=0, rng=rng)]
        out = step(nodes, k, {0: dets, 1: dets})
    t = out[1][0]
    want = box_at(*walk(299, 0))  # what camera 1 detects (pixels are the same for both cameras)
    np.testing.assert_allclose(t.boxes[1], want, atol=4.0)  # px, detector noise is 0.05 m = 5 px
    naive = nodes[1].cameras[0].to_image(t.x[None, :2])[0]  # the mean frame through camera 1
    assert abs(naive[0] - (want[0] + want[2] / 2)) > 15  # 0.25 m = 25 px off


def test_a_target_a_camera_has_not_seen_is_not_in_its_view():
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig(**SELECTIVE))
    for k in range(30):
        out = step(nodes, k, {0: [det(3.0, 3.0, 1)], 1: []})
    assert out[1] and out[1][0].boxes == {}
    assert set(out[0][0].boxes) == {0}
    cfg = TrackerConfig()
    for k in range(30, 30 + cfg.view_frames + 2):  # camera 0 stops seeing it; the network not
        out = step(nodes, k, {0: [], 1: []})
    assert all(t.boxes == {} for t in out[0])


# -- without appearance ---------------------------------------------------------------------------
def test_co_motion_merges_duplicates_without_appearance():
    """No descriptors, and camera 1's map 0.7 m off (no registration to correct it): both
    cameras start their own tracker of the person in the same frame, 0.7 m apart, too far to be
    taken for one at once. They move together, each camera measuring its own tracker: two
    cameras each saw one person there, 2 ln(1 / comotion_miss) = 1.386 nats a frame, so after
    ceil(merge_llr / 1.386) = 22 frames they are merged: one id, on both nodes, for good.
    While the pair agrees towards the merge the younger tracker is held but not reported
    (``hide_pending``): every node reports the one id from the first frame; without it, the
    duplicate shows until the merge."""
    for hide in (False, True):
        # negative evidence off: node 0's camera never measures node 1's tracker, 0.7 m off
        # its own, and would stop reporting it after 10 frames (the next test has it on);
        # report_age off: it would hold the duplicate back for its first 10 frames whatever
        # hide_pending says (tests/test_reported_ids.py)
        cfg = TrackerConfig(registration=False, hide_pending=hide, report_age=0, **SELECTIVE)
        nodes = make_nodes({0: (1,), 1: (0,)}, cfg, offsets={1: (0.7, 0.0)})
        rng = np.random.default_rng(5)
        counts, held = [], []
        for k in range(60):
            p = walk(k, 0)
            d = [Detection(det(*p, pid=0, rng=rng).box, None)]
            out = step(nodes, k, {0: d, 1: d})
            counts.append(len(out[0]))
            held.append(len(nodes[0].trackers))
        n = math.ceil(cfg.merge_llr / (2 * math.log(1 / cfg.comotion_miss)))
        assert n == 22 and cfg.comotion_frames >= n
        assert held[1:n] == [2] * (n - 1)  # the duplicate...
        assert held[n:] == [1] * (60 - n)  # ...merged in the frame the pair agreed n times
        assert counts[1:n] == [1 if hide else 2] * (n - 1)
        assert counts[n:] == [1] * (60 - n)
        assert [t.id for t in out[0]] == [t.id for t in out[1]] == [(0, 0)]


def test_a_merge_neither_hides_the_person_nor_teaches_a_miss():
    """The previous test's duplicate with negative evidence on (the defaults). Each camera
    measures its own tracker every frame and never its twin, whose count of misses climbs on
    that node; the merge keeps the smaller count (a camera missed the person only as long as
    it missed both). Before, the winner kept its own: node 1 showed nobody in the merge frame
    and learnt a run of 21 misses its camera never made, raising its limit to 22."""
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig(registration=False),
                       offsets={1: (0.7, 0.0)})
    rng = np.random.default_rng(5)
    counts = {0: [], 1: []}
    for k in range(60):
        d = [Detection(det(*walk(k, 0), pid=0, rng=rng).box, None)]
        out = step(nodes, k, {0: d, 1: d})
        for i in (0, 1):
            counts[i].append(len(out[i]))
    assert counts[0][1:] == counts[1][1:] == [1] * 59  # the person, on every frame
    assert nodes[0].stats.merged + nodes[1].stats.merged >= 1  # the duplicate did merge
    assert not nodes[0].own_views.runs and not nodes[1].own_views.runs
    assert [t.id for t in out[0]] == [t.id for t in out[1]] == [(0, 0)]


def test_simultaneous_births_on_top_of_each_other_merge_at_once_without_appearance():
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig())
    rng = np.random.default_rng(5)
    for k in range(10):
        d = [Detection(det(*walk(k, 0), pid=0, rng=rng).box, None)]
        out = step(nodes, k, {0: d, 1: d})
        assert len(out[0]) <= 1
    assert [t.id for t in out[0]] == [t.id for t in out[1]] == [(0, 0)]


def test_two_people_side_by_side_are_never_merged():
    """Two people walking 0.6 m apart: co-motion alone would say one target, but a camera sees
    them as two detections every frame."""
    nodes = make_nodes({0: (1,), 1: (0,)}, TrackerConfig())
    for k in range(80):
        x, y = walk(k, 0)
        pair = [undetected(x, y), undetected(x + 0.6, y)]
        out = step(nodes, k, {0: pair, 1: pair})
    assert len(out[0]) == 2 and len(out[1]) == 2
    assert {t.id for t in out[0]} == {t.id for t in out[1]}
    # each node merged its own and its neighbour's birth of each person, nothing more
    assert nodes[0].stats.merged == nodes[1].stats.merged == 2


def test_a_person_back_after_an_occlusion_gets_the_old_id_without_appearance():
    cfg = TrackerConfig()
    nodes = make_nodes({0: ()}, cfg)
    ids = []
    for k in range(90):
        hidden = 30 <= k < 30 + cfg.kappa + 10  # longer than kappa: the tracker is dropped
        out = step(nodes, k, {0: [] if hidden else [undetected(3.0 + 0.01 * k, 3.0)]})
        ids.append({t.id for t in out[0]})
    assert ids[20] == {(0, 0)} and ids[-1] == {(0, 0)}
    assert nodes[0].stats.dropped == 1 and nodes[0].stats.reidentified == 1
    # somebody else, far from where the person was lost, is somebody new
    nodes = make_nodes({0: ()}, cfg)
    for k in range(90):
        hidden = 30 <= k < 30 + cfg.kappa + 10
        x = 3.0 if k < 30 else 7.0
        out = step(nodes, k, {0: [] if hidden else [undetected(x, 3.0)]})
    assert {t.id for t in out[0]} == {(0, 1)}


@pytest.mark.parametrize("pixel_scale", [1.0, 0.25])
def test_image_and_jacobians_from_the_ground_match_the_image_to_ground_map(pixel_scale):
    """``Camera.image_and_jacobians`` (what the views and R1's inverse use): the pixel is
    ``to_image``'s, and the Jacobian is the image-to-ground map's, checked by central finite
    differences of ``to_ground`` around that pixel, for a tilted camera (terrace-sim's first)
    with and without a pixel scale."""
    from dataclasses import replace

    from sim_cluster.scenarios.loader import load_scenario
    cam = load_scenario("terrace-sim", frames=1).cameras[0]
    cam = replace(cam, G=cam.G @ np.diag([1 / pixel_scale, 1 / pixel_scale, 1.0]),
                  pixel_scale=pixel_scale)  # the same camera with scaled pixel coordinates
    W, H = cam.image_size
    px = np.random.default_rng(5).uniform([20, H / 2], [W - 20, H - 5], size=(30, 2))
    g = cam.to_ground(px)
    uv, J = cam.image_and_jacobians(g)
    np.testing.assert_allclose(uv, cam.to_image(g), rtol=0, atol=1e-9)
    np.testing.assert_allclose(uv, px, atol=1e-6)
    eps = 1e-3  # pixels
    for j, e in enumerate(np.eye(2) * eps):
        numeric = (cam.to_ground(uv + e) - cam.to_ground(uv - e)) / (2 * eps)
        np.testing.assert_allclose(J[:, :, j], numeric, rtol=1e-5, atol=1e-9)


def test_debias_is_the_expected_pull_of_the_foot_points_own_noise():
    """R2's sums ``A(g)^T W r`` over residuals of a perfectly registered camera (``theta`` 0,
    the others measuring the target exactly) should average zero, but ``A`` is taken at the
    noisy ``g = p + n`` and ``r = p - g = -n``: by Monte Carlo over the noise, the rotation
    and scale rows average ``-tr(J^T W Rg)`` and ``-tr(W Rg)``, which ``_debias`` adds back."""
    cam = topdown_camera(0)
    reg = Registration(cam, TrackerConfig())
    rng = np.random.default_rng(0)
    total_mc, total_db, var_mc = np.zeros(5), np.zeros(5), np.zeros(5)
    for _ in range(4):
        p = rng.uniform(1.0, 9.0, size=2)
        a = rng.uniform(0.05, 0.4, size=2)
        c, s = np.cos(rng.uniform(0, np.pi)), np.sin(rng.uniform(0, np.pi))
        Q = np.array([[c, -s], [s, c]])
        Rg = Q @ np.diag(a ** 2) @ Q.T  # the foot point's noise covariance
        W = np.linalg.inv(Rg + 0.01 * np.eye(2))
        n = rng.multivariate_normal(np.zeros(2), Rg, size=200_000)
        g = p + n
        A = reg.bases(g, np.tile([0.0, 1.0], (len(g), 1)))
        terms = np.einsum("nji,jk,nk->ni", A, W, -n)
        total_mc += terms.mean(axis=0)
        var_mc += terms.var(axis=0) / len(n)
        total_db += Registration._debias(W[None], Rg[None])
    se = np.sqrt(var_mc)  # the Monte Carlo means' standard errors
    assert np.all(np.abs(total_mc + total_db) < 4 * se), (total_mc, -total_db, se)
    assert abs(total_db[3]) > 20 * se[3]  # the scale row's pull is real (the check can fail)


def test_the_fused_regressor_has_no_errors_in_variables_pull():
    """``reg_fused``: R2's regressor at the fused point of this camera's foot point ``g`` and the
    others' ``z_o``. For a perfectly registered camera whose foot point and the others' both
    carry the noise their covariances say, the sums ``A^T W r`` average zero (the fused point's
    error is orthogonal to the residual ``z_o - g``), whatever the two noises; with ``A`` at
    ``g`` itself, the scale row's pull is there (the check can fail)."""
    cam = topdown_camera(0)
    reg = Registration(cam, TrackerConfig(reg_fused=True))
    reg.Sigma = np.zeros_like(reg.Sigma)  # R5's own part: pixels and sigma only
    rng = np.random.default_rng(1)
    total_f, var_f, total_g = np.zeros(5), np.zeros(5), np.zeros(5)
    m = 100_000
    for _ in range(3):
        p = rng.uniform(1.0, 9.0, size=2)
        a = rng.uniform(0.05, 0.6, size=2)
        Rpx = np.diag(a ** 2)
        Vo = np.diag(rng.uniform(0.05, 0.6, size=2) ** 2) + 0.02 * np.eye(2)
        Ry = Rpx + reg.noise_var * np.eye(2)
        g = p + rng.multivariate_normal(np.zeros(2), Ry, size=m)
        zo = p + rng.multivariate_normal(np.zeros(2), Vo, size=m)
        away = np.tile([0.0, 1.0], (m, 1))
        A0 = reg.bases(g, away)
        A = reg._fused_bases(g, away, A0, np.tile(Vo, (m, 1, 1)), zo, np.tile(Rpx, (m, 1, 1)))
        W = np.linalg.inv(Ry + Vo)
        terms = np.einsum("nji,jk,nk->ni", A, W, zo - g)
        total_f += terms.mean(axis=0)
        var_f += terms.var(axis=0) / m
        total_g += np.einsum("nji,jk,nk->ni", A0, W, zo - g).mean(axis=0)
    se = np.sqrt(var_f)
    assert np.all(np.abs(total_f) < 4 * se), (total_f, se)
    assert total_g[3] < -20 * se[3]  # at g the pull is real and a shrink


def knocked(cfg: TrackerConfig, frames: int = 260, at: int = 120, jump=(1.5, -1.0), n: int = 3):
    """``n`` nodes, complete; four people walking; node 0's camera knocked at frame ``at``:
    from then on every detection of it lands ``jump`` metres away (what its old calibration
    makes of the moved camera's view; no descriptors). Returns the nodes and the frame R7
    re-locked node 0's camera (None: never)."""
    nodes = make_nodes(graph("complete", n), cfg)
    rng = np.random.default_rng(3)
    relocked = None
    for k in range(frames):
        truth = [walk(k, lane) for lane in range(4)]
        dets = {i: [undetected(x + rng.normal(0, 0.02), y + rng.normal(0, 0.02)) for x, y in truth]
                for i in nodes}
        if k >= at:
            dets[0] = [undetected(x + jump[0], y + jump[1]) for x, y in truth]
        step(nodes, k, dets)
        if relocked is None and nodes[0].registrations[0].relocks:
            relocked = k
    return nodes, relocked


def test_a_knocked_camera_relocks_onto_its_neighbours_within_a_second():
    """R7: a camera knocked 1.8 m (detections land ``jump`` away, far outside every gate) is
    re-locked by its two neighbours' agreeing view within 25 frames: its correction is then
    the jump undone (to the 0.25 m grid and what R3 learns after), its neighbours did not
    move, and its corrected measurements of the people land on them again (R7 is the default).
    Without R7 the correction stays where it was (R3's random walk cannot follow 1.8 m)."""
    jump = np.array([1.5, -1.0])
    nodes, relocked = knocked(TrackerConfig())
    assert relocked is not None and 120 <= relocked <= 145, relocked
    p = np.array([2.5, 3.0])
    np.testing.assert_allclose(nodes[0].registrations[0].correction_at(p), -jump, atol=0.15)
    for i in (1, 2):
        assert nodes[i].registrations[i].relocks == 0
        assert np.linalg.norm(nodes[i].registrations[i].correction_at(p)) < 0.15
    assert nodes[0].registrations[0].relocks == 1
    held, _ = knocked(TrackerConfig(reg_relock=False))
    assert np.linalg.norm(held[0].registrations[0].correction_at(p) + jump) > 1.0


def test_two_cameras_that_only_see_each_other_never_relock():
    """R7 needs two other cameras that agree: of two cameras alone, neither can tell which of
    them was knocked (both would jump, and then disagree the other way)."""
    nodes, relocked = knocked(TrackerConfig(reg_relock=True), frames=200, n=2)
    assert relocked is None
    assert nodes[1].registrations[1].relocks == 0


def test_relock_votes_of_one_source_against_two_for_no_jump_do_not_move_a_camera():
    """A neighbour of a knocked camera hears a jump from it alone, and of none from its other
    neighbour: no re-lock, whatever the jump's support."""
    cfg = TrackerConfig(reg_relock=True)
    reg = Registration(topdown_camera(0), cfg)
    rng = np.random.default_rng(1)
    for k in range(60):
        p = rng.uniform(0.0, 6.0, size=(5, 2))
        ms = [box_measurement(reg.camera, box_at(x, y), cfg) for x, y in p]
        z = np.concatenate([p + [2.0, 0.5], p])  # source 7 says the map moved, source 8 not
        reg.vote(BoxMeasurements.of(ms), z, np.repeat([7, 8], 5))
        reg.end_frame()
    assert reg.relocks == 0
    np.testing.assert_allclose(reg.theta[:2], 0.0, atol=1e-9)


def _relock_run(own_shift, told_shift, frames: int = 60, at: int = 30) -> Registration:
    """R7 fed 60 frames of five people walking about 1 m/s past a camera: two sources (7, 8)
    both measure each person ``told_shift`` (m) from the truth; the camera's own foot points
    are the truth until frame ``at``, then shifted by ``own_shift``. The camera's registration
    has converged (``Sigma`` held at (5 cm)^2; R3's residuals are not fed here)."""
    cfg = TrackerConfig(reg_relock=True)
    reg = Registration(topdown_camera(0), cfg)
    rng = np.random.default_rng(4)
    p0, v = rng.uniform(1.0, 5.0, size=(5, 2)), rng.normal(0.0, 0.7, size=(5, 2))
    for k in range(frames):
        p = p0 + v * 0.04 * k
        own = p + (np.asarray(own_shift) if k >= at else 0.0)
        ms = [box_measurement(reg.camera, box_at(x, y), cfg) for x, y in own]
        z = np.concatenate([p + told_shift, p + told_shift])
        reg.Sigma = np.diag(np.full(5, 0.05 ** 2))
        reg.vote(BoxMeasurements.of(ms), z, np.repeat([7, 8], 5))
        reg.end_frame()
    return reg


def test_relock_needs_the_cameras_own_people_to_jump_at_once():
    """R7's onset: two sources agreeing on a steady 2.06 m displacement are not enough (people
    walking side by side, each seen by other cameras, vote for their distance as steadily);
    the camera's own foot points must have jumped at once, by the displacement undone, within
    ``reg_relock_onset`` frames. The same votes re-lock the camera when its own people jumped
    by minus the displacement at frame 30 (a knock), not when they jumped elsewhere."""
    d = np.array([2.0, 0.5])
    assert _relock_run((0.0, 0.0), d).relocks == 0
    knocked_ = _relock_run(-d, (0.0, 0.0))
    assert knocked_.relocks == 1
    np.testing.assert_allclose(knocked_.last_jump, d, atol=0.2)
    assert _relock_run((0.0, -2.0), d).relocks == 0  # an onset, but not the votes' jump


def test_the_camera_process_logs_each_relock_once(caplog):
    """``FrameLoop._log_relocks``: one warning per re-lock, with the jump the map had made
    (the opposite of the correction's change), none again for the same count, none for a
    restarted core counting from 0."""
    import logging
    from types import SimpleNamespace

    from edge_node.runtime.loop import FrameLoop

    reg = SimpleNamespace(relocks=1, last_jump=np.array([-0.6, 0.8]))
    loop = SimpleNamespace(node=SimpleNamespace(id=3, registrations={5: reg}), _relocks_seen={})
    with caplog.at_level(logging.WARNING, logger="edge_node.loop"):
        FrameLoop._log_relocks(loop, 40)
        FrameLoop._log_relocks(loop, 41)
        reg.relocks = 0  # a restarted core
        FrameLoop._log_relocks(loop, 42)
    lines = [r.getMessage() for r in caplog.records if "re-locked" in r.getMessage()]
    assert lines == ["node 3: frame 40: camera 5 re-locked: its ground map had jumped 1.00 m "
                     "(0.60, -0.80); knocked?"]
