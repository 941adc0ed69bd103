"""``PairEvidence``, the table of co-motion evidence per pair of trackers, against the
dictionary of pairs it replaced: the same pairs and nats after any sequence of what the manager
does to it (write a pair, read one, delete one, forget a tracker, settle the frame), and a
table no larger than the trackers it holds pairs of."""
from __future__ import annotations

import numpy as np
import pytest

from edge_node.core.evidence import PairEvidence


def _settled(ref: dict, held: set, alive: set) -> None:
    """The dictionary's end of frame, as ``find_merges`` wrote it before the table."""
    for key in list(ref):
        if key in alive:
            continue
        if key[0] in held and key[1] in held and ref[key] < 0.0:
            continue
        del ref[key]


def test_the_table_holds_what_the_dictionary_held_through_random_frames():
    rng = np.random.default_rng(7)
    ev, ref = PairEvidence(), {}
    ids = [(c, n) for c in range(3) for n in range(12)]
    live = set(ids[:8])
    for frame in range(400):
        for _ in range(rng.integers(0, 12)):
            a, b = sorted(rng.choice(len(ids), 2, replace=False))
            key = (ids[a], ids[b])
            if key[0] in live and key[1] in live:
                e = float(rng.normal(0.0, 20.0))
                ev[key] = ref[key] = e
        if ref and rng.random() < 0.3:
            key = sorted(ref)[rng.integers(len(ref))]
            del ev[key], ref[key]
        if rng.random() < 0.1:  # a tracker gone
            tid = ids[rng.integers(len(ids))]
            ev.forget(tid)
            for key in [key for key in ref if tid in key]:
                del ref[key]
            live.discard(tid)
        if rng.random() < 0.2:  # a tracker born
            live.add(ids[rng.integers(len(ids))])
        alive = {key for key in ref if rng.random() < 0.3 and ref[key] >= 0.0}
        ev.settle(live, alive)
        _settled(ref, live, alive)
        assert dict(ev.items()) == ref
        assert len(ev) == len(ref)
        assert ev.positive() == sorted((k, e) for k, e in ref.items() if e > 0.0)
        for key in list(ref)[:3]:
            assert ev[key] == ref[key] and ev.get(key) == ref[key] and key in ev
        missing = (ids[0], ids[-1])
        if missing not in ref:
            assert ev.get(missing, 0.0) == 0.0 and missing not in ev
            with pytest.raises(KeyError):
                ev[missing]
    assert frame == 399 and len(ref) > 0  # the run held pairs to the end


def test_slots_are_given_back_and_the_table_stays_bounded():
    """Ten thousand trackers, ten alive at a time, each with a pair: the table never holds more
    slots than twice the largest number of trackers it held pairs of at once (it doubles)."""
    ev = PairEvidence()
    live: list[tuple[int, int]] = []
    for n in range(10_000):
        tid = (n % 4, n)
        for other in live[-3:]:
            ev[(other, tid)] = -1.0
        live.append(tid)
        if len(live) > 10:
            ev.forget(live.pop(0))
        ev.settle(set(live), set())
    assert ev.size() <= 2 * 11
    # of the last ten, the oldest's partners are gone; the next pairs with it alone, the one
    # after with two, the other seven with their three before
    assert len(ev) == 1 + 2 + 3 * 7
    assert ev.holders() == set(live)


def test_an_absent_pair_reads_as_the_callers_default_and_a_pair_is_one_key_both_ways():
    ev = PairEvidence({((0, 1), (2, 3)): -4.0})
    assert ev[((2, 3), (0, 1))] == -4.0  # the table is symmetric
    assert ev.get(((0, 1), (5, 5)), 0.0) == 0.0
    assert list(ev) == [((0, 1), (2, 3))]
    assert ev.pop(((0, 1), (2, 3))) == -4.0 and len(ev) == 0
    assert ev.pop(((0, 1), (2, 3)), None) is None


def test_the_table_shrinks_after_a_crowd_and_a_pair_of_one_tracker_is_refused():
    """200 trackers, every one paired with the one before, then all gone but two: the table
    (256 slots at its largest) is halved at each end of frame while at most a quarter used,
    back to the smallest (8), the remaining pair intact; a tracker cannot pair with itself."""
    ev = PairEvidence()
    ids = [(0, n) for n in range(200)]
    for a, b in zip(ids, ids[1:]):
        ev[(a, b)] = -2.0
    ev.settle(set(ids), set())
    assert ev.size() == 256 and len(ev) == 199
    for _ in range(6):
        ev.settle(set(ids[:2]), set())
    assert ev.size() == 8 and dict(ev.items()) == {(ids[0], ids[1]): -2.0}
    assert ev.holders() == set(ids[:2])
    with pytest.raises(KeyError):
        ev[(ids[0], ids[0])] = 1.0
    assert ev.holders() == set(ids[:2])
