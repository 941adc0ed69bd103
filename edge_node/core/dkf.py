"""Distributed Kalman-Consensus Filter in information form (paper Section III-A, eqs. 2-4;
Olfati-Saber's Kalman-consensus filter).

Per camera ``i`` and target: measurement information ``u_i = H^T R_i^-1 z_i``,
``U_i = H^T R_i^-1 H`` (eq. 2); sums over the inclusive neighbourhood ``y_i``, ``S_i`` (eq. 3);
``M_i = (P_i^-1 + S_i)^-1``; correction with a consensus term on the neighbours' predictions
(eq. 4); then ``P_i <- A M_i A^T + Q``. Pure functions; covariances kept symmetric, inverses
replaced by solves.

Stability of the consensus step (eq. 4). Written for the nodes holding one tracker, the
consensus term ``x_i <- x_i + G_i sum_{j in N_i} (x_j - x_i)`` with ``G_i = gamma_i M_i`` is
``x <- (I - D (L (x) I)) x``: ``L`` the Laplacian of the links whose entries arrived, ``D`` the
block diagonal of the ``G_i`` (symmetric, positive semi-definite). With every ``G_i`` positive
definite, ``D (L (x) I)`` is similar to the symmetric ``D^1/2 (L (x) I) D^1/2``, so its eigenvalues
are real and non-negative, and with ``w_i = G_i^1/2 v_i``::

    v^T D^1/2 (L (x) I) D^1/2 v = sum_{edges ij} |w_i - w_j|^2 <= 2 sum_i d_i |w_i|^2
                                 <= 2 max_i (d_i ||G_i||_2) |v|^2

(``d_i`` the number of terms of node ``i``'s sum). If ``d_i ||G_i||_2 <= c < 1`` at every node,
the iteration matrix has its eigenvalues in ``[1 - 2c, 1]``, inside ``(-1, 1]``, the eigenvalue 1
only on agreement (``L 1 = 0``; a connected graph); it is self-adjoint in the ``D^-1`` inner
product, so the step never expands the disagreement in that norm, and every mode of
disagreement shrinks. This is the matrix form of the step bound ``epsilon < 1/Delta`` of
discrete-time consensus (the Perron matrix ``I - epsilon L``; Olfati-Saber, Fax & Murray, Proc.
IEEE 2007), taken per node with its own degree, and it is tight: for ``G_i = g I`` on an even
ring (bipartite, ``lambda_max(L) = 2d``) ``g d < 1`` is necessary. The prediction that follows is
the same ``A`` at every node. The argument is for one frame's graph and gains (synchronous
links); with gains that change every frame and one-way or lost entries (event-triggered runs)
it is the per-frame condition, checked by runs rather than proved
(``tests/test_consensus_stability.py``).

The paper's ``gamma = 1/(1 + ||M||)`` gives ``||gamma M||_2 < 1``: the condition for one
neighbour only. For a target no camera near node ``i`` measures, ``M = P`` grows every frame and
``||gamma M||_2 -> lambda_max(P) / ||P||_F`` (about 0.7 for a round position uncertainty): with two
neighbours ``d_i ||G_i||_2`` reaches 1.4, and on a chain or an even ring the alternating mode
(eigenvalue about ``1 - 4 * 0.7``) grows 1.8-fold per frame. Such estimates ran off at hundreds
of m/s (corridor-16 without regional scope: 58k neighbour entries refused as
``implausible_state`` in 300 frames). :func:`consensus_gamma` therefore keeps the paper's
``gamma`` wherever ``d_i ||gamma M_i||_2 <= c`` (every measured target in practice, and one
neighbour up to ``c``) and scales it down to ``c / (d_i ||M_i||_2)`` where it is not
(``TrackerConfig.consensus_bound``, ``c``). Olfati-Saber's Kalman-consensus filter has the same
freedom: his ``gamma = epsilon / (1 + ||M||)`` leaves the rate ``epsilon`` to the designer.
"""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from edge_node.core.model import MEAS_DIM, STATE_DIM
from edge_node.core.stacks import times
from edge_node.geometry import norms

# c of the stability condition ``degree ||gamma M||_2 <= c`` (module docstring); the default of
# ``TrackerConfig.consensus_bound``
CONSENSUS_BOUND = 0.9

_I = np.eye(STATE_DIM)
_I.setflags(write=False)


def symmetric(M: np.ndarray) -> np.ndarray:
    """``(M + M^T) / 2`` of one matrix or of a stack ``(n, d, d)``."""
    return 0.5 * (M + M.swapaxes(-1, -2))


def information(z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2: ``u = H^T R^-1 z``, ``U = H^T R^-1 H``."""
    u, U = informations(np.asarray(z, float)[None], np.asarray(R, float)[None])
    return u[0], U[0]


def informations(z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2 for a stack of measurements ``z`` ``(n, 4)``, ``R`` ``(n, 4, 4)``: ``u`` ``(n, 6)``,
    ``U`` ``(n, 6, 6)``. ``H`` only picks the first four state components, so ``H^T R^-1 H`` is
    ``R^-1`` padded with zeros and ``H^T R^-1 z`` is ``R^-1 z`` padded. (``numpy.linalg.inv``
    is LAPACK's ``gesv`` against the identity: the numbers of ``solve(R, I)``.)"""
    n = len(z)
    Rinv = np.linalg.inv(R)
    U = np.zeros((n, STATE_DIM, STATE_DIM))
    U[:, :MEAS_DIM, :MEAS_DIM] = symmetric(Rinv)
    u = np.zeros((n, STATE_DIM))
    u[:, :MEAS_DIM] = (Rinv.swapaxes(-1, -2) @ z[..., None])[..., 0]  # R^-T z = R^-1 z
    return u, U


def carried(u: np.ndarray, U: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``u`` of measurement information ``u = U z`` whose ground position is moved by ``shift``
    ``(2,)`` (``U`` unchanged): ``U (z + s) = u + U s``. What an event-triggered node does with a
    measurement of where a target was, to use it where the target is now."""
    return u + U[:, :2] @ shift


def no_information() -> tuple[np.ndarray, np.ndarray]:
    """What a camera without a measurement of the target contributes: ``u = 0``, ``U = 0``."""
    return np.zeros(STATE_DIM), np.zeros((STATE_DIM, STATE_DIM))


def fuse(contributions: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 3: ``y_i = sum_j u_j``, ``S_i = sum_j U_j`` over the inclusive neighbourhood."""
    y = np.zeros(STATE_DIM)
    S = np.zeros((STATE_DIM, STATE_DIM))
    for u, U in contributions:
        y = y + u
        S = S + U
    return y, S


def gain(P: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``M = (P^-1 + S)^-1`` computed as ``(I + P S)^-1 P`` (no inverse of ``P``); one matrix
    or a stack ``(n, 6, 6)``."""
    M = np.linalg.solve(_I + P @ S, P)
    return symmetric(M)


def consensus_gamma(M: np.ndarray, degree: int | np.ndarray = 1,
                    bound: float = CONSENSUS_BOUND) -> float | np.ndarray:
    """The consensus step of eq. 4: the paper's ``gamma = 1 / (1 + ||M||)`` (Frobenius norm),
    scaled down where the consensus sum's ``degree`` terms would step farther than ``bound``:
    ``gamma = min(1 / (1 + ||M||), bound / (degree ||M||_2))``, so that
    ``degree ||gamma M||_2 <= bound`` (the stability condition in the module docstring; ``M``
    symmetric positive semi-definite, ``||M||_2`` its largest eigenvalue). One matrix or a stack
    ``(n, 6, 6)`` with one ``degree`` each (then one ``gamma`` per matrix)."""
    M = np.asarray(M, float)
    one = M.ndim == 2
    Ms = M[None] if one else M
    d = np.asarray(degree, float)
    if d.shape != Ms.shape[:1]:  # one degree for all (the common call passes one per matrix)
        d = np.broadcast_to(d, Ms.shape[:1])
    frobenius = norms(Ms, axis=(-2, -1))
    g = 1.0 / (1.0 + frobenius)
    # ||M||_2 <= ||M||_F: where the Frobenius norm keeps the step within the bound the largest
    # eigenvalue does too, so the eigenvalues are computed only where they may not
    check = (d * g * frobenius > bound).nonzero()[0]
    if len(check):
        step = d[check] * g[check] * np.linalg.eigvalsh(symmetric(Ms.take(check, axis=0)))[:, -1]
        g[check] = np.where(step > bound, g[check] * bound / step, g[check])
    return float(g[0]) if one else g


def correct(x_bar: np.ndarray, P: np.ndarray, y: np.ndarray, S: np.ndarray,
            neighbour_x_bars: Iterable[np.ndarray] = (),
            own_x_bar_sent: np.ndarray | None = None,
            units_per_metre: float = 1.0,
            bound: float = CONSENSUS_BOUND) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4 for one tracker (see :func:`corrects`): ``x_bar_j`` are the neighbours'
    predictions and ``own_x_bar_sent`` this camera's prediction as they received it (rounded to
    the wire's precision; ``x_bar`` when ``None``). Returns ``(x_hat, M)``."""
    ref = x_bar if own_x_bar_sent is None else own_x_bar_sent
    diff = np.zeros(STATE_DIM)
    degree = 0
    for xj in neighbour_x_bars:
        diff = diff + (np.asarray(xj, float) - ref)
        degree += 1
    x_hat, M = corrects(x_bar[None], P[None], y[None], S[None], diff[None], units_per_metre,
                        degree=np.array([degree]), bound=bound)
    return x_hat[0], M[0]


def corrects(x_bar: np.ndarray, P: np.ndarray, y: np.ndarray, S: np.ndarray, diff: np.ndarray,
             units_per_metre: float = 1.0, *, degree: np.ndarray,
             bound: float = CONSENSUS_BOUND) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4 for ``n`` trackers at once: ``x_hat = x_bar + M (y - S x_bar) + gamma M diff``
    with ``diff = sum_j (x_bar_j - x_bar)`` over the neighbours (shapes ``(n, 6)`` and
    ``(n, 6, 6)``) and ``degree`` ``(n,)`` the number of terms of each tracker's sum (the
    neighbours whose entries arrived), which bounds ``gamma`` (:func:`consensus_gamma`, the
    stability condition of the module docstring). Returns ``(x_hat, M)``.

    ``diff`` uses this camera's prediction as its neighbours received it (rounded to the wire's
    precision), so that cameras that agree exactly see a zero consensus term.

    Units: the consensus term ``gamma M diff`` is not unit-invariant (``M`` carries squared
    ground units). It is evaluated with ``M`` in metres, ``M_m = M / units_per_metre^2``, so the
    filter behaves identically whatever the calibration's ground unit (EPFL's is ~1/30 m; taken
    literally there, every neighbour pulls with a weight near 1 and three neighbours oscillate).
    """
    M = gain(P, S)
    x_hat = x_bar + (M @ (y - (S @ x_bar[..., None])[..., 0])[..., None])[..., 0]
    pull = (diff != 0).any(axis=1).nonzero()[0]
    if len(pull):  # (rows by take: see stacks)
        M_m = M.take(pull, axis=0) / units_per_metre**2
        gamma = consensus_gamma(M_m, np.maximum(np.asarray(degree).take(pull), 1), bound)
        step = (M_m @ diff.take(pull, axis=0)[..., None])[..., 0]
        x_hat[pull] = x_hat.take(pull, axis=0) + gamma[:, None] * step
    return x_hat, M


def predict(x_hat: np.ndarray, M: np.ndarray, A: np.ndarray, Q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """``x_bar(k+1) = A x_hat(k)``, ``P(k+1) = A M A^T + Q``; one tracker ``(6,)``, ``(6, 6)``
    or a stack ``(n, 6)``, ``(n, 6, 6)`` (then ``(A M) A^T`` in one call: ``stacks.times``)."""
    if M.ndim == 2:
        return x_hat @ A.T, symmetric(A @ M @ A.T + Q)
    return x_hat @ A.T, symmetric(times(A @ M, A.T) + Q)


__all__ = ["information", "informations", "carried", "no_information", "fuse", "gain", "consensus_gamma",
           "correct", "corrects", "predict", "symmetric", "MEAS_DIM", "CONSENSUS_BOUND"]
