"""The screen's verdict on measurement information (``bad_information``,
``implausible_information``), batched, against the rules applied one entry at a time with
NumPy's eigen-decomposition and pseudo-inverse in this file: the screen decides most entries
without eigenvalues (a closed-form Cholesky factor and bounds), and a decoded block skips the
form checks its decoder guarantees; neither may change a verdict."""
import numpy as np
import pytest

from edge_node.core import TrackerConfig
from fakes import make_nodes
from protocol import codec
from protocol.messages import FrameMessage, TrackerBlock


@pytest.fixture(scope="module")
def screen():
    return make_nodes({0: (1,), 1: (0,)}, TrackerConfig())[1].screen


def verdict(screen, u, U):
    """The rules of ``edge_node/core/screen.py``'s docstring for one entry, from scratch."""
    if np.any(U[4:]) or np.any(U[:, 4:]) or np.any(u[4:]):
        return "bad_information"  # information on the velocity
    U4, u4 = U[:4, :4], u[:4]
    if np.any(np.abs(U4 - U4.T) > 1e-6 * np.abs(U4)):
        return "bad_information"
    if not np.any(U4):
        return "bad_information" if np.any(u4) else None
    ev, V = np.linalg.eigh(U4)
    if ev[0] < -1e-6 * ev[-1]:
        return "bad_information"  # not positive semi-definite
    if ev[-1] > 1e4:  # better than 1 cm
        return "implausible_information"
    w = V.T @ u4
    seen = ev > 1e-9 * ev[-1]  # the directions U measures
    if np.any(~seen & (np.abs(w) > 1e-6 * np.linalg.norm(w))):
        return "bad_information"  # u = U z for no z
    return "implausible_information" if _distance2(screen, ev, V, w, seen) > 1e4 else None


def _distance2(screen, ev, V, w, seen):
    """The squared distance, in the metric of ``U`` on the directions it measures, of ``z`` (the
    pseudo-inverse's measurement) from the plausible point nearest it."""
    z = V @ np.where(seen, w / np.where(seen, ev, 1.0), 0.0)
    p = z.copy()
    p[2:] = np.clip(p[2:], 0.0, screen.max_size)
    d = np.linalg.norm(screen.anchors - p[:2], axis=1)
    a = screen.anchors[np.argmin(d)]
    if d.min() > screen.radius:
        p[:2] = a + (p[:2] - a) * screen.radius / d.min()
    return np.sum(np.where(seen, ev * (V.T @ (z - p)) ** 2, 0.0))


def batch(rng, n):
    """``n`` entries of every kind: positive definite of condition numbers up to 10^16 (half of
    them below 10^3, as honest measurements are), semi-definite of lower rank, indefinite, too
    precise; measurements on and far off the world; some ``u`` outside ``U``'s range; a few
    with velocity information."""
    Q, _ = np.linalg.qr(rng.normal(size=(n, 4, 4)))
    kind = rng.choice([1.0, 1.0, 1.0, 1.0, 0.0, -1e-3, -1.0], (n, 4))
    ev = 10 ** rng.uniform(-12, 4.5, (n, 4)) * kind
    honest = rng.random(n) < 0.5
    k = int(honest.sum())
    ev[honest] = 10 ** (rng.uniform(-2, 4.5, (k, 1)) + rng.uniform(-3, 0, (k, 4)))
    U4 = Q @ (ev[:, :, None] * Q.transpose(0, 2, 1))
    U = np.zeros((n, 6, 6))
    U[:, :4, :4] = 0.5 * (U4 + U4.transpose(0, 2, 1))
    z = rng.normal(0, 10 ** rng.uniform(0, 3.5), (n, 4))
    u = np.zeros((n, 6))
    u[:, :4] = (U[:, :4, :4] @ z[:, :, None])[:, :, 0]
    u[:, :4] += rng.choice([0.0] * 6 + [1e-3], (n, 1)) * rng.normal(size=(n, 4))
    vel = rng.random(n) < 0.03
    U[vel, 4, 4] = 1.0
    return u, U


def near_a_threshold(screen, u, U):
    """A well-formed entry whose Mahalanobis distance or largest eigenvalue lies within 1e-6 of
    its gate: a verdict there is rounding, either way."""
    U4 = U[:4, :4]
    if verdict(screen, u, U) == "bad_information" or not np.any(U4):
        return False
    ev, V = np.linalg.eigh(U4)
    d2 = _distance2(screen, ev, V, V.T @ u[:4], ev > 1e-9 * ev[-1])
    return abs(d2 - 1e4) < 1e-6 * 1e4 or abs(ev[-1] - 1e4) < 1e-6 * 1e4


def test_batched_verdicts_equal_the_rules_applied_entry_by_entry(screen):
    rng = np.random.default_rng(11)
    seen, paths = {}, np.zeros(2, int)  # paths: entries decided without / with eigenvalues
    for _ in range(300):
        u, U = batch(rng, int(rng.integers(1, 40)))
        got = screen.informations(u, U)
        for i, g in enumerate(got):
            if near_a_threshold(screen, u[i], U[i]):
                continue
            want = verdict(screen, u[i], U[i])
            assert g == want, (u[i], U[i])
            seen[want] = seen.get(want, 0) + 1
        sure, _ = screen._measured(u[:, :4], U[:, :4, :4])
        paths += [sure.sum(), (~sure).sum()]
    # every verdict occurs often enough to mean something, and both paths decide many
    assert min(seen.get(v, 0) for v in (None, "bad_information", "implausible_information")) > 300
    assert paths.min() > 1000, paths


def test_honest_measurements_are_decided_without_eigenvalues(screen):
    """The closed-form path takes every measurement with a condition number up to 10^3 and
    standard deviations from 2 cm up (whatever the spectrum: the bound is weakest with three
    small eigenvalues and one large), and finds the far ones (a measurement 10 km off) as the
    entry-by-entry rules do."""
    rng = np.random.default_rng(5)
    n = 200
    Q, _ = np.linalg.qr(rng.normal(size=(n, 4, 4)))
    top = 10 ** rng.uniform(-2, np.log10(2.5e3), (n, 1))  # 2 cm: 2500 per m^2
    ev = top * 10 ** rng.uniform(-3, 0, (n, 4))
    ev[: n // 4, :3] = top[: n // 4] * 1e-3 * 1.01  # the weakest case for the bound
    U4 = Q @ (ev[:, :, None] * Q.transpose(0, 2, 1))
    z = np.column_stack([rng.uniform(-5, 15, len(U4)), rng.uniform(-5, 15, len(U4)),
                         rng.uniform(0.3, 0.8, len(U4)), rng.uniform(1.5, 1.9, len(U4))])
    z[::3, 0] += 1e4
    sure, far = screen._measured((U4 @ z[:, :, None])[:, :, 0], U4)
    assert sure.all()
    u = np.zeros((len(U4), 6))
    u[:, :4] = (U4 @ z[:, :, None])[:, :, 0]
    U = np.zeros((len(U4), 6, 6))
    U[:, :4, :4] = U4
    want = [verdict(screen, u[i], U[i]) == "implausible_information" for i in range(len(U4))]
    assert far.tolist() == want and sum(want) >= len(U4) // 3


def test_a_decoded_block_gets_the_verdicts_of_its_numbers(screen):
    """A decoded block skips the form checks and the factorisation (its decoder's factor,
    ``TrackerBlock.measurement_factor``); its verdicts equal those of the same numbers checked
    in full, honest and hostile (1 km off, better than 1 cm), and so do those of entries the
    bounds cannot decide (a condition number of 10^5, decided with eigenvalues)."""
    rng = np.random.default_rng(2)
    n = 36  # (row 36 would be 1 km off with a 1 cm sigma: beyond float16 on the wire)
    A = rng.normal(size=(n, 4, 4))
    U4 = np.linalg.inv(A @ A.transpose(0, 2, 1) + 0.05 * np.eye(4))
    U4[1::7] *= 1e4
    Q, _ = np.linalg.qr(rng.normal(size=(n, 4, 4)))
    ill = np.arange(n) % 8 == 3
    U4[ill] = (Q @ (np.array([1e-4, 1e-2, 0.1, 10.0])[:, None] * Q.transpose(0, 2, 1)))[ill]
    U = np.zeros((n, 6, 6))
    U[:, :4, :4] = 0.5 * (U4 + U4.transpose(0, 2, 1))
    U[::5] = 0.0  # unmeasured rows
    x = np.column_stack([rng.uniform(0, 10, (n, 2)), np.full(n, 0.5), np.full(n, 1.7),
                         np.zeros((n, 2))])
    z = x.copy()
    z[::6, 0] += 1e3
    u = (U @ z[:, :, None])[:, :, 0]
    ints = np.arange(n)
    block = TrackerBlock(np.zeros(n, np.int64), ints, ints, np.zeros(n, np.int64), x, u, U)
    msg = FrameMessage(network="n", sender=0, frame=n, sent_at=0.0, block=block)
    decoded = codec.decode(codec.encode(msg)).block
    assert decoded.measurement_factor() is not None
    assert block.measurement_factor() is None and decoded.take([0, 1]).measurement_factor() is None
    measured, L, v = decoded.measurement_factor()
    rows = measured.nonzero()[0]
    assert rows.tolist() == [i for i in range(n) if i % 5]
    assert np.allclose(L @ L.transpose(0, 2, 1), decoded.U[rows, :4, :4], rtol=1e-12, atol=0)
    assert np.allclose((L @ v[:, :, None])[:, :, 0], decoded.u[rows, :4], rtol=1e-9, atol=1e-9)
    fast = screen.informations(decoded.u, decoded.U, factor=(measured, L, v))
    assert fast == screen.informations(decoded.u, decoded.U)
    assert {None, "implausible_information"} == set(fast)
    assert fast == [verdict(screen, decoded.u[i], decoded.U[i]) for i in range(n)]
    sure, far = screen._measured(None, decoded.U[rows, :4, :4], (L, v))
    sure_full, far_full = screen._measured(decoded.u[rows, :4], decoded.U[rows, :4, :4])
    assert sure.tolist() == sure_full.tolist() and far.tolist() == far_full.tolist()
    assert ill[rows].any() and not sure[ill[rows]].any()  # the eigenvalues decided those


def test_a_frames_factors_stack_in_message_order_and_skip_empty_blocks():
    """``Screen.messages`` checks a frame's entries in one batch: the decoded blocks' factors
    stacked as their rows are; an empty message (a neighbour that tracks nobody) has nothing
    to factor and leaves the others' factors in use; a block that was not decoded has none, and
    the batch is checked in full."""
    from edge_node.core.screen import _factors
    rng = np.random.default_rng(4)

    def decoded(n, sender):
        A = rng.normal(size=(n, 4, 4))
        U = np.zeros((n, 6, 6))
        U[:, :4, :4] = np.linalg.inv(A @ A.transpose(0, 2, 1) + 0.1 * np.eye(4))
        U[1::3] = 0.0
        x = np.column_stack([rng.uniform(0, 10, (n, 2)), np.full(n, 0.5), np.full(n, 1.7),
                             np.zeros((n, 2))])
        u = (U @ x[:, :, None])[:, :, 0]
        ints = np.arange(n)
        block = TrackerBlock(np.full(n, sender, np.int64), ints, ints, np.zeros(n, np.int64), x, u, U)
        msg = FrameMessage(network="n", sender=sender, frame=9, sent_at=0.0, block=block)
        return codec.decode(codec.encode(msg)).block, block

    (a, plain), (b, _) = decoded(5, 1), decoded(4, 2)
    empty, _ = decoded(0, 3)
    assert empty.measurement_factor() is None
    measured, L, v = _factors([a, empty, b])
    assert measured.tolist() == [i % 3 != 1 for i in range(5)] + [i % 3 != 1 for i in range(4)]
    assert np.array_equal(L, np.concatenate([a.measurement_factor()[1], b.measurement_factor()[1]]))
    assert np.array_equal(v, np.concatenate([a.measurement_factor()[2], b.measurement_factor()[2]]))
    assert _factors([empty, b])[0].tolist() == b.measurement_factor()[0].tolist()
    assert _factors([a, plain]) is None and _factors([empty]) is None
