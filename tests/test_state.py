"""``NodeState``: a node's trackers as the columns of one table, rows in id order; rows in and
out by hand, checked against a dict of rows kept beside it."""
import numpy as np
import pytest

from edge_node.core.gallery import Gallery
from edge_node.core.state import CONFIRM_FRAMES, NodeState, TrackerRows


def _rows(st: NodeState) -> dict:
    return {t: (int(st.born[i]), st.x_bar[i].tolist(), st.P[i, 0, 0].item()) for i, t in enumerate(st.ids)}


def test_rows_stay_in_id_order_through_inserts_deletes_and_renames():
    st = NodeState(cameras=2)
    kept = {}
    for n, tid in enumerate([(3, 1), (0, 7), (2, 0), (0, 2), (9, 9)]):
        x = np.full(6, float(n))
        st.insert(tid, Gallery(), born=n, x_bar=x, P=np.eye(6) * (n + 1))
        kept[tid] = (n, x.tolist(), float(n + 1))
    assert st.ids == sorted(kept) and _rows(st) == kept
    assert st.index == {t: i for i, t in enumerate(sorted(kept))}
    out = st.delete((2, 0))
    assert out["born"] == 2 and out["x_bar"].tolist() == [2.0] * 6 and isinstance(out["gallery"], Gallery)
    del kept[(2, 0)]
    assert _rows(st) == kept
    i = st.rename((9, 9), (1, 0))  # a merge's loser takes the winner's id: its place moves
    kept[(1, 0)] = kept.pop((9, 9))
    assert st.ids[i] == (1, 0) and st.ids == sorted(kept) and _rows(st) == kept
    assert all(getattr(st, c).shape[0] == len(kept) for c in st._columns())
    with pytest.raises(KeyError):
        st.insert((0, 7), Gallery())


def test_a_new_row_starts_with_no_information_and_no_estimate():
    st = NodeState(cameras=2)
    st.insert((0, 0), Gallery())
    assert not st.estimated[0] and st.informed[0] and st.view_k[0].tolist() == [-1, -1]
    assert st.raw[0].tolist() == [-1, -1] and not st.seen[0].any()
    assert np.isnan(st.view_off[0]).all() and np.isnan(st.view_at[0]).all()  # nothing learnt
    rows = TrackerRows(st)
    assert rows[(0, 0)].x_hat is None and rows[(0, 0)].origin is None and not rows[(0, 0)].confirmed
    st.held[0] = CONFIRM_FRAMES
    assert rows[(0, 0)].confirmed and list(rows) == [(0, 0)] and (0, 0) in rows


def test_the_cameras_of_a_node_add_their_information_up():
    """Eq. 3 within a node: the first camera's information is the tracker's, a second adds."""
    st = NodeState(cameras=2)
    for t in [(0, 0), (0, 1), (0, 2)]:
        st.insert(t, Gallery())
    st.begin_frame()
    u1, U1 = np.arange(12.0).reshape(2, 6), np.stack([np.eye(6), 2 * np.eye(6)])
    st.add_information(np.array([0, 2]), 0, u1, U1, np.array([4, 5]))
    u2, U2 = np.ones((1, 6)), 3 * np.eye(6)[None]
    st.add_information(np.array([2]), 1, u2, U2, np.array([0]), residual=False)
    np.testing.assert_array_equal(st.u, [u1[0], np.zeros(6), u1[1] + u2[0]])
    np.testing.assert_array_equal(st.U[2], 5 * np.eye(6))
    assert st.seen.tolist() == [[True, False], [False, False], [True, True]]
    assert st.raw.tolist() == [[4, -1], [-1, -1], [5, 0]]
    assert st.residual.tolist() == [[True, False], [False, False], [True, False]]
    np.testing.assert_array_equal(st.cam_u[2, 1], u2[0])  # each camera's own, for the registrar
    st.begin_frame()
    assert not st.seen.any() and not st.u.any() and (st.raw == -1).all()
