"""What id a person is reported under while the network decides whether two trackers are one
(issue: no retroactive id switches). Figures come from the configuration alone."""
import numpy as np

from edge_node.core import Detection, TrackerConfig
from fakes import SELECTIVE, det, make_nodes, step


def walk(k):
    """One person shuffling along x at 5 cm/s (metres): slow enough that the older tracker,
    coasting where it was last seen, stays within the co-motion gate of the younger."""
    return 2.0 + 0.002 * k, 2.0


def _run(alias: bool, frames: int = 60, hidden_from: int = 5, offset: float = 0.7,
         **changes):
    """Two cameras start their own tracker of one person in frame 1, ``offset`` m apart
    (camera 1's calibration is off; 0.7 m: too far to merge at once, so the pair gathers
    co-motion evidence). From ``hidden_from`` on camera 0 no longer sees the person: the older
    tracker, (0, 0), coasts unreported while the younger, camera 1's (1, 0), goes on being
    measured. ``changes``: tracker parameters (``report_age`` 0 unless given)."""
    cfg = TrackerConfig(registration=False, pending_alias=alias,
                        **{"report_age": 0, **SELECTIVE, **changes})
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg, offsets={1: (offset, 0.0)})
    rng = np.random.default_rng(5)
    reported, held = [], []
    for k in range(frames):
        d = [Detection(det(*walk(k), pid=0, rng=rng).box, None)]
        out = step(nodes, k, {0: d if k < hidden_from else [], 1: d})
        reported.append({n: [t.id for t in out[n]] for n in out})
        held.append({n: sorted(nodes[n].trackers.ids()) for n in nodes})
    return cfg, reported, held


def test_a_duplicate_is_reported_under_the_older_id_while_the_older_is_unseen():
    """Without the alias every node shows the person as (0, 0), then as (1, 0) while (0, 0)
    coasts unreported, then as (0, 0) again once (0, 0) is dropped and its id goes to the
    tracker that was merging into it (``heir_pending``): two switches, one of them back. With
    ``pending_alias`` the younger is reported under the older id while it agrees with it
    towards a merge and the older is not reported: one id throughout."""
    cfg, plain, held = _run(alias=False)
    _, aliased, held_a = _run(alias=True)
    assert held == held_a  # reporting only: what the nodes hold is the same
    # the older tracker is dropped kappa frames after the last frame a camera saw it
    drop = next(k for k, h in enumerate(held) if k > 1 and len(h[0]) == 1)
    assert drop == 5 + cfg.kappa  # last seen in frame 4: ell 1..16 over frames 5..20
    assert held[drop][0] == [(0, 0)]  # the younger took the dropped id (heir_pending)
    for n in (0, 1):
        ids_plain = [r[n] for r in plain[2:]]
        ids_alias = [r[n] for r in aliased[2:]]
        assert all(len(i) == 1 for i in ids_plain + ids_alias)  # one person, one track
        seq = [i[0] for i in ids_plain]
        changes = [k for k in range(1, len(seq)) if seq[k] != seq[k - 1]]
        assert len(changes) == 2 and seq[0] == seq[-1] == (0, 0)  # there and back
        assert {i[0] for i in ids_alias} == {(0, 0)}  # one id throughout


def _first_reports(age: int, frames: int = 30, near: float = 0.0):
    """A chain of three nodes, only camera 0 sees one person standing at (2, 2) from frame 0;
    per node, the frame of its first reported track and the ids it reported (``near``:
    ``report_near``, 0 by default: every new tracker is tentative)."""
    cfg = TrackerConfig(registration=False, report_age=age, report_near=near)
    nodes = make_nodes({0: (1,), 1: (0, 2), 2: (1,)}, cfg)
    rng = np.random.default_rng(7)
    first, ids = {}, {n: set() for n in nodes}
    born = None
    for k in range(frames):
        out = step(nodes, k, {0: [Detection(det(2.0, 2.0, pid=0, rng=rng).box, None)]})
        if born is None and len(nodes[0].trackers):
            born = k  # the frame camera 0's second observation made the tracker
        for n, tracks in out.items():
            if tracks and n not in first:
                first[n] = k
            ids[n] |= {t.id for t in tracks}
    return born, first, ids


def test_a_new_tracker_is_reported_once_it_is_report_age_frames_old_on_every_node():
    """``report_age`` counts from the birth at the tracker's camera, so every node starts
    reporting it in the same frame, however many hops away (without it, each node as soon as
    the news arrives: a frame later two hops away)."""
    born, first, ids = _first_reports(age=0)
    # a frame's message carries the trackers born in it, and a relay takes one frame more
    assert first == {0: born, 1: born, 2: born + 1}
    for age in (3, 6):
        born_a, first_a, ids_a = _first_reports(age)
        assert born_a == born and ids_a == ids  # the same tracker, only reported later
        assert first_a == {0: born + age, 1: born + age, 2: born + age}


def test_report_age_delays_an_id_and_keeps_the_alias():
    """A young tracker reported under an older id (``pending_alias``) is tentative as long as
    that id is: in the two-camera run of the first test, with ``report_age`` 10 nothing is
    reported before the older id is 10 frames old, and from then on exactly what is reported
    without it, the person under (0, 0) while the younger (1, 0) carries it."""
    import dataclasses
    base = TrackerConfig(registration=False, pending_alias=True, report_near=0.0, **SELECTIVE)
    runs = {}
    for age in (0, 10):
        nodes = make_nodes({0: (1,), 1: (0,)}, dataclasses.replace(base, report_age=age),
                           offsets={1: (0.7, 0.0)})
        rng = np.random.default_rng(5)
        out = []
        for k in range(40):
            d = [Detection(det(*walk(k), pid=0, rng=rng).box, None)]
            got = step(nodes, k, {0: d if k < 5 else [], 1: d})
            out.append({n: [t.id for t in got[n]] for n in got})
        runs[age] = out
    born = next(k for k, r in enumerate(runs[0]) if r[0])  # both cameras start in frame 1
    for n in (0, 1):
        assert all(not r[n] for r in runs[10][:born + 10])
        assert [r[n] for r in runs[10][born + 10:]] == [r[n] for r in runs[0][born + 10:]]
        assert {i for r in runs[10][born + 10:] for i in r[n]} == {(0, 0)}


def test_a_person_who_walks_in_alone_is_reported_at_once():
    """With the defaults (``report_age`` 10 frames, ``report_near`` 2 m) only a tracker born
    beside an older one is tentative: a lone person is reported in the same frames as
    without ``report_age``."""
    cfg = TrackerConfig()
    assert cfg.report_age == 10 and cfg.report_near == 2.0
    born, first, ids = _first_reports(age=0)
    assert _first_reports(age=cfg.report_age, near=cfg.report_near) == (born, first, ids)


def _pair(age: int, frames: int = 40):
    """The two-camera run of the first test with camera 0 seeing the person throughout and
    camera 1's calibration 1.3 m off: per frame and node, the ids reported; and the birth frame
    of camera 1's duplicate (1, 0)."""
    _, out, held = _run(True, frames, hidden_from=frames, offset=1.3, report_age=age)
    return out, next(k for k, h in enumerate(held) if (1, 0) in h[1])


def test_a_duplicate_beside_a_person_is_tentative_for_report_age_frames():
    """Camera 1 (calibration 1.3 m off) starts its own tracker (1, 0) of the person camera 0
    tracks as (0, 0), in the same frame: (1, 0) ranks after (0, 0) and is born 1.3 m from it,
    within ``report_near`` but beyond the co-motion gate (1 m), so ``hide_pending`` has no
    evidence to hide it by. Without ``report_age`` the duplicate is reported as a second id in
    its first frames; with it, it is not reported before it is ``report_age`` frames old, and
    from then on every node reports exactly what it reports without ``report_age``."""
    age = TrackerConfig().report_age
    plain, born = _pair(0)
    tentative, born_t = _pair(age)
    assert born == born_t  # only reporting changes
    window = range(born, born + age)
    assert any((1, 0) in plain[k][n] for k in window for n in (0, 1))  # the blip it hides
    for n in (0, 1):
        for k in window:
            assert (1, 0) not in tentative[k][n]
            assert [i for i in plain[k][n] if i != (1, 0)] == tentative[k][n]
        assert [r[n] for r in tentative[born + age:]] == [r[n] for r in plain[born + age:]]


def test_a_second_person_the_network_knows_is_not_held_back():
    """Camera 0 sees person A from frame 0 and person B 0.6 m beside A from frame 10, both in
    every frame: B's tracker is born beside an older one, but the co-motion evidence knows
    them for two people (one camera measures both at once), so B is reported in the same
    frames as without ``report_age``."""
    def run(age):
        cfg = TrackerConfig(registration=False, report_age=age, **SELECTIVE)
        nodes = make_nodes({0: (1,), 1: (0,)}, cfg)
        rng = np.random.default_rng(3)
        out = []
        for k in range(30):
            d = [Detection(det(2.0, 2.0, pid=0, rng=rng).box, None)]
            if k >= 10:
                d.append(Detection(det(2.6, 2.0, pid=1, rng=rng).box, None))
            got = step(nodes, k, {0: d, 1: []})
            out.append({n: sorted(t.id for t in got[n]) for n in got})
        return out
    plain, tentative = run(0), run(TrackerConfig().report_age)
    assert plain[-1][0] == [(0, 0), (0, 1)]  # two people, two ids
    b = next(k for k, r in enumerate(plain) if (0, 1) in r[0])
    assert b <= 12
    assert tentative == plain


def test_an_id_the_alias_keeps_is_not_held_back_beside_itself():
    """The first test's run with the defaults (``pending_alias``, ``report_age`` 10,
    ``report_near`` 2 m): camera 0 stops seeing the person at frame 5 and the younger (1, 0),
    0.7 m from (0, 0), is reported under (0, 0). The alias's own older tracker is not a reason
    to hold it back: every node reports (0, 0) in every frame from the first, without the
    5-frame hole a first version left while (0, 0) was younger than ``report_age``."""
    cfg = TrackerConfig(registration=False, **SELECTIVE)
    assert cfg.pending_alias and cfg.report_age == 10 and cfg.report_near == 2.0
    _, reported, _ = _run(True, 30, report_age=cfg.report_age)
    for k in range(1, 30):
        assert reported[k][0] == reported[k][1] == [(0, 0)], k


def _walk_in(age: int, frames: int = 30):
    """Camera 0 sees person A standing at (2, 2); from frame 10 camera 1 alone sees person B
    walk in from 4.3 m towards A at 0.1 m a frame, stopping 0.6 m from A. Per frame and node,
    the ids reported."""
    cfg = TrackerConfig(registration=False, report_age=age, **SELECTIVE)
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg)
    rng = np.random.default_rng(3)
    out = []
    for k in range(frames):
        a = [Detection(det(2.0, 2.0, pid=0, rng=rng).box, None)]
        b = ([Detection(det(max(4.3 - 0.1 * (k - 10), 2.6), 2.0, pid=1, rng=rng).box, None)]
             if k >= 10 else [])
        got = step(nodes, k, {0: a, 1: b})
        out.append({n: sorted(t.id for t in got[n]) for n in got})
    return out


def test_a_person_shown_once_is_not_held_back_when_they_come_near_another():
    """B is born 2.3 m from A (beyond ``report_near``) and reported at once; walking on, B is
    within 2 m of the older A while still younger than ``report_age``. The rule decides once:
    B stays reported, every frame the same as without ``report_age`` (a first version judged
    every frame and withdrew B for six frames)."""
    plain, tentative = _walk_in(0), _walk_in(TrackerConfig().report_age)
    assert any((1, 0) in r[0] for r in plain[10:16])  # B is reported within its first frames
    assert any(abs(4.3 - 0.1 * (k - 10) - 2.0) < 2.0 and (1, 0) in plain[k][0]
               for k in range(10, 20))  # ...and while young, within report_near of A
    assert tentative == plain


class KnowsNobodyApart:
    """A manager that knows no pair of trackers for two people."""

    def two_people(self, pairs):
        return np.zeros(len(pairs), bool)


def _table_reporter(near: float = 2.0, units_per_metre: float = 1.0):
    """A reporter whose ``_beside_older`` is judged on a hand-made table (``_table``)."""
    from edge_node.core.reporter import Reporter, ReporterSettings

    s = ReporterSettings(report_coast=1, report_age=10, report_near=near, hide_pending=True,
                         pending_alias=True, comotion_frames=10, reappear_age=10,
                         reappear_hide=0, units_per_metre=units_per_metre)
    return Reporter(KnowsNobodyApart(), None, None, None, s)


def _table(ids, born, xy, estimated):
    """The columns ``_beside_older`` reads, for trackers ``ids`` at ground points ``xy``."""
    from types import SimpleNamespace

    x_hat = np.zeros((len(ids), 6))
    x_hat[:, :2] = xy
    return SimpleNamespace(ids=ids, born=np.array(born), estimated=np.array(estimated),
                           x_hat=x_hat, row=ids.index)


def test_report_near_is_in_metres_on_the_ground_units():
    """``report_near`` is in metres whatever the ground unit: with 30 units per metre two
    trackers 1.5 m (45 units) apart are beside each other at 2 m and not at 1 m."""
    state = _table([(0, 0), (1, 0)], [0, 5], [(0.0, 0.0), (45.0, 0.0)], [True, True])

    def beside(near):
        return _table_reporter(near, units_per_metre=30.0)._beside_older(state, [1])

    assert beside(2.0) == [1] and beside(1.0) == []


def test_beside_an_older_one_by_rank_by_distance_and_only_among_estimated_trackers():
    """``_beside_older`` on a hand-made table (one ground unit a metre, ``report_near`` 2 m):
    rank is the birth frame first and the id only between equal births, the distance is on the
    ground plane (both axes), and a tracker without an estimate holds nobody back."""
    reporter = _table_reporter()

    def beside(ids, born, xy, estimated, rows):
        return [ids[i] for i in reporter._beside_older(_table(ids, born, xy, estimated), rows)]

    # (1, 0) born at 5, (0, 3) born at 8 beside it: the later birth is the younger, whatever
    # the ids say
    ids = [(1, 0), (0, 3)]
    assert beside(ids, [5, 8], [(0.0, 0.0), (1.0, 0.0)], [True, True], [0, 1]) == [(0, 3)]
    # equal births: the larger id is the younger
    assert beside(ids, [5, 5], [(0.0, 0.0), (1.0, 0.0)], [True, True], [0, 1]) == [(1, 0)]
    # 3 m apart along y only: not beside; 1.5 m along y: beside
    assert beside(ids, [5, 8], [(0.0, 0.0), (0.0, 3.0)], [True, True], [1]) == []
    assert beside(ids, [5, 8], [(0.0, 0.0), (0.0, 1.5)], [True, True], [1]) == [(0, 3)]
    # the older tracker has no estimate yet: it holds nobody back
    assert beside(ids, [5, 8], [(0.0, 0.0), (1.0, 0.0)], [False, True], [1]) == []
