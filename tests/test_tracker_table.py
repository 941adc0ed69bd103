"""``TrackerTable``: the node's trackers by id with their sorted order kept between changes."""
import random

import pytest

from edge_node.core.tracker import TrackerTable


def _check(t: TrackerTable) -> None:
    ids = sorted(dict(t))  # the plain dict's keys, sorted independently of the table
    assert t.ids() == ids
    assert t.in_order() == [dict.__getitem__(t, k) for k in ids]


@pytest.mark.parametrize("change", [
    lambda t: t.__setitem__((0, 1), "new"),  # a new id
    lambda t: t.__setitem__((2, 7), "replaced"),  # another tracker under a held id
    lambda t: t.__delitem__((2, 7)),
    lambda t: t.pop((2, 7)),
    lambda t: t.pop((9, 9), None),
    lambda t: t.popitem(),
    lambda t: t.setdefault((0, 3), "set"),
    lambda t: t.update({(5, 0): "u"}),
    lambda t: t.clear(),
    lambda t: t.__ior__({(1, 0): "o"}),
])
def test_every_change_shows_in_the_order(change):
    t = TrackerTable({(3, 1): "a", (2, 7): "b", (2, 10): "c"})
    _check(t)  # the order is kept now
    change(t)
    _check(t)


def test_random_changes_keep_the_order_of_a_sorted_dict():
    rng = random.Random(0)
    t = TrackerTable()
    for step in range(2000):
        key = (rng.randrange(4), rng.randrange(30))
        if rng.random() < 0.6:
            t[key] = step
        else:
            t.pop(key, None)
        if step % 7 == 0:
            _check(t)
    _check(t)


def test_lists_handed_out_are_the_callers():
    t = TrackerTable({(1, 1): "a", (0, 2): "b"})
    ids, trs = t.ids(), t.in_order()
    ids.append((9, 9))
    trs.clear()
    assert t.ids() == [(0, 2), (1, 1)] and t.in_order() == ["b", "a"]
