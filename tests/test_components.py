"""Unit tests of the core's components, each on its own with tiny hand-made inputs: the gallery
(eq. 7), the initiator (local births, paper III-C), the measurement model (``z, R_i``), the
identity book, and a node assembled with fake components."""
import numpy as np
import pytest

from edge_node.core import CameraNode, Components, TrackerConfig, assemble
from edge_node.core.association import LocalDataAssociation, Observation
from edge_node.core.gallery import Gallery, cosine_distance
from edge_node.core.identity import IdentityBook
from edge_node.core.initiator import Initiator
from edge_node.core.reidstore import ReidStore
from edge_node.core.manager import DistributedTrackerManager, IndependentTrackers, reidentify
from edge_node.core.measurement import measure
from edge_node.geometry import Camera
from fakes import box_at, det, identity, topdown_camera


def unit(*v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# -- gallery ----------------------------------------------------------------------------------
def test_gallery_distance_is_the_minimum_cosine_distance():
    g = Gallery(5, 1, [unit(1, 0, 0), unit(0, 1, 0)])
    q = np.array([3.0, 4.0, 0.0])  # cos to the two: 0.6 and 0.8
    assert g.distance(q) == pytest.approx(1 - 0.8)
    np.testing.assert_allclose(g.distances(np.array([q, [0, 0, 2.0]])), [0.2, 1.0])
    assert cosine_distance(q, np.array([1.0, 0, 0])) == pytest.approx(0.4)
    other = Gallery(5, 1, [unit(1, 1, 0)])
    assert g.distance_to(other) == pytest.approx(1 - np.sqrt(0.5))
    assert np.isnan(Gallery().distance(q)) and np.isnan(g.distance_to(Gallery()))


def test_gallery_keeps_one_descriptor_every_n_frames_and_drops_the_oldest():
    g = Gallery(capacity=3, every=10)
    stored = [k for k in range(0, 60) if g.offer(identity(1), k)]
    assert stored == [0, 10, 20, 30, 40, 50]  # one every 10 frames
    assert len(g) == 3  # bounded: the oldest went first
    g2 = Gallery(capacity=2, every=1)
    for i in range(3):
        g2.add(unit(*np.eye(3)[i]))
    np.testing.assert_allclose(g2.newest(2), [[0, 1, 0], [0, 0, 1]])
    np.testing.assert_allclose(g2.newest(1), [[0, 0, 1]])


def test_gallery_admits_only_descriptors_that_look_like_it():
    g = Gallery(5, 1, [identity(1)])
    assert not g.offer(identity(2), 5, admit=0.35)  # another person: not learned
    assert g.offer(identity(1) + 0.01, 6, admit=0.35)
    assert len(g) == 2
    assert not g.offer(None, 7)


def test_gallery_copy_is_independent():
    g = Gallery(5, 1, [identity(1)])
    c = g.copy()
    c.add(identity(2))
    assert len(g) == 1 and len(c) == 2


# -- initiator ----------------------------------------------------------------------------------
def obs(x, y, pid=None):
    return Observation(np.array([x, y, 0.5, 1.7]), np.eye(4) * 0.01,
                       None if pid is None else identity(pid))


def test_two_close_observations_make_a_birth():
    ini = Initiator(TrackerConfig())
    assert ini.step(0, [obs(1.0, 1.0, 1)]) == []
    births = ini.step(1, [obs(1.3, 1.0, 1)])  # 0.3 m away, within candidate_gate 0.8
    assert len(births) == 1 and births[0].frames == [0, 1]
    assert ini.pending == []


def test_far_or_unlike_second_observations_start_their_own_chain():
    cfg = TrackerConfig()
    ini = Initiator(cfg)
    ini.step(0, [obs(1.0, 1.0, 1)])
    assert ini.step(1, [obs(1.0 + 0.81, 1.0, 1)]) == []  # beyond candidate_gate
    assert len(ini.pending) == 2
    ini = Initiator(cfg)
    ini.step(0, [obs(1.0, 1.0, 1)])
    assert ini.step(1, [obs(1.1, 1.0, 2)]) == []  # close, but another person's look
    # without appearance (the dkf configuration) the same pair is a birth
    ini = Initiator(cfg, appearance=False)
    ini.step(0, [obs(1.0, 1.0, 1)])
    assert len(ini.step(1, [obs(1.1, 1.0, 2)])) == 1


def test_a_lone_observation_waits_candidate_max_age_frames():
    cfg = TrackerConfig(candidate_max_age=3)
    ini = Initiator(cfg)
    ini.step(0, [obs(1.0, 1.0)])
    assert len(ini.step(3, [obs(1.1, 1.0)])) == 1  # 3 frames later: still waiting
    ini = Initiator(cfg)
    ini.step(0, [obs(1.0, 1.0)])
    assert ini.step(4, [obs(1.1, 1.0)]) == []  # 4 frames: forgotten, a new chain starts


def test_chains_are_extended_by_the_optimal_assignment():
    """Two pending chains and two new observations where the greedy nearest pick for the first
    chain would steal the second chain's only option."""
    ini = Initiator(TrackerConfig(candidate_gate=1.0))
    ini.step(0, [obs(1.0, 0.0), obs(0.0, 0.0)])  # the chain at 1.0 comes first
    births = ini.step(1, [obs(0.45, 0.0), obs(1.6, 0.0)])
    # chain at 1.0: nearest is 0.45 (0.55 m) but the chain at 0.0 can only take 0.45
    assert sorted((b.observations[0].z[0], b.observations[1].z[0]) for b in births) == \
        [(0.0, 0.45), (1.0, 1.6)]


def test_one_observation_is_enough_when_configured():
    assert len(Initiator(TrackerConfig(init_observations=1)).step(0, [obs(1.0, 1.0)])) == 1


# -- measurement ----------------------------------------------------------------------------------
def test_measurement_of_a_top_down_camera_by_hand():
    """``topdown_camera``: 100 px per metre, linear. Foot point (3, 4) m, box 50 x 170 px:
    z = (3, 4, 0.5, 1.7); R_xy = J diag(s^2/2, s^2) J^T + calib^2 I with J = I / 100."""
    cfg = TrackerConfig(pixel_sigma=2.0, calib_sigma=0.4, size_meas_floor=0.05)
    z, R = measure(topdown_camera(0), box_at(3.0, 4.0), cfg)
    np.testing.assert_allclose(z, [3.0, 4.0, 0.5, 1.7], atol=1e-12)
    s2 = 2.0**2 / 100.0**2
    np.testing.assert_allclose(R[:2, :2], np.diag([s2 / 2 + 0.16, s2 + 0.16]), atol=1e-15)
    # w, h: difference of two edges, sigma sqrt(2) px scaled by metres per pixel, plus the floor
    sw2 = (0.5 / 50 * 2 * np.sqrt(2)) ** 2 + 0.05**2
    sh2 = (1.7 / 170 * 2 * np.sqrt(2)) ** 2 + 0.05**2
    np.testing.assert_allclose(np.diag(R)[2:], [sw2, sh2], rtol=1e-12)
    assert np.count_nonzero(R - np.diag(np.diag(R))) == 0


def test_fixed_R_is_the_papers_constant_covariance():
    z, R = measure(topdown_camera(0), box_at(3.0, 4.0), TrackerConfig(fixed_R=(0.3, 0.1)))
    np.testing.assert_allclose(R, np.diag([0.09, 0.09, 0.01, 0.01]))


def test_far_targets_are_less_certain_through_a_perspective_homography():
    # ground y grows with 1 / (image row distance from the horizon): farther = more metres per px
    G = np.array([[0.01, 0, -5.0], [0, 0, 1.0], [0, 0.002, 0]])
    cam = Camera(0, (1000, 1000), G)
    cfg = TrackerConfig(calib_sigma=0.0)
    near = measure(cam, np.array([480, 700, 40, 200]), cfg)[1]
    far = measure(cam, np.array([490, 300, 20, 100]), cfg)[1]
    assert far[1, 1] > 10 * near[1, 1]


# -- identity book ------------------------------------------------------------------------------
def test_identity_book_ranks_merges_and_announces():
    cfg = TrackerConfig(merge_announce_frames=2)
    book = IdentityBook(3, cfg, first_counter=7)
    assert book.new_id() == (3, 7) and book.new_id() == (3, 8)
    book.note_born((3, 7), 10)
    book.note_born((1, 0), 12)
    # whoever announces it, the older (born 10) survives
    assert book.alias((3, 7), (1, 0)) == ((1, 0), (3, 7))
    assert book.resolve((1, 0)) == (3, 7)
    assert book.alias((1, 0), (3, 7)) is None  # already one id
    first, second, third = book.announcements(), book.announcements(), book.announcements()
    assert [(m.loser, m.winner, m.winner_born) for m in first] == [((1, 0), (3, 7), 10)]
    assert second == first and third == ()


def test_identity_book_memory_is_bounded():
    cfg = TrackerConfig(max_old_trackers=3)
    book = IdentityBook(0, cfg)
    for c in range(10):
        book.retire((1, c), Gallery(), keep_gallery=True, frame=c, xy=np.zeros(2))
        book.retire((2, c), Gallery(), keep_gallery=False)
    assert list(book.old) == [(1, 7), (1, 8), (1, 9)]
    assert sorted(book.last) == [(1, 7), (1, 8), (1, 9)]
    book.old.take((1, 8))  # re-identified: where it was dropped goes with it
    assert sorted(book.last) == [(1, 7), (1, 9)]
    assert len(book.dropped) == 10
    for c in range(100):
        book.alias((5, c), (6, c))
    book.forget(set())
    assert len(book.aliases) <= 10 * cfg.max_old_trackers


def _full_gallery(seed: int, n: int = 20, dim: int = 512) -> Gallery:
    rng = np.random.default_rng(seed)
    return Gallery(20, 1, rng.standard_normal((n, dim)))


def test_reid_store_keeps_float16_within_a_count_and_a_byte_budget():
    assert _full_gallery(0).nbytes == 20 * 512 * 8 == 4 * _full_gallery(0).astype(np.float16).nbytes
    store = ReidStore(max_count=200, max_bytes=5 * 20 * 512 * 2)  # room for five, as float16
    for c in range(500):  # a node that runs for months drops trackers without end
        store.put((0, c), _full_gallery(c, n=1 + c % 20), frame=c, xy=np.array([c, 0.0]))
        assert store.nbytes <= store.max_bytes and len(store) <= store.max_count
        assert set(store.last) <= set(store)
    assert store.nbytes == sum(store[t].nbytes for t in store)
    assert all(store[t].matrix().dtype == np.float16 for t in store)
    assert list(store)[-1] == (0, 499)  # the newest stay
    # a short gallery costs its rows only (not the 20 a live one preallocates)
    store.put((9, 9), _full_gallery(1, n=3))
    assert store[(9, 9)].nbytes == 3 * 512 * 2
    # the count bound still holds where descriptors are small
    small = ReidStore(max_count=3, max_bytes=1 << 30)
    for c in range(10):
        small.put((1, c), _full_gallery(c, n=2, dim=8), frame=c, xy=np.zeros(2))
    assert list(small) == [(1, 7), (1, 8), (1, 9)] and sorted(small.last) == list(small)


def test_reid_store_distances_are_the_float64_galleries_to_float16_rounding():
    store = ReidStore(10, 1 << 20)
    g = _full_gallery(3)
    store.put((0, 1), g)
    q = _full_gallery(4, n=5)
    near = Gallery(20, 1, g.matrix()[:2] + 0.3 * q.matrix()[:2])
    for query in (q, near):
        assert abs(query.distance_to(store[(0, 1)]) - query.distance_to(g)) < 1e-3
    back = store.take((0, 1))  # taken back by a new tracker: float64 again, out of the store
    assert back.matrix().dtype == np.float64 and len(back) == 20 and (0, 1) not in store
    assert store.nbytes == 0
    np.testing.assert_allclose(back.matrix(), g.matrix(), atol=1e-3)
    back.add(q.matrix()[0], 5)  # it lives on as a tracker's gallery
    assert len(back) == 20


def test_reidentification_decides_from_the_float16_store_as_from_float64():
    """Eq. 7 against epsilon over 300 dropped galleries (synthetic OSNet-like descriptors, the
    query seen by another camera), float64 galleries against the store, with epsilon set
    between two of the true matches' distances so that half of them fall on each side."""
    from sim_cluster.scenarios.synthetic.appearance import AppearanceModel

    model, rng = AppearanceModel(seed=1), np.random.default_rng(0)
    plain, store = {}, ReidStore(1000, 1 << 30)
    for pid in range(300):
        g = Gallery(20, 1, model.descriptors(np.full(20, pid), 0, rng))
        plain[(0, pid)] = g
        store.put((0, pid), g)
    queries = {pid: Gallery(20, 1, model.descriptors(np.full(2, pid), 1, rng))
               for pid in range(150, 450)}  # half of them dropped here before, half never seen
    true = np.sort([queries[p].distance_to(plain[(0, p)]) for p in range(150, 300)])
    cfg = TrackerConfig(epsilon=float(true[74] + true[75]) / 2)
    found, gap = 0, 0.0
    for pid, q in queries.items():
        tid = reidentify(q, plain, cfg)
        assert reidentify(q, store, cfg) == tid
        found += tid is not None
        if (0, pid) in plain:
            gap = max(gap, abs(q.distance_to(store[(0, pid)]) - q.distance_to(plain[(0, pid)])))
    assert 70 <= found <= 80 and gap < 1e-3


def test_reid_store_extend_keeps_the_place_and_the_budget():
    store = ReidStore(10, 30 * 16 * 2)
    store.put((0, 1), _full_gallery(1, n=4, dim=16))
    store.put((0, 2), _full_gallery(2, n=4, dim=16))
    store.extend((0, 1), _full_gallery(3, n=30, dim=16))  # merged: at most its capacity (20)
    assert list(store) == [(0, 1), (0, 2)] and len(store[(0, 1)]) == 20
    assert store.nbytes == (20 + 4) * 16 * 2 <= store.max_bytes
    store.extend((0, 2), _full_gallery(4, n=30, dim=16))  # 40 rows: over budget, oldest out
    assert list(store) == [(0, 2)] and store.nbytes == 20 * 16 * 2


# -- assembly ---------------------------------------------------------------------------------------
def test_the_papers_three_configurations_are_three_assemblies():
    for name, appearance, mgr in (("dkf", False, IndependentTrackers),
                                  ("dkf+lda", True, IndependentTrackers),
                                  ("dkf+lda+dtm", True, DistributedTrackerManager)):
        parts = assemble(TrackerConfig.for_ablation(name))
        assert parts.associate.appearance is appearance
        assert isinstance(parts.manager, mgr)
        assert parts.initiator().appearance is appearance


class RecordingAssociation(LocalDataAssociation):
    """A fake LDA that records what it was asked and assigns nothing."""

    def __init__(self, cfg):
        super().__init__(cfg, appearance=True)
        self.calls = []

    def __call__(self, trackers, obs):
        self.calls.append((len(trackers), len(obs)))
        return []

    def recover(self, trackers, obs, taken):
        return []


def test_a_node_runs_with_a_fake_association():
    """Injected components replace the defaults: with an association that never assigns, every
    detection is unassigned, so a person standing still is born again every second frame."""
    cfg = TrackerConfig()
    fake = RecordingAssociation(cfg)
    parts = assemble(cfg)
    node = CameraNode(topdown_camera(0), (), cfg, "t",
                      components=Components(fake, parts.manager, parts.initiator))
    for k in range(6):
        node.prepare(k, [det(3.0, 3.0, 1)])
        node.update([])
    assert fake.calls[0] == (0, 1) and fake.calls[-1][1] == 1
    assert node.stats.births == 3  # frames 1, 3, 5: a birth from every two observations
    # the default assembly tracks the same person with one tracker
    real = CameraNode(topdown_camera(0), (), cfg, "t")
    for k in range(6):
        real.prepare(k, [det(3.0, 3.0, 1)])
        real.update([])
    assert real.stats.births == 1


# -- each camera's own view (views.OwnViews) ----------------------------------------------------
def test_own_view_smooths_the_size_a_camera_measures_at_view_rate():
    from edge_node.core.state import NodeState
    from edge_node.core.views import OwnViews, ViewSettings
    views = OwnViews(ViewSettings.of(TrackerConfig(), view_rate=0.25), [topdown_camera(0)], {})
    st = NodeState(1)
    st.insert((0, 0), Gallery())
    st.insert((0, 1), Gallery())  # not measured: nothing drawn for it changes
    st.begin_frame()
    st.raw[0, 0] = 1  # measured by the camera's box 1
    views.saw(st, 3, {0: measured([[9.0, 9.0], [0.5, 1.7]])})
    assert st.view_k[:, 0].tolist() == [3, -1]
    assert st.view_size[0, 0].tolist() == [0.5, 1.7]  # the first, as measured
    st.begin_frame()
    st.raw[0, 0] = 0
    views.saw(st, 4, {0: measured([[0.9, 1.3]])})
    np.testing.assert_allclose(st.view_size[0, 0], [0.5 + 0.25 * 0.4, 1.7 - 0.25 * 0.4])
    assert st.view_k[:, 0].tolist() == [4, -1]
    # a measurement that does not locate the target (foot point 1 m uncertain, above
    # view_locate 0.5 m) keeps the size but counts as measured
    st.begin_frame()
    st.raw[0, 0] = 0
    views.saw(st, 5, {0: measured([[3.0, 3.0]], sigma=1.0)})
    np.testing.assert_allclose(st.view_size[0, 0], [0.5 + 0.25 * 0.4, 1.7 - 0.25 * 0.4])
    assert st.view_k[:, 0].tolist() == [5, -1] and np.isnan(st.view_at[0, 0]).all()


def measured(sizes, sigma=0.05, at=(0.0, 0.0)):
    """One camera frame's measurements (``BoxMeasurements``) of boxes ``sizes`` (ground units)
    whose foot points at ``at`` are known to ``sigma`` along each ground axis."""
    from edge_node.core.measurement import BoxMeasurements
    n = len(sizes)
    R = np.repeat(np.diag([sigma**2, sigma**2, 0.01, 0.01])[None], n, axis=0)
    z = np.array([[*at, *size] for size in sizes], float)
    return BoxMeasurements(z, R, np.zeros((n, 2)), np.zeros((n, 2)), np.array(sizes, float),
                           np.zeros(n, bool))


def test_a_merge_keeps_what_each_camera_measured_last_of_the_two_rows():
    """Two rows of one person merge: per camera, the view of the row that camera measured last
    (its frame, size, place against the estimate and pending foot point) is the one kept."""
    from edge_node.core.lifecycle import Lifecycle
    from edge_node.core.state import NodeState
    st = NodeState(2)
    st.insert((0, 0), Gallery())
    st.insert((0, 1), Gallery())
    st.view_k[:] = [[5, 9], [7, 3]]  # camera 0 measured (0, 1) last, camera 1 (0, 0)
    st.view_size[:] = [[[1.0, 1.0], [2.0, 2.0]], [[3.0, 3.0], [4.0, 4.0]]]
    st.view_off[0] = [[0.1, 0.2], [0.5, 0.6]]
    st.view_off[1, 0] = [0.3, 0.4]  # (0, 1) in camera 1: no place learnt
    st.view_at[1, 0] = [5.0, 5.0]
    Lifecycle._absorb(st, st.row((0, 0)), st.delete((0, 1)))
    assert st.view_k[0].tolist() == [7, 9]
    assert st.view_size[0].tolist() == [[3.0, 3.0], [2.0, 2.0]]
    assert st.view_off[0].tolist() == [[0.3, 0.4], [0.5, 0.6]]
    assert st.view_at[0, 0].tolist() == [5.0, 5.0] and np.isnan(st.view_at[0, 1]).all()
    # the other way round, the place camera 1 has not learnt for the later row is not learnt
    st.insert((0, 2), Gallery(), view_k=[1, 12])
    Lifecycle._absorb(st, st.row((0, 0)), st.delete((0, 2)))
    assert st.view_k[0].tolist() == [7, 12] and np.isnan(st.view_off[0, 1]).all()
    assert st.view_off[0, 0].tolist() == [0.3, 0.4]


def test_own_view_draws_a_box_only_while_enough_of_it_is_in_the_image():
    from edge_node.core.views import OwnViews, ViewSettings
    cam = Camera(0, (100, 80), np.eye(3))
    views = OwnViews(ViewSettings.of(TrackerConfig(), view_inside=0.9, view_hidden=0.5, view_fresh=10),
                     [cam], {})
    boxes = np.array([[10.0, 10, 20, 40],    # inside
                      [-1.0, 10, 20, 40],    # 19 of 20 px across: 0.95 >= 0.9
                      [-3.0, 10, 20, 40],    # 17 of 20: 0.85, left out
                      [90.0, 70, 20, 40],    # 10 of 20 across, left out
                      [10.0, 12, 20, 30]])   # inside, but behind the first (bottom edge higher)
    fresh = np.zeros(5)
    assert views.visible(cam, boxes, fresh).tolist() == [True, True, False, False, True]
    # unmeasured for longer than view_fresh: the nearer first box covers 100 % of the last
    stale = np.array([0, 0, 0, 0, 11])
    assert views.visible(cam, boxes, stale).tolist() == [True, True, False, False, False]


class NoViews:
    """A fake views role: draws nothing, counts the frames it was asked."""

    def __init__(self, cameras, registrations):
        self.asked = 0

    def saw(self, state, k, raws):
        pass

    def boxes(self, state, rows, k, x_hat, two_people=None):
        self.asked += 1
        return [{} for _ in rows]

    def unseen_limit(self):
        return 0  # no negative evidence


def test_a_node_runs_with_a_fake_views_role():
    """The own-view role is injected like the others: the fake's (empty) boxes are what the
    tracks carry, and the default draws the person in camera 0."""
    cfg = TrackerConfig()
    parts = assemble(cfg)
    made = []
    node = CameraNode(topdown_camera(0), (), cfg, "t", components=Components(
        parts.associate, parts.manager, parts.initiator, parts.registration,
        views=lambda cams, regs: made.append(NoViews(cams, regs)) or made[-1]))
    real = CameraNode(topdown_camera(0), (), cfg, "t")
    for k in range(6):
        for n in (node, real):
            n.prepare(k, [det(3.0, 3.0, 1)])
            tracks = n.update([])
    assert made[0].asked >= 4 and all(t.boxes == {} for t in node.tracks())
    assert len(tracks) == 1 and set(tracks[0].boxes) == {0}
