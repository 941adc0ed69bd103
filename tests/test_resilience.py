"""A plausible but wrong neighbour (edge_node/core/trust.py): detected by a CUSUM per neighbour,
quarantined, re-admitted; the honest nodes' tracks and ids survive it; honest networks never
quarantine anyone. The faulty node's lies are the fault layer's (edge_node/forgery.py), the same
in both shells (tests/test_cluster.py runs one across processes)."""
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from edge_node.core import TrackerConfig
from edge_node.core.trust import REFUTED, QUARANTINED, SUSPECT, TRUSTED, Trust, TrustSettings
from edge_node.faults import FaultPlan, FaultyNode
from edge_node.forgery import Forger
from fakes import det, graph, make_nodes
from protocol import codec

START = 30  # the frame node 2 turns faulty
PEOPLE = [(2.0, 2.0), (2.0, 6.5), (6.5, 2.0), (6.5, 6.5), (4.2, 8.8), (8.8, 4.2)]  # 4 m apart


def triangle(kind: str | None, frames: int, cfg: TrackerConfig | None = None, people=PEOPLE[:2],
             each=None, stop: int | None = None):
    """Three nodes, each neighbour of the others, every camera seeing ``people`` walking
    slowly; from ``START`` (to ``stop``, None: the end) node 2's messages carry the lies of
    ``kind`` (its detections, for the kinds of a camera). Returns the nodes and every frame's
    tracks of nodes 0 and 1, and the people's positions per frame; ``each(k, nodes)`` is
    called after every frame."""
    nodes = make_nodes(graph("complete", 3), cfg or TrackerConfig())
    forger = None
    if kind is not None:
        n2 = nodes[2]
        forger = Forger([FaultyNode(2, kind, START, stop, seed=1)], n2.cameras[0],
                        n2.cfg.units_per_metre, 1.0 / n2.cfg.fps)
    rng = np.random.default_rng(5)
    tracks, truth = [], []
    for k in range(frames):
        where = [(x + 0.01 * k, y) for x, y in people]
        dets = [det(x, y, p, rng) for p, (x, y) in enumerate(where)]
        msgs = {i: n.prepare(k, forger.detections(k, dets) if forger and i == 2 else dets)
                for i, n in nodes.items()}
        if forger is not None:
            msgs[2] = forger.message(k, msgs[2])
        wire = {i: codec.encode(m) for i, m in msgs.items()}
        out = {i: n.update([codec.decode(wire[j], expect_sender=j) for j in n.neighbours])
               for i, n in nodes.items()}
        tracks.append(out)
        truth.append(where)
        if each is not None:
            each(k, nodes)
    return nodes, tracks, truth


def worst_error(tracks, truth, honest=(0, 1)) -> float:
    """The largest distance of an honest node's track from the person nearest to it (m)."""
    worst = 0.0
    for out, where in zip(tracks, truth):
        for i in honest:
            for t in out[i]:
                worst = max(worst, min(np.hypot(t.x[0] - x, t.x[1] - y) for x, y in where))
    return worst


def ids_at(tracks, k, honest=(0, 1)):
    return {i: sorted(t.id for t in tracks[k][i]) for i in honest}


def test_a_hijacking_neighbour_is_quarantined_on_its_second_frame_and_drags_nothing():
    """Node 2 moves every state it sends 4 m and claims a 5 cm measurement there. Each entry's
    normalised distance from the honest node's prediction is about 16 m^2 over ``calib_sigma``^2
    0.16 m^2 plus the claimed and predicted variances (a few 0.01 m^2), so 80-100; the other
    neighbour's score is near 0, so the allowance is ``trust_drift`` 6 and the sum grows by
    more than 50 a frame: suspect (>= 30) at frame START, quarantined (>= 100) at START + 1. The honest nodes' tracks stay on the people and
    keep their ids; without the trust role the same lies drag them metres away."""
    frames = START + 40
    nodes, tracks, truth = triangle("hijack", frames)
    for i in (0, 1):
        t = nodes[i].trust.of[2]
        assert t.changes[:2] == [(START, SUSPECT), (START + 1, QUARANTINED)]
        assert t.state == QUARANTINED and nodes[i].stats.trust[2]["first_quarantine"] == START + 1
        assert nodes[i].trust.of[1 - i].state == TRUSTED and not nodes[i].trust.of[1 - i].changes
    for i in (0, 1):
        assert 50.0 < nodes[i].trust.level[2] and nodes[i].trust.level[1 - i] < 6.0
    assert worst_error(tracks, truth) < 0.3
    assert ids_at(tracks, START - 1) == ids_at(tracks, frames - 1)
    assert all(len(tracks[k][i]) == 2 for k in range(START, frames) for i in (0, 1))

    _, off, truth_off = triangle("hijack", frames, TrackerConfig(trust_check=False))
    assert worst_error(off, truth_off) > 1.0  # the harm the role prevents


def test_a_neighbour_announcing_merges_of_people_apart_is_quarantined_before_any_is_applied():
    """Six people 4 m apart (farther than twice the merge rules' reach, 2 x 1.5 m): node 2
    announces 5 merges of them. Each is a ``far_merge`` and each pair adds ``trust_merge`` 20
    to node 2's sum: 100, quarantined in the frame it announced them, so none is applied. The
    honest nodes keep six ids, the same before and after."""
    frames = START + 30
    nodes, tracks, truth = triangle("forged_merge", frames, people=PEOPLE)
    for i in (0, 1):
        assert nodes[i].trust.of[2].changes[0] == (START, QUARANTINED)
        assert len(nodes[i].trust.of[2].disputed) == 5  # each far_merge pair, disputed once
    assert ids_at(tracks, START - 1) == ids_at(tracks, frames - 1)
    assert all(len(tracks[k][i]) == 6 for k in range(START, frames) for i in (0, 1))


def test_a_neighbour_whose_detector_sees_people_who_are_not_there_is_quarantined():
    """From ``START`` node 2's detector adds 3 invented people walking through its view
    (``hallucinate``), which is also nodes 0 and 1's view: their cameras should measure them
    and never do. Once a node has held one for ``unseen_limit()`` frames (10: these detectors
    miss nobody, so nothing raises the floor) each of node 2's entries measuring it is refuted,
    and the sum grows by ``trust_refuted`` 2 times (the entries less ``trust_refuted_allow``
    1) a frame: with the three refuted from the same frame, 4 a frame, so node 2 is quarantined
    25 frames after its first refuted entry (100; the refuted sum does not make a neighbour
    suspect), for that reason. The honest nodes then drop its invented people and keep the two real people's
    ids. With ``trust_refuted = 0`` nobody is quarantined, and the honest nodes go on holding
    node 2's invented people."""
    frames = START + 60
    record = []
    nodes, tracks, truth = triangle(
        "hallucinate", frames,
        each=lambda k, ns: record.append({i: n.stats.trust for i, n in ns.items()}))
    for i in (0, 1):
        t = nodes[i].trust.of[2]
        total = [0] + [r[i][2]["refuted"] for r in record]
        per_frame = [b - a for a, b in zip(total, total[1:])]  # node 2's refuted entries a frame
        first = next(k for k, n in enumerate(per_frame) if n)
        assert START + 10 <= first <= START + 16, first
        assert per_frame[first:first + 25] == [3] * 25, per_frame[first:]
        assert t.changes == [(first + 24, QUARANTINED)], (first, t.changes)
        assert t.reason == REFUTED and t.state == QUARANTINED
        assert nodes[i].trust.of[1 - i].state == TRUSTED and not nodes[i].trust.of[1 - i].changes
    assert ids_at(tracks, START - 1) == ids_at(tracks, frames - 1) == ids_at(tracks, START - 1)

    off, _, _ = triangle("hallucinate", frames, cfg=TrackerConfig(trust_refuted=0.0))
    for i in (0, 1):
        assert off[i].trust.of[2].state == TRUSTED and not off[i].trust.of[2].changes
        assert sum(1 for t in off[i].state.ids if t[0] == 2) > sum(1 for t in nodes[i].state.ids if t[0] == 2)


def test_a_quarantined_hallucinating_neighbour_stays_out_while_it_hallucinates():
    """After the quarantine the honest nodes drop node 2's invented people (nothing of them
    is used), but node 2 goes on claiming them: a claim of a tracker the node does not hold is
    judged on its own (the sender's state of it inside the node's view, no target the node
    measures within ``tau_gda``), so its entries are still refuted every frame once a claimed
    person has been in view unmeasured for ``unseen_limit()`` frames, and node 2 is never
    re-admitted while it hallucinates (without that, nothing was left to refute and it was
    trusted again after its sum drained, its invented people adopted again). Once it stops, the
    sum drains (2 a frame) and it is trusted again after 25 calm frames."""
    stop = START + 150
    frames = stop + 150
    refuted, at_stop = {0: [], 1: []}, {}

    def each(k, nodes):
        for i in (0, 1):
            refuted[i].append(nodes[i].stats.trust[2]["refuted"])
            if k == stop - 1:
                at_stop[i] = nodes[i].trust.of[2].refuted_sum

    nodes, _, _ = triangle("hallucinate", frames, each=each, stop=stop)
    for i in (0, 1):
        t = nodes[i].trust.of[2]
        (kq, q), (kt, tr) = t.changes
        assert (q, tr) == (QUARANTINED, TRUSTED) and t.reason == REFUTED
        # the sum S when the hallucination stops falls 2 a frame: 0 at stop - 1 + S / 2, the
        # first calm frame; trusted at the 25th calm frame
        assert at_stop[i] >= 100 and at_stop[i] % 2 == 0, at_stop
        assert kq < START + 60 and kt == stop - 1 + at_stop[i] // 2 + 24, (t.changes, at_stop)
        after = [b - a for a, b in zip(refuted[i][kq + 40:stop], refuted[i][kq + 41:stop])]
        # its claims still refuted every frame, the trackers not held (one or two a frame: an
        # invented person new in view counts once it has been unmeasured unseen_limit() frames)
        assert min(after) >= 1 and max(after) >= 2, after
        assert not any(tid[0] == 2 for tid in nodes[i].state.ids)  # none of them adopted again


def test_honest_neighbours_are_never_suspected():
    frames = 120
    nodes, tracks, truth = triangle(None, frames, people=PEOPLE[:4])
    for n in nodes.values():
        assert all(t.state == TRUSTED and not t.changes and t.cusum < 30 for t in n.trust.of.values())


class Scripted(Trust):
    """The trust role fed its neighbours' scores directly (one entry each, no state needed)."""

    def __init__(self, settings, scores):
        super().__init__(settings, sorted(scores[0]))
        self.script = iter(scores)
        self.now = {}

    def __call__(self, state, msgs, k, resolve):
        self.now = next(self.script)
        return super().__call__(state, msgs, k, resolve)

    def _statistics(self, state, msgs, resolve, k):
        return [(np.zeros(1, np.intp), [self.now[m.sender]]) for m in msgs]

    def _lagging(self):  # no measurements, no lag
        return {}

    def _used(self, m, entries, verdicts):
        return m


class Msg:
    def __init__(self, sender):
        self.sender, self.merges = sender, ()


SETTINGS = TrustSettings.of(TrackerConfig())


def test_the_cusum_by_hand():
    """Neighbour 1 scores 10 a frame, neighbour 2 scores 1: the allowance is max(6, 3 x 1) = 6,
    so 1's sum grows 4 a frame: suspect at the 8th frame (32 >= 30), quarantined at the 25th
    (100). Then 1 scores 1 (within the allowance 6: the sum falls 5 a frame, floored at 0);
    after 25 calm frames in a row it is trusted again, its sum reset. When both score 10 the
    allowance is 3 x 10 = 30: cameras that all disagree (registration not converged) accuse
    nobody."""
    bad = [{1: 10.0, 2: 1.0}] * 25 + [{1: 1.0, 2: 1.0}] * 25 + [{1: 10.0, 2: 10.0}] * 40
    tr = Scripted(SETTINGS, bad)
    states = []
    for k in range(len(bad)):
        tr(None, [Msg(1), Msg(2)], k, lambda t: t)
        states.append(tr.of[1].state)
    assert states.index(SUSPECT) == 7 and states.index(QUARANTINED) == 24
    assert tr.of[1].changes == [(7, SUSPECT), (24, QUARANTINED), (49, TRUSTED)]
    assert states[48] == QUARANTINED and states[49:] == [TRUSTED] * 41
    assert tr.of[1].cusum == 0.0 and tr.of[2].cusum == 0.0 and not tr.of[2].changes
    assert tr.of[1].quarantined_frames == 25 and tr.of[1].suspect_frames == 17


class Refuting(Scripted):
    """The trust role fed each neighbour's refuted entries a frame directly (its scores 0)."""

    def __init__(self, settings, refuted):
        super().__init__(settings, [{n: 0.0 for n in r} for r in refuted])
        self.refuted = iter(refuted)

    def _statistics(self, state, msgs, resolve, k):
        self._refuted = Counter(next(self.refuted))
        return super()._statistics(state, msgs, resolve, k)


def test_the_refuted_sum_by_hand():
    """Neighbour 1 has 3 entries refuted a frame for 60 frames: its refuted sum grows by
    ``trust_refuted`` x (3 - ``trust_refuted_allow``) = 2 x 2 = 4 a frame: past
    ``trust_suspect`` (30) at the 8th frame but not suspect (the refuted sum only quarantines),
    quarantined at the 25th (100), bounded at 200 (twice ``trust_quarantine``) from the 50th
    frame on. Then none: the sum falls by 2 x 1 = 2 a frame and is 0 after 100 more (frame
    index 159), the first calm frame; trusted again after 25 calm frames (index 183).
    Neighbour 2 has two refuted a frame for 10 frames (20), then one a frame: one a frame adds
    nothing (a person behind a pillar, however long he stays), so 20 stays 20 until no entry is
    refuted, then falls 2 a frame. With ``trust_refuted = 0`` neither sum moves."""
    script = ([{1: 3, 2: 2}] * 10 + [{1: 3, 2: 1}] * 50 + [{1: 0, 2: 1}] * 150
              + [{1: 0, 2: 0}] * 20)
    tr = Refuting(SETTINGS, script)
    for k in range(len(script)):
        tr(None, [Msg(1), Msg(2)], k, lambda t: t)
        if k == 23:
            assert tr.of[1].refuted_sum == 96.0 and tr.of[1].state == TRUSTED
        if k == 59:
            assert tr.of[1].refuted_sum == 200.0
        if k == 209:
            assert tr.of[2].refuted_sum == 20.0
    assert tr.of[1].changes == [(24, QUARANTINED), (183, TRUSTED)]
    assert tr.of[1].reason == REFUTED and tr.of[1].refuted_peak == 200.0
    assert tr.summary()[1]["refuted"] == 180 and tr.summary()[2]["refuted"] == 220
    assert not tr.of[2].changes and tr.of[2].refuted_peak == 20.0
    assert tr.of[2].refuted_sum == 0.0
    off = Refuting(replace(SETTINGS, trust_refuted=0.0), script)
    for k in range(len(script)):
        off(None, [Msg(1), Msg(2)], k, lambda t: t)
    assert not off.of[1].changes and off.of[1].refuted_peak == 0.0


def test_a_quiet_neighbour_keeps_its_state():
    """A neighbour not heard in a frame (a lost message) neither gains nor loses trust."""
    script = [{1: 100.0, 2: 0.0}] * 2 + [{2: 0.0}] * 30
    tr = Scripted(SETTINGS, script)
    for k, s in enumerate(script):
        tr(None, [Msg(n) for n in sorted(s)], k, lambda t: t)
    assert tr.of[1].state == QUARANTINED and tr.of[1].cusum == pytest.approx(188.0)


def test_a_suspect_neighbours_late_and_current_messages_are_both_judged():
    """Async: a suspect sender's current message (forged, one tracker) and its late one (of
    the frame before, honest, two trackers) reach the role in one frame; each keeps only its own
    entries that pass the gate alone: none of the forged, both of the honest (a message's rows
    are never applied to another's: they once were, and raised IndexError)."""
    nodes, _, _ = triangle("hijack", START + 1, TrackerConfig(trust_quarantine=1000.0))
    node, n2 = nodes[0], nodes[2]
    assert node.trust.of[2].state == SUSPECT
    k = START + 1
    node.prepare(k, [det(2.31, 2.0, 0), det(2.31, 6.5, 1)])
    honest = n2.prepare(k, [det(2.31, 2.0, 0), det(2.31, 6.5, 1)])
    forged = Forger([FaultyNode(2, "hijack", 0, None, seed=1)], n2.cameras[0], 1.0, 0.04)
    cur = forged.message(k, replace(honest, trackers=honest.trackers[1:]))
    late = replace(honest, frame=k - 1)
    assert len(late.trackers) == 2 and len(cur.trackers) == 1
    used = node.trust(node.state, [cur, late], k, node.book.resolve)
    assert [len(m.block) for m in used] == [0, 2]
    assert node.trust.of[2].state == SUSPECT


def test_faulty_rules_are_read_with_their_fields_checked(tmp_path):
    plan = tmp_path / "f.toml"
    plan.write_text('[[faulty]]\nnode = 0\nkind = "hijack"\nstart = 5\nstop = 9\noffset = 3.0\n')
    (rule,) = FaultPlan.load(plan).faulty
    assert (rule.node, rule.kind, rule.start, rule.stop, rule.offset) == (0, "hijack", 5, 9, 3.0)
    assert rule.active(5) and rule.active(8) and not rule.active(9) and not rule.active(4)
    plan.write_text('[[faulty]]\nnode = 0\nkind = "lies"\n')
    with pytest.raises(Exception) as e:
        FaultPlan.load(plan)
    assert "kind" in str(e.value) and "f.toml" in str(e.value)


def test_a_merge_is_judged_by_what_the_nodes_own_cameras_see():
    """Two people 4.5 m apart (twice the merge reach is 3 m): measured by node 0's camera this
    frame, a merge of their trackers is ``far_merge`` (refused, ``trust_merge`` against its
    sender); with one of them not measured now it is only ``apart`` in the estimates (applied
    from a trusted sender, ``trust_apart``); two trackers 1 m apart are not disputed."""
    from edge_node.core.trust import APART
    frames = 60
    nodes, tracks, _ = triangle(None, frames, people=[(2.0, 2.0), (2.0, 6.5)])
    node = nodes[0]
    a, b = sorted(t.id for t in tracks[-1][0])
    k = frames - 1
    assert node.trust._implausible_merge(node.state, k, a, b) == "far_merge"
    node.state.U[node.state.row(b)] = 0.0  # camera 0 did not measure b this frame
    assert node.trust._implausible_merge(node.state, k, a, b) == APART
    node.state.x_bar[node.state.row(b), :2] = node.state.x_bar[node.state.row(a), :2] + [0.0, 1.0]
    assert node.trust._implausible_merge(node.state, k, a, b) is None


def test_a_phantom_its_neighbours_relayed_back_is_sent_once():
    """A phantom node that adopted one of its own invented ids back from a neighbour sends it
    once (twice, the codec refused the whole message and the node fell silent)."""
    nodes, _, _ = triangle(None, 3)
    n2 = nodes[2]
    forger = Forger([FaultyNode(2, "phantom", 0, None, seed=1, count=2)], n2.cameras[0], 1.0, 0.04)
    first = forger.message(3, n2.prepare(3, [det(2.0, 2.0, 0)]))
    invented = [t for t in first.trackers if t.id[1] >= 10**9]
    assert len(invented) == 2
    n2.update([])
    msg = n2.prepare(4, [det(2.0, 2.0, 0)])
    msg = replace(msg, trackers=msg.trackers + (invented[0],))  # adopted back
    out = forger.message(4, msg)
    ids = [t.id for t in out.trackers]
    assert len(ids) == len(set(ids)) and {t.id for t in invented} <= set(ids)
    codec.encode(out)  # the wire takes it
