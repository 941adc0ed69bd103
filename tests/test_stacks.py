"""The core's stacked columns give what stacking the rows gives, bit for bit: ``Candidates`` / ``Observations`` (the association's inputs) and
``BoxMeasurements`` (registration's), each against ``numpy.array`` of the rows or the
per-object path computed in the test."""
import numpy as np

from edge_node.core import TrackerConfig
from edge_node.core.association import (Candidate, Candidates, Observation, Observations, appearance_matrix,
                                        mahalanobis_matrix, recover)
from edge_node.core.gallery import Gallery
from edge_node.core.measurement import BoxMeasurements, box_measurement, box_measurements
from edge_node.core.registration import Registration
from fakes import box_at, topdown_camera


def _spd(rng, k):
    A = rng.normal(size=(k, k))
    return A @ A.T + 0.1 * np.eye(k)


def test_candidates_and_observations_columns_give_the_per_object_results():
    rng = np.random.default_rng(11)
    n, m = 5, 4
    x, P = rng.normal(size=(n, 6)), np.array([_spd(rng, 6) for _ in range(n)])
    galleries = [Gallery(20, 20, list(rng.normal(size=(k, 8)))) if k else None for k in (2, 0, 1, 3, 1)]
    z, R = rng.normal(size=(m, 4)), np.array([_spd(rng, 4) for _ in range(m)])
    descs = [rng.normal(size=8), rng.normal(size=8), None, rng.normal(size=8)]
    cands, obs = Candidates(x, P, galleries), Observations(z, R, descs)
    # the rows as plain objects (copies, so nothing is shared with the columns)
    cand_list = [Candidate(x[i].copy(), P[i].copy(), galleries[i]) for i in range(n)]
    obs_list = [Observation(z[j].copy(), R[j].copy(), descs[j], j) for j in range(m)]
    assert len(cands) == n and len(obs) == m
    assert np.array_equal(cands[3].P, P[3]) and obs[2].raw == 2 and obs[1].descriptor is descs[1]
    assert np.array_equal(mahalanobis_matrix(cands, obs), mahalanobis_matrix(cand_list, obs_list))
    where = rng.random((n, m)) < 0.7
    for unknown in (7.0, np.nan):
        assert np.array_equal(appearance_matrix(cands, obs, unknown, where=where),
                              appearance_matrix(cand_list, obs_list, unknown, where=where), equal_nan=True)
    cfg = TrackerConfig(tau_gda=10.0, comotion_gate=10.0, merge_appearance=2.0)
    assert recover(cands, obs, [(0, 1)], cfg) == recover(cand_list, obs_list, [(0, 1)], cfg)
    assert recover(cands, obs, [(0, 1)], cfg)  # the case is not empty: something is recovered


def test_box_measurements_columns_are_the_single_box_measurements():
    """A frame's boxes measured at once: row ``i`` is box ``i`` measured alone, and R5 (the
    correction) and R2 (residuals) read the columns as they read a list of those rows."""
    cam, cfg = topdown_camera(0), TrackerConfig()
    boxes = np.array([box_at(5.0, 5.0), box_at(2.0, 7.5, 0.6, 1.8), [-10.0, 300.0, 50.0, 170.0],
                      box_at(8.0, 3.0)])
    ms = box_measurements(cam, boxes, cfg)
    rows = [box_measurement(cam, b, cfg) for b in boxes]
    assert len(ms) == 4 and [m.cut for m in rows] == [False, False, True, False]
    for i, m in enumerate(rows):
        for name in ("z", "R", "foot", "away", "size"):
            assert np.array_equal(getattr(ms[i], name), getattr(m, name))
        assert ms[i].cut == m.cut
    assert np.array_equal(BoxMeasurements.of(rows).R, ms.R)
    sub = ms.take([3, 0])
    assert np.array_equal(sub.z, ms.z[[3, 0]]) and not sub.cut.any()

    def learnt():
        reg = Registration(cam, cfg)
        reg.theta = np.array([0.3, -0.2, 0.05, 0.02, 0.1])  # a correction that moves things
        return reg
    a, b = learnt(), learnt()
    for got, want in zip(a.corrects(ms), b.corrects(rows)):
        assert np.array_equal(got, want)
    z_o = ms.z[:, :2] + np.array([0.05, -0.03])
    V_o = np.broadcast_to(np.eye(2) * 0.01, (4, 2, 2))
    used = a.observe_many(ms, z_o, V_o)
    assert np.array_equal(used, b.observe_many(rows, z_o, V_o))
    assert used.tolist() == [True, True, False, True]  # the cut box is not a residual
    assert np.array_equal(a._info, b._info) and np.array_equal(a._vec, b._vec) and a._info.any()
    empty = box_measurements(cam, np.zeros((0, 4)), cfg)
    assert len(empty) == 0 and empty.R.shape == (0, 4, 4)


def test_unusable_boxes_are_counted_and_the_rest_tracked_as_alone():
    """A frame's boxes go in as one array when all are four numbers, box by box otherwise:
    either way a box that is not four finite numbers of positive size is counted and left out,
    and the others give the tracks they give without it (a second node fed the good ones)."""
    from fakes import det, make_nodes, step
    from edge_node.core.types import Detection
    rng = np.random.default_rng(2)
    with_bad, alone = make_nodes({0: ()}), make_nodes({0: ()})
    bad_counts = []
    for k in range(30):
        good = [det(3.0 + 0.02 * k, 4.0, 1, rng), det(6.0, 6.0 - 0.02 * k, 2, rng)]
        junk = {0: [], 1: [Detection(np.array([1.0, np.nan, 20.0, 40.0]))],  # all four numbers
                2: [Detection(np.array([1.0, 2.0, 0.0, 40.0])), Detection([1.0, 2.0, 3.0])],  # ragged
                3: [Detection(np.ones((2, 2)))]}[k % 4]  # four numbers, not a box
        a = step(with_bad, k, {0: junk[:1] + good + junk[1:]})[0]
        b = step(alone, k, {0: good})[0]
        bad_counts.append(with_bad[0].stats.bad_detections)
        assert [t.id for t in a] == [t.id for t in b]
        for s, t in zip(a, b):
            assert np.array_equal(s.x, t.x) and np.array_equal(s.P, t.P)
    assert len(b) == 2
    # frames k = 0..29: k % 4 == 1 (8 frames, 1 bad box), 2 (7 frames, 2), 3 (7 frames, 1)
    assert bad_counts[-1] == 8 * 1 + 7 * 2 + 7 * 1 and bad_counts[0] == 0


def test_a_stack_times_one_matrix_in_one_call_is_the_stacked_product():
    """``times(a, b)`` is ``a @ b`` for a stack ``a`` and one matrix or vector ``b``: shapes,
    and the numbers to the last bits (the same sums of the same products; a BLAS may round
    the last bit differently between its kernels), on random stacks of every size the core
    meets."""
    from edge_node.core.stacks import times
    rng = np.random.default_rng(4)
    worst = 0.0
    for _ in range(300):
        n = int(rng.integers(1, 60))
        a = rng.normal(size=(n, 2, 5)) * 10.0 ** rng.integers(-3, 4)
        for b in (rng.normal(size=5), rng.normal(size=(5, 5)), rng.normal(size=(5, 3))):
            want = a @ b
            got = times(a, b)
            assert got.shape == want.shape
            scale = np.abs(a) @ np.abs(b)  # the size of the sums' terms: the rounding's scale
            worst = max(worst, float((np.abs(got - want) / np.where(scale > 0, scale, 1.0)).max()))
    assert worst <= 8 * np.finfo(float).eps
