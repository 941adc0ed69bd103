"""Behaviour of the tracker core (LDA, DTM) on tiny hand-built cases."""
import numpy as np
import pytest

from edge_node.core import TrackerConfig
from edge_node.core.association import Candidate, LocalDataAssociation, Observation
from edge_node.core.gallery import Gallery
from edge_node.core import manager
from edge_node.core.evidence import PairEvidence
from edge_node.core.manager import MergeView, find_merges
from fakes import SELECTIVE, det, graph as build, identity, make_nodes, step
from protocol import codec
from sim_cluster.network.topology import diameter


def associate(trackers, obs, cfg):
    return LocalDataAssociation(cfg, cfg.use_appearance)(trackers, obs)


def _gallery(pid):
    return Gallery(20, 20, [identity(pid)])


def test_lda_appearance_fixes_a_geometric_swap():
    """Two detections each geometrically closer to the other person's prediction: geometry
    alone (dkf) swaps them; geometry x appearance (dkf+lda, eq. 7) does not."""
    P = np.diag([0.04, 0.04, 0.01, 0.01, 0.1, 0.1])
    R = np.diag([0.01, 0.01, 0.01, 0.01])
    tA = Candidate(np.array([0.0, 0, 0.5, 1.7, 0, 0]), P, _gallery(1))
    tB = Candidate(np.array([1.0, 0, 0.5, 1.7, 0, 0]), P, _gallery(2))
    oA = Observation(np.array([0.6, 0, 0.5, 1.7]), R, identity(1))  # person 1, near B
    oB = Observation(np.array([0.4, 0, 0.5, 1.7]), R, identity(2))  # person 2, near A
    geometric = associate([tA, tB], [oA, oB], TrackerConfig(use_appearance=False))
    assert geometric == [(0, 1), (1, 0)]  # swapped
    with_appearance = associate([tA, tB], [oA, oB], TrackerConfig(use_appearance=True))
    assert with_appearance == [(0, 0), (1, 1)]


def test_appearance_matrix_scores_only_the_pairs_asked_for():
    """Eq. 7 per pair, checked against cosine distances computed here one by one: the minimum
    of ``1 - cos`` over a tracker's gallery where ``where`` allows the pair, ``unknown`` where
    it does not, where the tracker has no gallery or the measurement no descriptor."""
    from edge_node.core.association import appearance_matrix
    rng = np.random.default_rng(3)
    galleries = [Gallery(20, 20, list(rng.normal(size=(k, 16)))) if k else None for k in (3, 0, 1, 5)]
    trackers = [Candidate(np.zeros(6), np.eye(6), g) for g in galleries]
    descs = [rng.normal(size=16), None, rng.normal(size=16), rng.normal(size=16)]
    obs = [Observation(np.zeros(4), np.eye(4), d) for d in descs]
    where = np.array([[1, 1, 0, 1], [1, 1, 1, 1], [0, 0, 1, 0], [1, 0, 1, 1]], bool)
    A = appearance_matrix(trackers, obs, 7.0, where=where)
    for i, g in enumerate(galleries):
        for j, d in enumerate(descs):
            if g is None or d is None or not where[i, j]:
                assert A[i, j] == 7.0
            else:
                rows = g.matrix()
                cos = rows @ d / (np.linalg.norm(rows, axis=1) * np.linalg.norm(d))
                assert A[i, j] == pytest.approx(1.0 - cos.max(), abs=1e-12)
    assert np.isclose(A, appearance_matrix(trackers, obs, 7.0), atol=0)[where].all()


def test_mahalanobis_matrix_is_each_pairs_distance():
    """Eq. 5 per pair, checked against ``sqrt(e^T V^-1 e)`` solved here pair by pair, with
    ``V = P_xy + R_xy`` and ``e`` the ground innovation, on rectangular tables both ways."""
    from edge_node.core.association import mahalanobis_matrix
    rng = np.random.default_rng(5)

    def spd(k):
        A = rng.normal(size=(k, k))
        return A @ A.T + 0.1 * np.eye(k)
    for n, m in ((4, 3), (2, 6), (1, 1)):
        trackers = [Candidate(rng.normal(size=6), spd(6), None) for _ in range(n)]
        obs = [Observation(rng.normal(size=4), spd(4), None) for _ in range(m)]
        d = mahalanobis_matrix(trackers, obs)
        assert d.shape == (n, m)
        for i, t in enumerate(trackers):
            for j, o in enumerate(obs):
                e = o.z[:2] - t.x_bar[:2]
                V = t.P[:2, :2] + o.R[:2, :2]
                assert d[i, j] == pytest.approx(np.sqrt(e @ np.linalg.solve(V, e)), rel=1e-12)


def test_lda_gate_rejects_far_pairs():
    P = np.eye(6) * 0.01
    R = np.eye(4) * 0.01
    t = Candidate(np.zeros(6), P, None)
    far = Observation(np.array([1.0, 0, 0.5, 1.7]), R, None)  # d = 1/sqrt(0.02) = 7 > tau = 3
    assert associate([t], [far], TrackerConfig(use_appearance=False)) == []


def test_crossing_people_that_turn_back_keep_their_ids_with_appearance():
    """Two people walk towards each other, meet and turn back. A constant-velocity prediction
    carries each through the other, so geometry alone swaps the ids; appearance does not."""
    def run(config):
        nodes = make_nodes({0: ()}, TrackerConfig.for_ablation(config))
        rng = np.random.default_rng(0)
        frames = 120
        for k in range(frames):
            t = k / 25.0
            s = 1.2 * t if k < 60 else 1.2 * (120 - k) / 25.0
            p1, p2 = (3.0 + s, 5.0), (7.0 - s, 5.05)
            tracks = step(nodes, k, {0: [det(*p1, 1, rng), det(*p2, 2, rng)]})[0]
        # who is where at the end: the id on the left should be the one that started left
        left = min(tracks, key=lambda t: t.x[0])
        first = nodes[0]
        return left.id, sorted(first.trackers)
    left_id, ids = run("dkf+lda")
    assert ids == [(0, 0), (0, 1)] and left_id == (0, 0)
    left_id_geo, ids_geo = run("dkf")
    assert left_id_geo != (0, 0)


@pytest.mark.parametrize("topology", ["complete", "chain", "ring"])
def test_simultaneous_inits_converge_to_one_id(topology):
    """All four cameras see one new person from frame 0; each initialises its own tracker at
    frame 1; merges with the smallest id as winner spread until every node holds (0, 0)."""
    adj = build(topology, 4)
    nodes = make_nodes(adj, TrackerConfig())
    rng = np.random.default_rng(1)
    settled = None
    for k in range(12):
        x = 4.0 + 0.04 * k
        out = step(nodes, k, {i: [det(x, 5.0, 7, rng)] for i in adj})
        if k >= 1 and all([t.id for t in out[i]] == [(0, 0)] for i in adj):
            settled = settled if settled is not None else k
    assert settled is not None and settled <= 1 + diameter(adj) + 1
    assert all(sorted(n.trackers) == [(0, 0)] for n in nodes.values())


def test_duplicate_from_neighbour_and_own_camera_merges():
    """Node 1's camera is 0.8 m off from node 0's, and its R is tight, so its detection fails
    the LDA gate of the network's tracker. Node 1 first holds the person only through node 0
    (its camera does not see them). When its camera starts seeing the person, the second
    association stage takes the detection into the network's tracker (within ``tau_gda``):
    never a second tracker. Without that stage node 1 starts its own tracker, which node 1 (the
    camera that started it, and sees nobody else there) merges into the network's in the frame
    it is born: their galleries match and they are within ``tau_gda``."""
    def run(recover):
        cfg = TrackerConfig(calib_sigma=0.05, registration=False, recover=recover, **SELECTIVE)
        nodes = make_nodes({0: (1,), 1: (0,)}, cfg, offsets={1: (0.8, 0.0)})
        rng = np.random.default_rng(2)
        counts = []
        for k in range(40):
            x = 3.0 + 0.03 * k
            dets = {0: [det(x, 5.0, 3, rng)], 1: [det(x, 5.0, 3, rng)] if k >= 15 else []}
            out = step(nodes, k, dets)
            counts.append(len(out[1]))
        return cfg, nodes, counts, out

    cfg, nodes, counts, out = run(recover=True)
    assert counts[1:] == [1] * 39 and nodes[1].stats.births == 0
    assert [t.id for t in out[1]] == [(0, 0)] and [t.id for t in out[0]] == [(0, 0)]

    cfg, nodes, counts, out = run(recover=False)
    assert counts[1:] == [1] * 39
    assert nodes[1].stats.births >= 1 and nodes[1].stats.merged >= 1
    assert [t.id for t in out[1]] == [(0, 0)] and [t.id for t in out[0]] == [(0, 0)]


def test_without_manager_duplicates_stay():
    cfg = TrackerConfig.for_ablation("dkf+lda", calib_sigma=0.05, registration=False,
                                     recover=False)
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg, offsets={1: (0.8, 0.0)})
    rng = np.random.default_rng(2)
    for k in range(40):
        x = 3.0 + 0.03 * k
        out = step(nodes, k, {0: [det(x, 5.0, 3, rng)], 1: [det(x, 5.0, 3, rng)] if k >= 15 else []})
        if k == 16:
            assert len(nodes[1].trackers) == 2  # a duplicate: the neighbour's tracker and its own
    # Later each camera keeps what it sees itself (local drop), so the two cameras end up
    # naming one person differently: the network does not agree on an id.
    ids = {i: sorted(t.id for t in out[i]) for i in out}
    assert ids[0] != ids[1] or len(ids[0]) > 1


def test_unseen_target_dropped_everywhere_within_kappa_plus_diameter():
    adj = build("chain", 4)
    cfg = TrackerConfig()
    nodes = make_nodes(adj, cfg)
    rng = np.random.default_rng(3)
    last_seen = 10
    alive_until = {i: None for i in adj}
    for k in range(60):
        dets = {0: [det(2.0, 2.0, 5, rng)]} if k <= last_seen else {}
        step(nodes, k, dets)
        for i in adj:
            if nodes[i].trackers:  # held (reported or coasting), not yet dropped
                alive_until[i] = k
    bound = last_seen + cfg.kappa + diameter(adj)
    for i in adj:
        assert alive_until[i] is not None  # the far end of the chain did hear of it
        assert alive_until[i] <= bound
    assert alive_until[0] >= last_seen + cfg.kappa  # not before kappa frames unseen


def test_coasting_tracker_is_held_but_not_reported():
    """A person unseen by every camera: the tracker is reported ``report_coast`` more frames,
    then only held (predicted, kept for re-association) until ``ell`` passes ``kappa``; seen
    again within that time it is reported again under the same id."""
    cfg = TrackerConfig(report_coast=2)
    nodes = make_nodes({0: ()}, cfg)
    rng = np.random.default_rng(11)
    reported, held = [], []
    for k in range(30):
        seen = k < 10 or k >= 18
        out = step(nodes, k, {0: [det(3.0, 3.0, 4, rng)] if seen else []})
        reported.append({t.id for t in out[0]})
        held.append(set(nodes[0].trackers))
        assert {t.id for t in nodes[0].tracks()} == reported[-1]
    assert reported[9] == {(0, 0)}
    assert reported[10] == reported[11] == {(0, 0)}  # coasting 1, 2 frames: still reported
    assert reported[12] == set() and held[12] == {(0, 0)}  # coasting 3 frames: held only
    assert reported[18] == {(0, 0)}  # seen again: the same tracker, reported at once
    assert nodes[0].stats.births == 1


def test_a_target_seen_far_away_in_the_network_is_reported_everywhere():
    """Coasting is ``ell`` *growing*, not its value: the far end of a chain holds ell = hops - 1
    for a target only node 0 sees, and reports it every frame."""
    adj = build("chain", 4)
    nodes = make_nodes(adj, TrackerConfig(report_coast=0, **SELECTIVE))
    rng = np.random.default_rng(12)
    for k in range(40):
        out = step(nodes, k, {0: [det(2.0 + 0.02 * k, 2.0, 5, rng)]})
        if k >= 10:
            assert all(len(out[i]) == 1 for i in adj), (k, out)
    assert [out[i][0].ell for i in sorted(adj)] == [0, 0, 1, 2]


def test_returning_person_gets_their_old_id():
    nodes = make_nodes({0: ()}, TrackerConfig())
    rng = np.random.default_rng(4)
    ids = []
    for k in range(120):
        present = k < 30 or k >= 70
        other = [det(8.0, 8.0, 9, rng)] if k >= 75 else []
        out = step(nodes, k, {0: ([det(3.0, 3.0, 4, rng)] if present else []) + other})
        ids.append({t.id for t in out[0]})
    assert ids[20] == {(0, 0)}
    assert ids[60] == set()  # dropped after kappa frames
    assert (0, 0) in ids[-1]  # re-identified: old id back
    assert (0, 1) in ids[-1]  # while a different person gets a new one
    assert nodes[0].stats.reidentified == 1


def test_find_merges_needs_co_motion_for_established_trackers():
    """Two established trackers of one look merge only once the cameras' co-motion evidence
    reaches ``merge_llr``; appearance can forbid a merge but never hurries one. Here camera 0
    (this node's) measures one and neighbour 1's camera the other: each saw one person there,
    2 ln(1 / comotion_miss) = 2 ln 2 = 1.386 nats a frame, so 5 nats take 4 frames."""
    cfg = TrackerConfig(comotion_miss=0.5, merge_llr=5.0)
    g = _gallery(1)
    a = MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset({0}))
    b = MergeView((1, 0), np.array([0.5, 0.0]), g, False, frozenset(), measured_by=frozenset({1}))
    streaks = PairEvidence()
    assert [find_merges([a, b], streaks, cfg) for _ in range(3)] == [[], [], []]
    assert streaks[(0, 0), (1, 0)] == pytest.approx(3 * 2 * np.log(2))
    assert find_merges([a, b], streaks, cfg) == [((1, 0), (0, 0))]
    # measured by nobody: no evidence either way, never merged
    a_, b_ = (MergeView(v.id, v.xy, g, False, frozenset()) for v in (a, b))
    assert all(find_merges([a_, b_], PairEvidence(), cfg) == [] for _ in range(30))
    # identical galleries 1.2 m apart (beyond comotion_gate, within tau_gda): never merged
    far = MergeView((1, 0), np.array([1.2, 0.0]), g, False, frozenset(), measured_by=frozenset({1}))
    assert all(find_merges([a, far], streaks, cfg) == [] for _ in range(10))
    # the camera that starts a tracker merges it at once into one of the same look within
    # tau_gda (it sees nobody else there), and so do two trackers both new this frame (the
    # paper's simultaneous initialisations)...
    started = MergeView((1, 1), np.array([1.2, 0.0]), g, True, frozenset(), started=True)
    assert find_merges([a, started], PairEvidence(), cfg) == [((1, 1), (0, 0))]
    both = [MergeView((0, 1), np.array([0.0, 0.0]), g, True, frozenset()),
            MergeView((1, 1), np.array([1.2, 0.0]), g, True, frozenset())]
    assert find_merges(both, PairEvidence(), cfg) == [((1, 1), (0, 1))]
    # ...but a tracker adopted from a neighbour (new here, started elsewhere) merges at once
    # into an established one only right on top of it (under half the comotion_gate),
    # whatever it looks like: a look-alike next to it may be someone else
    for gallery in (g, Gallery(20, 20)):
        a0 = MergeView((0, 0), np.array([0.0, 0.0]), gallery, False, frozenset())
        near = MergeView((1, 1), np.array([0.4, 0.0]), gallery, True, frozenset())
        off = MergeView((1, 1), np.array([0.6, 0.0]), gallery, True, frozenset())
        assert find_merges([a0, near], PairEvidence(), cfg) == [((1, 1), (0, 0))]
        assert find_merges([a0, off], PairEvidence(), cfg) == []
    # two trackers this node's camera saw as two measurements are never merged
    c = MergeView((0, 0), np.array([0.0, 0.0]), g, True, frozenset({0}))
    d = MergeView((1, 0), np.array([0.1, 0.0]), g, True, frozenset({0}))
    assert find_merges([c, d], PairEvidence(), cfg) == []
    # nor two whose entries from one neighbour both carry a measurement (it saw two people),
    # however alike they look
    e = MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset(), measured_by=frozenset({3}))
    f = MergeView((1, 0), np.array([0.1, 0.0]), g, False, frozenset(), measured_by=frozenset({3}))
    assert all(find_merges([e, f], streaks, cfg) == [] for _ in range(10))
    # different appearance: never merged
    h = MergeView((1, 0), np.array([0.1, 0.0]), _gallery(2), True, frozenset(),
                  measured_by=frozenset({1}))
    assert all(find_merges([a, h], streaks, cfg) == [] for _ in range(10))


def test_co_motion_remembers_that_two_trackers_were_seen_as_two_people():
    """Evidence against a merge (a camera measured both: ln(comotion_split / (1 -
    comotion_miss)) = ln(0.02 / 0.5) = -3.219 nats a frame) is kept while both trackers live,
    also while they are apart, down to ``merge_llr_floor``; evidence for one target is
    forgotten when they part. Two people seen as two for 3 frames then hidden from every
    camera but one each need 5 + 3 x 3.219 = 14.66 nats, 11 frames of 1.386, not 4."""
    cfg = TrackerConfig(comotion_miss=0.5, comotion_split=0.02, merge_llr=5.0,
                        merge_llr_floor=-20.0)
    g = _gallery(1)
    two = [MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset({0})),
           MergeView((1, 0), np.array([0.6, 0.0]), g, False, frozenset({0}))]
    one_each = [MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset({0})),
                MergeView((1, 0), np.array([0.6, 0.0]), g, False, frozenset(),
                          measured_by=frozenset({1}))]
    apart = [one_each[0], MergeView((1, 0), np.array([5.0, 0.0]), g, False, frozenset())]
    key = ((0, 0), (1, 0))
    ev = PairEvidence()
    assert all(find_merges(two, ev, cfg) == [] for _ in range(3))
    assert ev[key] == pytest.approx(3 * np.log(0.02 / 0.5))
    assert all(find_merges(apart, ev, cfg) == [] for _ in range(50))  # kept while apart
    assert ev[key] == pytest.approx(3 * np.log(0.02 / 0.5))
    got = [find_merges(one_each, ev, cfg) for _ in range(11)]
    assert got[:10] == [[]] * 10 and got[10] == [((1, 0), (0, 0))]
    # the floor: 100 frames seen as two weigh no more than -20 nats: 5 + 20 = 25 nats, 19 frames
    ev = PairEvidence()
    for _ in range(100):
        find_merges(two, ev, cfg)
    assert ev[key] == -20.0
    got = [find_merges(one_each, ev, cfg) for _ in range(19)]
    assert got[:18] == [[]] * 18 and got[18] == [((1, 0), (0, 0))]
    # evidence for one target is forgotten when they part; a tracker gone takes its pairs along
    ev = PairEvidence()
    find_merges(one_each, ev, cfg)
    assert ev[key] > 0
    find_merges(apart, ev, cfg)
    assert key not in ev
    find_merges(two, ev, cfg)
    find_merges(two[:1], ev, cfg)
    assert key not in ev


def test_co_motion_remembers_two_people_a_camera_saw_as_two_while_far_apart():
    """Two trackers one camera measures at once, 3 m apart (farther than any merge rule
    reaches: no co-motion is scored there), are two people: a detector splits one person into
    two boxes (``comotion_split``) a body's width apart, never metres. Each such frame adds
    ln(0.02 / 0.5) = -3.219 nats, kept while both trackers live, as within the gate. Two
    people seen as two for 5 frames while 3 m apart, who then walk together 0.7 m apart, one
    hidden behind the other from each of two cameras (each measures one of the pair:
    2 ln 2 = 1.386 nats a frame), need 30 + 5 x 3.219 = 46.09 nats, 34 frames, not 22
    (terrace-full chain, seed 2, ``naive_yield``: such a pair merged on every node after 20
    frames together)."""
    cfg = TrackerConfig()  # comotion_miss 0.5, comotion_split 0.02, merge_llr 30, floor -70
    g = _gallery(1)
    far = [MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset({0})),
           MergeView((1, 0), np.array([3.0, 0.0]), g, False, frozenset({0}))]
    near = [MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset({0})),
            MergeView((1, 0), np.array([0.7, 0.0]), g, False, frozenset(),
                      measured_by=frozenset({1}))]
    key = ((0, 0), (1, 0))
    ev = PairEvidence()
    assert all(find_merges(far, ev, cfg) == [] for _ in range(5))
    assert ev[key] == pytest.approx(5 * np.log(0.02 / 0.5))
    got = [find_merges(near, ev, cfg) for _ in range(34)]
    assert got[:33] == [[]] * 33 and got[33] == [((1, 0), (0, 0))]
    # seen apart by a neighbour's camera too (its entries of both carry a measurement)
    by_neighbour = [MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset(),
                              measured_by=frozenset({2})),
                    MergeView((1, 0), np.array([0.0, 3.0]), g, False, frozenset(),
                              measured_by=frozenset({2}))]
    ev = PairEvidence()
    find_merges(by_neighbour, ev, cfg)
    assert ev[key] == pytest.approx(np.log(0.02 / 0.5))
    # far apart and each measured by a different camera, or by none: nothing said
    ev = PairEvidence()
    find_merges([far[0], MergeView((1, 0), np.array([3.0, 0.0]), g, False, frozenset({1}))],
                ev, cfg)
    find_merges([far[0], MergeView((1, 0), np.array([3.0, 0.0]), g, False, frozenset())],
                ev, cfg)
    assert key not in ev
    # down to the floor, like the evidence within the gate
    ev = PairEvidence()
    for _ in range(100):
        find_merges(far, ev, cfg)
    assert ev[key] == -70.0
    # and forgotten with a tracker that is gone
    find_merges(far[:1], ev, cfg)
    assert key not in ev


def test_far_apart_counts_each_camera_that_measured_both():
    """Per pair, every camera that measured both trackers far apart adds ln(0.02 / 0.5) once:
    camera 0 (this node's) measures a, b and c, 3 m apart in a row; a neighbour's camera 5
    measures a and c (6 m apart); camera 7 measures b alone. So a-b and b-c are seen as two by
    one camera, a-c by two; the pairs camera 7 takes part in gain nothing from it."""
    cfg = TrackerConfig()
    g = _gallery(1)
    a = MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset({0}),
                  measured_by=frozenset({5}))
    b = MergeView((0, 1), np.array([3.0, 0.0]), g, False, frozenset({0}),
                  measured_by=frozenset({7}))
    c = MergeView((2, 0), np.array([6.0, 0.0]), g, False, frozenset({0}),
                  measured_by=frozenset({5}))
    ev = PairEvidence()
    assert find_merges([c, a, b], ev, cfg) == []
    one = np.log(0.02 / 0.5)
    assert ev == pytest.approx({((0, 0), (0, 1)): one, ((0, 1), (2, 0)): one,
                                ((0, 0), (2, 0)): 2 * one})


def test_tracker_is_unit_invariant():
    """The same world in centimetres (units_per_metre=100) gives the same ids and the same
    states scaled by 100: every length parameter is in metres and converted, and the consensus
    term is evaluated in metres. Up to the wire's rounding, which is not exact under a change of
    unit (a float16 factor rounds differently once scaled): it moves a measurement by at most
    2**-11 of its innovation, so states may differ by a fraction of a millimetre."""
    from edge_node.geometry import Camera
    from edge_node.core.node import CameraNode
    from fakes import topdown_camera
    from protocol import codec

    def run(scale):
        cfg = TrackerConfig(units_per_metre=scale)
        adj = build("ring", 3)
        nodes = {}
        for i in adj:
            G = topdown_camera(i, (0.1 * i, 0.0)).G.copy()
            G[:2] *= scale  # image -> ground in the new unit
            nodes[i] = CameraNode(Camera(i, (1000, 1000), G), adj[i], cfg, "t")
        rng = np.random.default_rng(5)
        out = []
        for k in range(60):
            dets = {i: [det(3 + 0.03 * k, 4.0, 1, rng), det(6.0, 3 + 0.02 * k, 2, rng)]
                    for i in adj if (k + i) % 5}
            msgs = {i: codec.encode(n.prepare(k, dets.get(i, []))) for i, n in nodes.items()}
            out.append({i: n.update([codec.decode(msgs[j]) for j in n.neighbours])
                        for i, n in nodes.items()})
        return out

    a, b = run(1.0), run(100.0)
    for fa, fb in zip(a, b):
        for i in fa:
            assert [t.id for t in fa[i]] == [t.id for t in fb[i]]
            for ta, tb in zip(fa[i], fb[i]):
                np.testing.assert_allclose(tb.x / 100.0, ta.x, rtol=1e-4, atol=2**-11)


def test_stale_messages_fused_once_and_aged():
    """Event-triggered input (update(stale_ok=True)): a neighbour's entry is predicted forward
    and aged; its u, U count once (a duplicate or a re-delivery adds nothing); entries older
    than kappa are forgotten."""
    from edge_node.core import dkf
    from edge_node.core.model import transition

    cfg = TrackerConfig()
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg)
    rng = np.random.default_rng(6)
    msgs = {}
    for k in range(3):  # both see the person: a shared tracker (0, 0)
        msgs = {i: n.prepare(k, [det(3.0 + 0.04 * k, 5.0, 1, rng)]) for i, n in nodes.items()}
        for i, n in nodes.items():
            n.update([msgs[1 - i]] if (i, k) != (1, 2) else [])
    assert sorted(nodes[1].trackers) == [(0, 0)]
    late = msgs[0]  # node 0's frame-2 message: node 1 gets it one frame late, below

    n1 = nodes[1]
    n1.prepare(3, [])
    tr = n1.trackers[(0, 0)]
    x_bar, P = tr.x_bar.copy(), tr.P.copy()
    entry = late.trackers[0]
    n1.update([late, late], stale_ok=True)  # one frame late, delivered twice
    A = transition(cfg.dt)
    expect, _ = dkf.correct(x_bar, P, entry.u, entry.U, [A @ entry.x_bar],
                            own_x_bar_sent=tr.x_bar_sent)
    np.testing.assert_allclose(tr.x_hat, expect, atol=1e-9)  # fused once, x_bar predicted
    # aged by one frame: the neighbour's newest message is a frame old (a late link, not a
    # deliberate silence, which would hold it)
    assert tr.ell == min(tr.ell_sent, entry.ell + 1)

    n1.prepare(4, [])
    tr = n1.trackers[(0, 0)]
    x_bar, P = tr.x_bar.copy(), tr.P.copy()
    n1.update([late], stale_ok=True)  # the same message yet again: no u, U any more
    assert n1.stats.duplicate_messages == 2
    expect, _ = dkf.correct(x_bar, P, np.zeros(6), np.zeros((6, 6)),
                            [transition(2 * cfg.dt) @ entry.x_bar],
                            own_x_bar_sent=tr.x_bar_sent)
    np.testing.assert_allclose(tr.x_hat, expect, atol=1e-9)

    for k in range(5, 5 + cfg.kappa + 1):
        n1.prepare(k, [])
        n1.update([], stale_ok=True)
    assert n1.memory.entries[0] == {}  # forgotten after kappa frames
    n1.prepare(5 + cfg.kappa + 1, [])
    before = n1.stats.ignored_messages
    n1.update([late], stale_ok=True)
    assert n1.stats.ignored_messages == before + 1  # too old to use


def test_a_target_only_a_late_neighbour_sees_is_reported_every_frame():
    """Node 0 alone sees a person and every message to node 1 arrives 1-4 frames late
    (jittered, sometimes two at once, sometimes none). The person is seen all along, so node 1
    reports them every frame: its ``ell`` ages by the link's lag (eq. 8, for the drop), but the
    lag is no news that nobody sees the target. Once node 0 stops seeing the person, node 1
    stops reporting them within ``report_coast`` frames after the news can have arrived (the
    longest lag, 4). Before, node 1 missed the person in 16 of 75 frames."""
    cfg = TrackerConfig(**SELECTIVE)
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg)
    rng, jitter = np.random.default_rng(3), np.random.default_rng(4)
    due: dict[int, list] = {}
    reported = []
    for k in range(100):
        dets = [det(3.0 + 0.02 * k, 5.0, 1, rng)] if k < 80 else []
        m0 = nodes[0].prepare(k, dets)
        nodes[1].prepare(k, [])
        nodes[0].update([], stale_ok=True)
        due.setdefault(k + 1 + int(jitter.integers(0, 4)), []).append(m0)
        out = nodes[1].update(due.pop(k, []), stale_ok=True)
        reported.append(len(out))
    first = next(k for k, n in enumerate(reported) if n)
    assert first <= 1 + cfg.init_observations + 4
    assert reported[first:80] == [1] * (80 - first)
    assert reported[80 + 4 + cfg.report_coast + 1:] == [0] * (100 - 80 - 4 - cfg.report_coast - 1)


def test_targets_only_a_dead_node_saw_are_dropped_by_the_survivors():
    """Node 0 alone sees person 5 and dies at frame 20. Its neighbours stop hearing about the
    person; the ell consensus drops it on every survivor within kappa + diameter frames."""
    adj = build("chain", 4)
    cfg = TrackerConfig()
    nodes = make_nodes(adj, cfg)
    rng = np.random.default_rng(7)
    last_held = {}
    for k in range(70):
        alive = [i for i in adj if not (i == 0 and k >= 20)]
        dets = {0: [det(2.0 + 0.02 * k, 2.0, 5, rng)]}
        msgs = {i: codec.encode(nodes[i].prepare(k, dets.get(i, []))) for i in alive}
        for i in alive:
            nodes[i].update([codec.decode(msgs[j]) for j in nodes[i].neighbours if j in msgs])
            if nodes[i].trackers:
                last_held[i] = k
    for i in (1, 2, 3):
        assert 20 <= last_held[i] <= 20 + cfg.kappa + diameter(adj)


def test_a_cut_chain_keeps_tracking_on_both_sides():
    """A chain 0-1-2-3 cut between 1 and 2: each half keeps tracking what its cameras see."""
    adj = build("chain", 4)
    nodes = make_nodes(adj, TrackerConfig(**SELECTIVE))
    rng = np.random.default_rng(8)
    for k in range(60):
        dets = {0: [det(2.0, 2.0 + 0.02 * k, 1, rng)], 3: [det(7.0, 7.0 - 0.02 * k, 2, rng)]}
        msgs = {i: codec.encode(n.prepare(k, dets.get(i, []))) for i, n in nodes.items()}
        cut = k >= 20 and {(1, 2), (2, 1)}
        out = {i: n.update([codec.decode(msgs[j]) for j in n.neighbours
                            if not (cut and (j, i) in cut)]) for i, n in nodes.items()}
    left = {t.id for i in (0, 1) for t in out[i]}
    right = {t.id for i in (2, 3) for t in out[i]}
    # each half still tracks its own person, with the id the whole network agreed on before
    assert all(len(out[i]) == 1 for i in nodes)
    assert len(left) == 1 and len(right) == 1 and left != right
    assert abs(out[0][0].x[1] - (2.0 + 0.02 * 59)) < 0.3
    assert abs(out[3][0].x[1] - (7.0 - 0.02 * 59)) < 0.3


def test_core_imports_no_heavy_dependency():
    """The tracker core stays testable in microseconds: no Zenoh, Rerun, torch or OpenCV."""
    import subprocess
    import sys

    code = ("import sys, edge_node.core.node, edge_node.core.trigger, protocol.codec; "
            "print(sorted(m for m in ('zenoh', 'rerun', 'torch', 'cv2') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_reidentification_by_appearance_must_be_reachable():
    """A new tracker takes a dropped tracker's id by appearance (eq. 7, ``epsilon``) only if the
    dropped person could have walked there: within ``reid_gate`` plus ``reid_speed`` times the
    frames since the drop (25 fps here)."""
    from edge_node.core.manager import reidentify

    cfg = TrackerConfig()
    old = {(0, 3): _gallery(1), (1, 4): _gallery(2)}
    last = {(0, 3): (100, np.array([0.0, 0.0])), (1, 4): (100, np.array([0.0, 0.0]))}
    reach_1s = cfg.reid_gate + cfg.reid_speed * 1.0  # metres, one second after the drop
    assert reidentify(_gallery(1), old, cfg, 125, np.array([reach_1s - 0.1, 0.0]), last) == (0, 3)
    assert reidentify(_gallery(1), old, cfg, 125, np.array([reach_1s + 0.1, 0.0]), last) is None
    assert reidentify(_gallery(1), old, cfg, 150, np.array([reach_1s + 0.1, 0.0]), last) == (0, 3)
    assert reidentify(_gallery(1), old, cfg) == (0, 3)  # no place given: appearance alone
    assert reidentify(_gallery(3), old, cfg, 125, np.zeros(2), last) is None  # nobody alike


def test_merge_evidence_needs_a_measurement_of_both_here_or_next_door():
    """With ``merge_evidence`` a node merges two look-alike trackers by co-motion only while its
    camera or a neighbour measures each of them; without it, also when only one is measured
    (a camera that sees one person where two trackers are: ln 4 = 1.386 nats a frame, two
    frames to 2.7; two cameras each measuring one of them: 2.77 nats, one frame)."""
    g = _gallery(1)
    half = [MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset({0})),
            MergeView((1, 0), np.array([0.5, 0.0]), g, False, frozenset())]
    near = [MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset({0})),
            MergeView((1, 0), np.array([0.5, 0.0]), g, False, frozenset(), measured_by=frozenset({2}))]
    merge = [((1, 0), (0, 0))]
    for views, on, expected in ((half, False, [[], merge]), (half, True, [[], []]),
                                (near, True, [merge, merge])):  # (a test repeats the pair)
        cfg = TrackerConfig(comotion_miss=0.25, merge_llr=2.7, merge_evidence=on)
        streaks = PairEvidence()
        got = [find_merges(views, streaks, cfg) for _ in range(2)]
        assert got == expected, (on, views[1].measured_by)


def test_the_inbox_takes_one_entry_per_sender_and_surviving_id():
    """A sender that still names both ids of a merge (its message left before it heard of the
    merge) contributes one entry to the survivor: the one under the survivor's own id, in
    whatever row order the sender wrote them; entries stack in sender order."""
    from edge_node.core.entries import Inbox
    from protocol.messages import FrameMessage, TrackerInfo

    aliases = {(1, 4): (0, 2)}  # (1, 4) lost to (0, 2) here

    def info(tid, x0, ell):
        return TrackerInfo(tid, np.full(6, x0), np.zeros(6), np.zeros((6, 6)), ell)

    m1 = FrameMessage("t", 1, 7, (info((1, 4), 1.0, 0), info((0, 2), 2.0, 3), info((3, 1), 9.0, 1)))
    m0 = FrameMessage("t", 0, 7, (info((1, 4), 4.0, 2),))
    inbox = Inbox([m0, m1], aliases)
    assert inbox.ids() == [(0, 2), (3, 1)]
    e = inbox.entries([(0, 2), (3, 1), (5, 5)])
    assert e.rows.tolist() == [0, 0, 1]
    assert e.x_bar[:, 0].tolist() == [4.0, 2.0, 9.0]  # sender 0's alias entry, sender 1's own
    assert e.ell.tolist() == [2, 3, 1]  # eq. 8's received counters, per row
    # sender 1's ell-0 entry was under the alias, not the one taken: nobody is said to see it
    assert inbox.measured == {}
    m1_own_seen = FrameMessage("t", 1, 7, (info((0, 2), 2.0, 0),))
    assert Inbox([m0, m1_own_seen], aliases).measured == {(0, 2): frozenset({1})}
    assert [t.x_bar[0] for t in inbox.infos((0, 2))] == [4.0, 2.0]


def test_entries_are_summed_per_tracker_in_sender_order_as_add_at_does():
    """Eq. 3's sums over a frame's entries: each tracker's start plus its entries one after
    another in sender order, the numbers ``np.add.at`` gives (which the core used before), bit
    for bit; for trackers with 0 to 4 entries, rows of 6 and of 6 x 6, and entries that make
    the order matter (large and small terms)."""
    from edge_node.core.entries import Inbox
    from protocol.messages import FrameMessage, TrackerInfo

    rng = np.random.default_rng(4)
    ids = [(0, k) for k in range(12)]
    msgs = []
    for sender in range(1, 5):  # each names a random subset of the trackers
        named = [t for t in ids if rng.random() < 0.6]
        infos = []
        for t in named:
            scale = 10.0 ** rng.integers(-8, 9)
            U = rng.normal(size=(6, 6)) * scale
            infos.append(TrackerInfo(t, rng.normal(size=6) * scale, rng.normal(size=6) * scale,
                                     U + U.T, 1))
        msgs.append(FrameMessage("t", sender, 3, tuple(infos)))
    e = Inbox(msgs).entries(ids)
    counts = np.bincount(e.rows, minlength=len(ids))
    assert len(set(counts.tolist())) >= 3 and counts.min() <= 1 and counts.max() == 4, counts
    for values, shape in ((e.u, (6,)), (e.U, (6, 6)), (e.x_bar, (6,))):
        start = rng.normal(size=(len(ids),) + shape) * 1e-3
        want = start.copy()
        np.add.at(want, e.rows, values)
        got = e.summed(start, values)
        np.testing.assert_array_equal(got, want)
        # and the order matters for these numbers: summed the other way round they differ
        other = start.copy()
        np.add.at(other, e.rows[::-1], values[::-1])
        assert not np.array_equal(other, want)


def test_a_neighbour_that_saw_a_target_counts_as_seeing_it_without_u_U():
    """The merge exclusion's "a neighbour saw them as two" reads what the neighbour's camera
    saw: an entry with ``ell`` 0 whose measurement the trigger withheld counts, and so does,
    in event-triggered operation, a newest entry up to ``hold_frames`` old that said so."""
    from edge_node.core.entries import Inbox
    from protocol.messages import FrameMessage, TrackerInfo

    cfg = TrackerConfig()
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg)
    node = nodes[1]
    x = np.array([3.0, 5.0, 0.5, 1.7, 0.0, 0.0])

    def entry(ell, measured):
        U = np.diag([4.0, 4.0, 9.0, 9.0, 0.0, 0.0]) if measured else np.zeros((6, 6))
        return TrackerInfo((0, 0), x, U @ x, U, ell)

    def heard(t, frame=0):
        return FrameMessage("t", 0, frame, (t,))

    for t, seen in ((entry(0, True), True), (entry(0, False), True), (entry(2, False), False)):
        measured = Inbox([heard(t)], node.book.aliases).measured
        assert (0 in measured.get((0, 0), frozenset())) == seen, t.ell
    # event-triggered: node 0's frame-3 entry said ell 0; at frame 5 it is held, at 9 too old
    node.memory.remember([heard(entry(0, False), frame=3)])
    for k, seen in ((5, True), (3 + cfg.hold_frames, True), (4 + cfg.hold_frames, False)):
        node.memory.at(k)
        assert ((0, (0, 0)) in node.memory.observed) == seen, k


def test_simultaneous_inits_heard_of_late_merge_at_once():
    """Two cameras start the same person in the same frame; each hears of the other's tracker
    three frames late (event-triggered operation). Had the news come on time the two would
    have been new together (the paper's simultaneous initialisations, merged at once); so they
    are when it comes, although this node's own tracker is no longer new by then. The cameras
    place the person 0.8 m apart (beyond half the ``comotion_gate``: no merge at once by place).
    Before, the pair waited ``comotion_frames`` (terrace-gt with every message 1-4 frames late
    kept such duplicates through its first 40 frames)."""
    cfg = TrackerConfig()
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg)
    rng = np.random.default_rng(5)
    due: dict[int, list] = {}
    held = []
    for k in range(12):
        x = 3.0 + 0.02 * k
        dets = {0: [det(x, 5.0, 7, rng)], 1: [det(x + 0.8, 5.0, 7, rng)]}
        for i, n in nodes.items():
            due.setdefault((1 - i, k + 3), []).append(codec.decode(codec.encode(n.prepare(k, dets[i]))))
        for i, n in nodes.items():
            n.update(due.pop((i, k), []), stale_ok=True)
        held.append({i: sorted(n.trackers) for i, n in nodes.items()})
    first = next(k for k, h in enumerate(held) if h[0])  # the births
    assert held[first] == {0: [(0, 0)], 1: [(1, 0)]}
    # the other's news arrives 3 frames after the births: merged in that frame, for good
    assert all(h == {0: [(0, 0)], 1: [(0, 0)]} for h in held[first + 3:])
    assert nodes[0].stats.merged + nodes[1].stats.merged >= 1


def test_simultaneous_means_before_news_of_the_other():
    """``simultaneous``: both new here; or one new from a neighbour's news of frame ``heard``
    (come late) and the other here since that frame or later, not before it."""
    from edge_node.core.manager import simultaneous
    g = _gallery(1)
    late = MergeView((1, 0), np.array([0.0, 0.0]), g, True, frozenset(), since=10, heard=7)
    assert simultaneous(late, MergeView((0, 0), np.array([0.8, 0.0]), g, False, frozenset(), since=7))
    assert simultaneous(MergeView((0, 0), np.array([0.8, 0.0]), g, False, frozenset(), since=9), late)
    assert not simultaneous(late, MergeView((0, 0), np.array([0.8, 0.0]), g, False, frozenset(),
                                            since=6))
    on_time = MergeView((1, 0), np.array([0.0, 0.0]), g, True, frozenset(), since=10, heard=10)
    assert not simultaneous(on_time, MergeView((0, 0), np.array([0.8, 0.0]), g, False, frozenset(),
                                               since=9))
    cfg = TrackerConfig()
    assert find_merges([late, MergeView((0, 0), np.array([0.8, 0.0]), g, False, frozenset(),
                                        since=8)], PairEvidence(), cfg) == [((1, 0), (0, 0))]


def test_a_track_built_by_the_core_is_a_track():
    """``Track._built`` (what ``update`` returns) sets every field a ``Track`` has, as the
    dataclass does, and stays frozen."""
    import dataclasses
    from edge_node.core.types import Track
    args = ((1, 2), 7, np.arange(6.0), np.eye(6), True, 3, {1: np.ones(4)})
    built, made = Track._built(*args), Track(*args)
    assert [f.name for f in dataclasses.fields(Track)] == list(vars(built))
    assert all(getattr(built, f.name) is getattr(made, f.name) for f in dataclasses.fields(Track))
    with pytest.raises(dataclasses.FrozenInstanceError):
        built.ell = 4


def test_norms_are_numpys_norms_bit_for_bit():
    """``geometry.norms`` (the core's norms, without ``numpy.linalg.norm``'s dispatch) gives
    the same bits as ``numpy.linalg.norm`` on vectors, stacks, pairs of axes and strided views."""
    from edge_node.geometry import norms
    rng = np.random.default_rng(11)
    J = rng.normal(size=(9, 2, 2))
    for x, axis, keep in ((rng.normal(size=(20, 2)) * 1e3, -1, False),
                          (rng.normal(size=(30, 512)), 1, True),
                          (rng.normal(size=(5, 4, 2)) * 1e-3, 2, False),
                          (rng.normal(size=(7, 6, 6)), (-2, -1), False),
                          (J[..., :, 0], -1, False)):
        assert np.array_equal(norms(x, axis=axis, keepdims=keep),
                              np.linalg.norm(x, axis=axis, keepdims=keep))


def test_the_core_s_own_message_block_is_what_the_checked_constructor_makes():
    """``prepare`` builds its message's block without the checked constructor: the same
    columns, dtypes and read-only arrays as ``TrackerBlock(...)`` would make of them, the new
    trackers' appearance included, and no array shared with a tracker's state."""
    from protocol.messages import TrackerBlock
    nodes = make_nodes(build("chain", 2))
    with_appearance, sizes = 0, []
    for k in range(6):
        dets = [det(2.0 + k * 0.04, 3.0, 1), det(6.0, 5.0 - k * 0.04, 2)]
        msgs = {i: n.prepare(k, dets) for i, n in nodes.items()}
        b = msgs[0].block
        sizes.append(len(b))
        checked = TrackerBlock(b.camera, b.counter, b.born, b.ell, b.x_bar, b.u, b.U, b.appearance)
        for name in ("camera", "counter", "born", "ell", "x_bar", "u", "U"):
            got, want = getattr(b, name), getattr(checked, name)
            assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want)
            assert not got.flags.writeable
        assert [r for r, _ in b.appearance] == [r for r, _ in checked.appearance]
        assert all(not a.flags.writeable and a.dtype == np.float64 for _, a in b.appearance)
        with_appearance += bool(b.appearance)
        st = nodes[0].state
        assert not (np.shares_memory(b.x_bar, st.x_bar_sent) or np.shares_memory(b.U, st.U))
        for n in nodes.values():
            n.update([codec.decode(codec.encode(msgs[j])) for j in n.neighbours])
    assert sizes[-1] == 2 and with_appearance == 1  # two trackers, announced once, at birth


def test_eq8_for_all_trackers_at_once_is_each_trackers_minimum():
    """Eq. 8 batched: per tracker the minimum of its own counter and the counters its entries
    carry, checked against ``min`` tracker by tracker; a tracker with no entry keeps its own;
    the paper's ``dkf`` (no manager) keeps its own always."""
    from edge_node.core.manager import DistributedTrackerManager, IndependentTrackers
    rng = np.random.default_rng(8)
    own = rng.integers(0, 6, 12)
    rows = np.sort(rng.integers(0, 12, 30))
    received = rng.integers(0, 6, 30)
    got = DistributedTrackerManager(TrackerConfig()).ells(own.tolist(), rows, received)
    want = [min([int(own[i]), *(int(r) for r, t in zip(received, rows) if t == i)]) for i in range(12)]
    assert got.tolist() == want and got.dtype == np.int64
    assert any(i not in rows for i in range(12)) and got.tolist() != own.tolist()  # both cases occur
    assert IndependentTrackers(TrackerConfig()).ells(own.tolist(), rows, received).tolist() == own.tolist()


def test_a_dropped_tracker_hands_its_id_to_the_duplicate_that_took_its_target_over():
    """``heir``: lost at (0, 0), unseen for ell = 16 frames, dropped at frame 100 (kappa 15, 25
    fps): the reach is reid_gate + reid_speed x 16 / 25 = 1.5 + 1.28 = 2.78 m, and a tracker
    qualifies if it appeared on the node at frame 100 - 16 - 30 = 54 or later, is younger, and
    was never seen beside the lost one as a second person."""
    from edge_node.core.manager import heir
    cfg = TrackerConfig(reid_gate=1.5, reid_speed=2.0, kappa=15, fps=25.0)
    g = Gallery(20, 20)

    def view(tid, x, born, since):
        return MergeView(tid, np.array([x, 0.0]), g, False, frozenset(), born=born, since=since)
    lost = view((0, 1), 0.0, 10, 10)
    young = view((2, 7), 2.7, 60, 60)  # 2.7 m < 2.78 m
    nearer = view((1, 3), 1.0, 70, 70)
    assert heir(lost, 16, [lost, young], 100, {}, cfg) == (2, 7)
    assert heir(lost, 16, [lost, young, nearer], 100, {}, cfg) == (1, 3)
    assert heir(lost, 16, [lost, view((2, 7), 2.9, 60, 60)], 100, {}, cfg) is None  # too far
    assert heir(lost, 16, [lost, view((2, 7), 1.0, 60, 50)], 100, {}, cfg) is None  # came before 54
    assert heir(lost, 16, [lost, view((2, 7), 1.0, 5, 60)], 100, {}, cfg) is None  # older
    # a camera once saw the two as two people: no heir
    assert heir(lost, 16, [lost, nearer], 100, {((0, 1), (1, 3)): -3.2}, cfg) is None
    assert heir(lost, 16, [lost, nearer], 100, {((0, 1), (1, 3)): 4.0}, cfg) == (1, 3)


def test_a_dropped_tracker_passes_its_id_to_the_duplicate_on_its_way_to_merge_into_it():
    """``manager.partner``: the younger tracker with positive co-motion evidence towards the
    dropped one (the most evidence first), never an older one, never one seen as a second
    person, never one without evidence."""
    g = Gallery(20, 20)
    lost = MergeView((0, 0), np.array([0.0, 0.0]), g, False, frozenset(), born=100)
    dup = MergeView((1, 4), np.array([0.5, 0.0]), g, False, frozenset(), born=300)
    dup2 = MergeView((2, 7), np.array([0.2, 0.0]), g, False, frozenset(), born=310)
    older = MergeView((3, 1), np.array([0.1, 0.0]), g, False, frozenset(), born=50)
    views = [lost, dup, dup2, older]
    ev = {((0, 0), (1, 4)): 12.0, ((0, 0), (2, 7)): 4.0, ((0, 0), (3, 1)): 25.0}
    assert manager.partner(lost, views, ev) == (1, 4)  # the most evidence, not the nearest
    ev[((0, 0), (1, 4))] = -3.0  # a camera saw the two as two people
    assert manager.partner(lost, views, ev) == (2, 7)
    assert manager.partner(lost, views, {((0, 0), (3, 1)): 25.0}) is None  # only older
    assert manager.partner(lost, views, {}) is None
    # through the manager: only with heir_pending, and stitch takes precedence
    m = manager.DistributedTrackerManager(TrackerConfig())
    m.evidence = PairEvidence({((0, 0), (2, 7)): 4.0})
    assert m.heir(lost, 16, views, 400) == (2, 7)
    m.cfg = TrackerConfig(heir_pending=False)
    assert m.heir(lost, 16, views, 400) is None
