"""A node's measured re-id (edge_node/core/reidquality.py): the histograms of one person's and
two people's appearance distances, the thresholds they set, what the association learns from
a frame, and the decisions that follow. Expected values are computed here by hand (numpy's
own quantile, cosines of hand-made vectors), not read from the code under test."""
from __future__ import annotations

import numpy as np
import pytest

from edge_node.core import TrackerConfig
from edge_node.core.association import Candidate, LocalDataAssociation, Observation, recover
from edge_node.core.gallery import Gallery
from edge_node.core.evidence import PairEvidence
from edge_node.core.manager import MergeView, find_merges, pair_score, reidentify
from edge_node.core.reidquality import ReidQuality, Thresholds, quantile, samples

CFG = TrackerConfig()  # appearance_gate 0.6, merge_appearance 0.4, epsilon 0.25


def test_histogram_quantiles_bound_the_sample_quantiles():
    rng = np.random.default_rng(3)
    d = rng.uniform(0.1, 0.9, 5000)
    hist = np.histogram(d, bins=200, range=(0.0, 2.0))[0].astype(float)
    for p in (0.01, 0.5, 0.99):
        exact = float(np.quantile(d, p))
        up, low = quantile(hist, p, upper=True), quantile(hist, p, upper=False)
        assert low <= exact <= up and up - low == pytest.approx(0.01)


def test_a_frame_is_counted_as_numpy_histograms_it_on_the_edges_and_between():
    # the learned histograms count each distance in the bin numpy.histogram puts it in, also
    # on an edge, one float either side of it, at 0 and at 2 (its last bin is closed)
    rng = np.random.default_rng(7)
    edges = np.linspace(0.0, 2.0, 201)
    on = rng.choice(edges, 40)
    d = np.concatenate([rng.uniform(0.0, 2.0, 300), on, np.nextafter(on, 3.0), np.nextafter(on, -1.0),
                        [0.0, 2.0, 2.0]]).clip(0.0, 2.0)
    q = ReidQuality(CFG)
    q.learn(d, np.zeros(0))
    assert q.same.tolist() == np.histogram(d, bins=edges)[0].astype(float).tolist()
    assert q.same[-1] >= 2 and q.same.sum() == len(d)


def test_thresholds_stay_configured_until_enough_samples_then_follow_them():
    cfg = CFG.with_(reid_samples=1000, reid_error=0.01)  # 1 %: this test's hand-set rate
    q = ReidQuality(cfg)
    rng = np.random.default_rng(0)
    same = rng.uniform(0.0, 0.8, 999)  # one person: up to 0.8 apart (a weak re-id)
    two = rng.uniform(0.05, 1.5, 5000)  # two people: down to 0.05 apart (look-alikes)
    q.learn(same, two)
    assert q.thresholds == Thresholds.of(cfg) == Thresholds(0.6, 0.4, 0.4, 0.25)
    last = rng.uniform(0.0, 0.8, 1)
    q.learn(last, np.zeros(0))
    t = q.thresholds
    high = float(np.quantile(np.concatenate([same, last]), 0.99))  # about 0.79
    low = float(np.quantile(two, 0.01))  # about 0.0645
    assert high - 0.011 <= t.gate <= high + 0.011 and t.gate == t.veto
    assert t.gate > 0.6  # wider than configured: the person's own detections pass
    assert low - 0.011 <= t.match <= low + 0.011 and t.match == t.epsilon
    assert t.match < 0.25  # tighter: look-alikes neither merge at once nor take ids


def test_a_good_reid_leaves_the_configured_thresholds():
    q = ReidQuality(CFG.with_(reid_samples=100))
    rng = np.random.default_rng(1)
    q.learn(rng.uniform(0.0, 0.3, 2000), rng.uniform(0.6, 1.2, 2000))
    assert q.thresholds == Thresholds.of(CFG)


def test_memory_is_bounded_and_follows_a_change():
    cfg = CFG.with_(reid_samples=100, reid_memory=1000)
    q = ReidQuality(cfg)
    for _ in range(50):
        q.learn(np.full(100, 0.05), np.full(100, 0.9))
    assert q.same.sum() <= 1000 and q.two.sum() <= 1000
    assert q.thresholds == Thresholds.of(cfg)
    for _ in range(50):  # the light changes: one person's distances grow to 0.75
        q.learn(np.full(100, 0.75), np.full(100, 0.9))
    assert q.same.sum() <= 1000 and q.thresholds.gate == pytest.approx(0.76)


def test_nan_distances_are_not_counted():
    q = ReidQuality(CFG)
    q.learn(np.array([np.nan, 0.1]), np.array([np.inf, np.nan]))
    assert q.same.sum() == 1 and q.two.sum() == 0


def test_lone_pairs_are_each_others_only_partner_in_the_gate():
    allowed = np.array([[1, 0, 0, 0],
                        [0, 1, 1, 0],   # tracker 1 has two detections: no pair
                        [0, 0, 0, 1],
                        [0, 0, 0, 1]], bool)  # detection 3 has two trackers: no pair
    s_a = np.arange(16, dtype=float).reshape(4, 4) / 100
    rows, cols, d = samples(allowed, s_a)
    assert rows.tolist() == [0] and cols.tolist() == [0] and d.tolist() == [0.0]


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def test_the_association_learns_one_person_from_its_lone_pairs():
    a, b = _unit([1, 0, 0, 0]), _unit([0, 1, 0, 0])
    da, db = _unit([1, 0.2, 0, 0]), _unit([0.3, 1, 0, 0])  # each person's detection today
    P = np.eye(6) * 0.01
    trackers = [Candidate(np.array([0.0, 0, 0.5, 1.7, 0, 0]), P, Gallery(descriptors=[a])),
                Candidate(np.array([5.0, 0, 0.5, 1.7, 0, 0]), P, Gallery(descriptors=[b])),
                Candidate(np.array([9.0, 0, 0.5, 1.7, 0, 0]), P, Gallery(descriptors=[b])),
                Candidate(np.array([9.05, 0, 0.5, 1.7, 0, 0]), P, Gallery(descriptors=[a]))]
    R = np.eye(4) * 0.01
    obs = [Observation(np.array([0.05, 0, 0.5, 1.7]), R, da),
           Observation(np.array([5.05, 0, 0.5, 1.7]), R, db),
           Observation(np.array([9.02, 0, 0.5, 1.7]), R, da)]  # two trackers in its gate
    q = ReidQuality(CFG)
    lda = LocalDataAssociation(CFG, True, q)
    assert lda(trackers, obs)[:2] == [(0, 0), (1, 1)]
    edges = np.linspace(0, 2, 201)
    bins = sorted(int(np.searchsorted(edges, 1 - g @ d, "right") - 1) for g, d in ((a, da), (b, db)))
    assert sorted(np.repeat(np.arange(200), q.same.astype(int)).tolist()) == bins
    assert q.two.sum() == 0  # two people come from the manager's nearby pairs


def test_the_manager_learns_two_people_from_nearby_pairs_seen_as_two():
    a, b, c = _unit([1, 0, 0, 0]), _unit([1, 1, 0, 0]), _unit([0, 0, 1, 0])
    views = [_view((0, 1), (0, 0), a, seen_by=frozenset({0})),
             _view((1, 1), (0.5, 0), b, seen_by=frozenset({0})),  # camera 0 sees both: two
             _view((2, 1), (0.8, 0), c, seen_by=frozenset({1}))]  # near, not seen as two
    q = ReidQuality(CFG)
    find_merges(views, PairEvidence(), CFG, learn=q)
    assert q.two.sum() == 1
    bin_ = int(np.searchsorted(np.linspace(0, 2, 201), 1 - a @ b, "right") - 1)
    assert q.two[bin_] == 1


def _view(tid, xy, desc, seen_by=frozenset(), new=False, **kw):
    return MergeView(tid, np.asarray(xy, float), Gallery(descriptors=[desc]), new=new,
                     seen_by=seen_by, **kw)


def test_appearance_that_cannot_tell_leaves_the_merge_to_co_motion():
    a, b = _unit([1, 0.55, 0, 0]), _unit([1, 0, 0, 0])
    s_a = 1 - a @ b  # 0.124
    new = _view((0, 1), (0, 0), a, new=True, started=True, born=10)
    old = _view((1, 1), (0.6, 0), b, new=False)
    assert pair_score(new, old, CFG) == (pytest.approx(s_a * 0.6 / 1.5), True)  # at once
    learned = Thresholds(gate=0.6, veto=0.4, match=0.1, epsilon=0.1)  # look-alikes at 0.1
    score, at_once = pair_score(new, old, CFG, learned)
    assert not at_once  # co-motion decides, as without descriptors
    assert pair_score(new, old, CFG, Thresholds(0.6, 0.1, 0.1, 0.1)) is None  # vetoed


def test_a_learned_epsilon_keeps_look_alikes_from_taking_ids():
    a, b = _unit([1, 0.55, 0, 0]), _unit([1, 0, 0, 0])
    old = {(5, 1): Gallery(descriptors=[b])}
    assert reidentify(Gallery(descriptors=[a]), old, CFG) == (5, 1)
    assert reidentify(Gallery(descriptors=[a]), old, CFG, epsilon=0.1) is None


def test_recover_falls_back_on_the_co_motion_gate_where_appearance_cannot_tell():
    a, b = _unit([1, 0.55, 0, 0]), _unit([1, 0, 0, 0])  # 0.124 apart
    P = np.eye(6)
    R = np.eye(4)
    trackers = [Candidate(np.array([0.0, 0, 0.5, 1.7, 0, 0]), P, Gallery(descriptors=[b]))]
    far = [Observation(np.array([1.2, 0, 0.5, 1.7]), R, a)]  # within tau_gda, not comotion_gate
    near = [Observation(np.array([0.8, 0, 0.5, 1.7]), R, a)]
    unsure = Thresholds(gate=0.6, veto=0.4, match=0.1, epsilon=0.1)
    assert recover(trackers, far, [], CFG) == [(0, 0)]
    assert recover(trackers, far, [], CFG, unsure) == []
    assert recover(trackers, near, [], CFG, unsure) == [(0, 0)]
